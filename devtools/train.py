"""Training the initialisation network (:mod:`backend.init.network`) on a synthetic dataset.

    python -m devtools train DATASET [DATASET ...] --out CHECKPOINT [--epochs 120] [--batch 64] [--lr 1e-3]
        [--hidden 256] [--seed 0] [--validation 0.05] [--limit N]

Data (:mod:`devtools.dataset`): per item, features of six (pattern, tiles) candidates (one per
preset at the lattice the estimator would propose, then the true pattern at the exact tiles), the
true pattern and the [0, 1] parameter vector. One training example is one item with its five
preset candidates; the true pattern's row is, at random, its slightly mis-estimated lattice or the
exact one (so the network tolerates the estimator's error of a few tenths of a percent).

Loss (the paper's, spec section 5, item 2): L1 between the predicted and true parameter vectors on
the true pattern's candidate, plus 0.2 x cross-entropy of the softmax over the five candidates'
plausibility logits against the true pattern. AdamW (lr 1e-3, weight decay 1e-4, cosine decay),
batch 64; the weights of the epoch with the lowest validation loss (a held-back fraction of the
items, chosen by a hash of the item's name) are kept. Deterministic for a given dataset, settings
and seed, on one thread.

Items whose ``feature_version`` differs from the code's are re-described from their stored renders
(slow, but no re-rendering).
"""
from __future__ import annotations

import math
import sys
import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from backend.core import priors
from backend.init import network as init_net

from .dataset import load_items, redescribed

CE_WEIGHT = 0.2
EXACT_ROW = len(priors.PATTERNS)  # index of the exact-tiles row of an item's features


@dataclass
class Arrays:
    """A dataset in memory: features (n, 6, D) float32, targets (n, T), patterns (n,), names."""

    features: torch.Tensor
    targets: torch.Tensor
    patterns: torch.Tensor
    names: list[str]
    params: list[str]

    def subset(self, mask: np.ndarray) -> "Arrays":
        index = torch.from_numpy(np.nonzero(mask)[0])
        return Arrays(self.features[index], self.targets[index], self.patterns[index],
                      [self.names[i] for i in index], [self.params[i] for i in index])

    def __len__(self) -> int:
        return len(self.names)


def load_arrays(folders: str | Path | Sequence[str | Path], limit: int | None = None, log=sys.stderr) -> Arrays:
    """Reads every item of one or several dataset folders (features, targets, patterns); ``limit``
    applies per folder. Items of several folders are named ``<folder>/<item>`` (the validation
    hold-out hashes the name)."""
    folders = [folders] if isinstance(folders, (str, Path)) else list(folders)
    parts = [_load_folder(Path(folder), limit, log, prefix=f"{Path(folder).name}/" if len(folders) > 1 else "")
             for folder in folders]
    return Arrays(torch.cat([p.features for p in parts]), torch.cat([p.targets for p in parts]),
                  torch.cat([p.patterns for p in parts]), [n for p in parts for n in p.names],
                  [q for p in parts for q in p.params])


def _load_folder(folder: Path, limit: int | None, log, prefix: str) -> Arrays:
    files = load_items(folder, limit)
    if not files:
        raise ValueError(f"{folder}: no dataset items (*.npz); make them with `python -m devtools dataset`")
    features, targets, patterns, names, params = [], [], [], [], []
    stale = 0
    for k, path in enumerate(files):
        with np.load(path, allow_pickle=False) as data:
            if int(data["feature_version"]) == init_net.FEATURE_VERSION:
                rows = data["features"]
            else:
                rows, stale = redescribed({name: data[name] for name in data.files})["features"], stale + 1
            features.append(rows)
            targets.append(data["target"])
            patterns.append(int(data["pattern"]))
            params.append(str(data["params"]))
        names.append(prefix + path.stem)
        if (k + 1) % 1000 == 0:
            print(f"train: read {k + 1}/{len(files)} items of {folder}", file=log, flush=True)
    if stale:
        print(f"train: {stale} item(s) of {folder} re-described (feature version {init_net.FEATURE_VERSION})",
              file=log)
    return Arrays(torch.from_numpy(np.stack(features)).float(), torch.from_numpy(np.stack(targets)).float(),
                  torch.tensor(patterns), names, params)


def validation_mask(names: list[str], fraction: float) -> np.ndarray:
    """Items held back for model selection: a stable hash of the name, not their order."""
    return np.array([zlib.crc32(n.encode()) % 10000 < fraction * 10000 for n in names])


def candidate_batch(arrays: Arrays, index: torch.Tensor, exact: torch.Tensor | None) -> torch.Tensor:
    """(B, 5, D): the five preset candidates; where ``exact`` is set, the true row at exact tiles."""
    batch = arrays.features[index, :EXACT_ROW].clone()
    if exact is not None and bool(exact.any()):
        rows = torch.nonzero(exact).flatten()
        batch[rows, arrays.patterns[index[rows]]] = arrays.features[index[rows], EXACT_ROW]
    return batch


def losses(net: init_net.InitNet, batch: torch.Tensor, targets: torch.Tensor, patterns: torch.Tensor) -> dict:
    predicted, logits = net(batch)
    rows = torch.arange(len(patterns))
    l1 = (predicted[rows, patterns] - targets).abs().mean()
    ce = F.cross_entropy(logits, patterns)
    return {"loss": l1 + CE_WEIGHT * ce, "l1": l1, "ce": ce,
            "accuracy": (logits.argmax(1) == patterns).float().mean()}


def evaluate(net: init_net.InitNet, arrays: Arrays, batch_size: int = 512) -> dict[str, float]:
    """Mean losses over a set, on the candidates as the fit would propose them (no exact rows)."""
    net.eval()
    totals: dict[str, float] = {}
    with torch.no_grad():
        for start in range(0, len(arrays), batch_size):
            index = torch.arange(start, min(start + batch_size, len(arrays)))
            out = losses(net, candidate_batch(arrays, index, None), arrays.targets[index], arrays.patterns[index])
            for k, v in out.items():
                totals[k] = totals.get(k, 0.0) + float(v) * len(index)
    return {k: v / max(len(arrays), 1) for k, v in totals.items()}


@dataclass(frozen=True)
class TrainSettings:
    epochs: int = 120
    batch: int = 64
    lr: float = 1e-3
    weight_decay: float = 1e-4
    hidden: int = 256
    dropout: float = 0.1
    seed: int = 0
    validation: float = 0.05


def train(arrays: Arrays, settings: TrainSettings = TrainSettings(), log=sys.stderr,
          steps: int | None = None) -> tuple[init_net.InitNet, dict]:
    """Trains a network; ``steps`` (tests) stops after that many optimiser steps."""
    torch.manual_seed(settings.seed)
    generator = torch.Generator().manual_seed(settings.seed)
    training, validation = _split(arrays, settings.validation)
    net = init_net.InitNet(init_net.INPUT_DIM, settings.hidden, settings.dropout)
    net.set_normalisation(training.features[:, :EXACT_ROW].reshape(-1, init_net.FEATURE_DIM))
    optimiser = torch.optim.AdamW(net.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
    per_epoch = max(1, math.ceil(len(training) / settings.batch))
    total_steps = steps or settings.epochs * per_epoch
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, total_steps)
    initial = evaluate(net, training)
    best = (math.inf, None, None)
    started = time.perf_counter()
    step = 0
    epoch = 0
    while step < total_steps:
        train_stats, step = _epoch(net, training, settings.batch, optimiser, scheduler, generator, step, total_steps)
        epoch += 1
        val = evaluate(net, validation)
        if val["loss"] < best[0]:
            best = (val["loss"], {k: v.clone() for k, v in net.state_dict().items()}, epoch)
        if epoch == 1 or epoch % 10 == 0 or step >= total_steps:
            print(f"train: epoch {epoch} train loss {train_stats['loss']:.4f} (L1 {train_stats['l1']:.4f}, "
                  f"CE {train_stats['ce']:.3f}); validation {val['loss']:.4f} (L1 {val['l1']:.4f}, "
                  f"pattern accuracy {val['accuracy']:.3f}) [{time.perf_counter() - started:.0f} s]",
                  file=log, flush=True)
    net.load_state_dict(best[1])
    net.eval()
    final_val = evaluate(net, validation)
    final_train = evaluate(net, training)
    info = {"items": len(arrays), "training_items": len(training), "validation_items": len(validation),
            "epochs": epoch, "best_epoch": best[2], "seconds": round(time.perf_counter() - started, 1),
            "initial_train": {k: round(v, 5) for k, v in initial.items()},
            "train": {k: round(v, 5) for k, v in final_train.items()},
            "validation": {k: round(v, 5) for k, v in final_val.items()},
            "settings": settings.__dict__}
    return net, info


def _split(arrays: Arrays, fraction: float) -> tuple[Arrays, Arrays]:
    """The training and the validation items (:func:`validation_mask`); a set too small to hold
    items back validates on the training items."""
    held = validation_mask(arrays.names, fraction)
    if held.all() or not held.any():
        return arrays, arrays
    return arrays.subset(~held), arrays.subset(held)


def _epoch(net: init_net.InitNet, training: Arrays, batch: int, optimiser, scheduler, generator: torch.Generator,
           step: int, total_steps: int) -> tuple[dict[str, float], int]:
    """One pass over the training items in a random order (or up to ``total_steps``): each batch's
    true rows at the exact tiles for a random half. Returns the mean losses and the step count."""
    net.train()
    order = torch.randperm(len(training), generator=generator)
    running = {"loss": 0.0, "l1": 0.0, "ce": 0.0}
    count = 0
    for start in range(0, len(training), batch):
        index = order[start:start + batch]
        exact = torch.rand(len(index), generator=generator) < 0.5
        out = losses(net, candidate_batch(training, index, exact), training.targets[index], training.patterns[index])
        optimiser.zero_grad(set_to_none=True)
        out["loss"].backward()
        optimiser.step()
        scheduler.step()
        for k in running:
            running[k] += float(out[k].detach()) * len(index)
        count += len(index)
        step += 1
        if step >= total_steps:
            break
    return {k: v / count for k, v in running.items()}, step
