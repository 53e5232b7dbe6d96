"""``python -m devtools train``: the initialisation network from a dataset (:mod:`devtools.train`)."""
from __future__ import annotations

import sys
from dataclasses import asdict
from pathlib import Path

import torch

from backend.init import network

from ..dataset import DatasetSettings, recorded_settings
from ..train import TrainSettings, load_arrays, train


def run_train(args) -> int:
    torch.set_num_threads(args.threads)
    settings = TrainSettings(epochs=args.epochs, batch=args.batch, lr=args.lr, hidden=args.hidden,
                             seed=args.seed, validation=args.validation)
    try:
        arrays = load_arrays(args.dataset, args.limit)
    except (OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    net, info = train(arrays, settings)
    info["datasets"] = [_dataset_settings(Path(folder)) for folder in args.dataset]
    path = network.save(net, args.out, {"training": info})
    size_mb = path.stat().st_size / 1e6
    print(f"train: wrote {path} ({size_mb:.1f} MB); validation L1 {info['validation']['l1']:.4f}, "
          f"pattern accuracy {info['validation']['accuracy']:.3f}", file=sys.stderr)
    return 0


def _dataset_settings(folder: Path) -> dict:
    """The folder's DatasetSettings as its dataset.json records them (None each without one)."""
    recorded = recorded_settings(folder) or {}
    return {name: recorded.get(name) for name in asdict(DatasetSettings())}


def add_parser(sub) -> None:
    p = sub.add_parser("train", help="train the initialisation network on a synthetic dataset")
    p.add_argument("dataset", nargs="+", help="folders made by `python -m devtools dataset` (trained on together)")
    p.add_argument("--out", required=True, help="weights file to write (the shipped one: backend/data/init_net.pt)")
    p.add_argument("--epochs", type=int, default=TrainSettings.epochs)
    p.add_argument("--batch", type=int, default=TrainSettings.batch)
    p.add_argument("--lr", type=float, default=TrainSettings.lr)
    p.add_argument("--hidden", type=int, default=TrainSettings.hidden)
    p.add_argument("--seed", type=int, default=TrainSettings.seed)
    p.add_argument("--validation", type=float, default=TrainSettings.validation,
                   help="fraction of items held back to choose the best epoch")
    p.add_argument("--limit", type=int, help="use only the first N items (by name) of each folder")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1: a shared machine)")
    p.set_defaults(run=run_train)
