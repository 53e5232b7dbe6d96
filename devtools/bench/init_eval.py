"""Evaluation of the initialisation network: ``python -m devtools evaluate-init``.

    evaluate-init [--weights PATH] [--heldout DIR] [--golden DIR] [--fit-cases NAME ...]
                  [--iterations N] [--json FILE]

1. *Raw prediction on a held-out synthetic set* (a dataset folder made with another seed than the
   training set): pattern accuracy (softmax over the five preset candidates, at the lattices the
   estimator would propose) and the mean absolute error of each parameter on the true pattern's
   candidate, in the parameter's own units, beside the error of the prior's centre
   (:func:`backend.core.priors.typical`, the fit's start without the network).
2. *Raw prediction on the golden targets* (``cases.json`` + 16-bit renders of the paper's renderer;
   cases with ablation flags are skipped): the same, with the candidates of the real lattice
   estimator (:func:`backend.texture.candidates.propose`) on the 512-pixel images.
3. *Fits* of the golden targets named by ``--fit-cases`` (default: all), once from the prior and
   once from the network, with the same settings: final loss, pattern, roughness and thickness MAE,
   wall time, and the iteration and seconds at which the network-started fit first reaches the
   prior-started fit's final loss (seconds from the start of ``fit``, search included).
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from backend.app.environment import renderer_compiles
from backend.core import priors
from backend.core.params import FabricParams
from backend.core.rig import DEFAULT_RIG
from backend.fit.pipeline import fit
from backend.fit.settings import FitSettings
from backend.image.photos import load_pair
from backend.init import network as init_net
from backend.texture.candidates import propose
from backend.texture.spectra import Spectra

from ..train import EXACT_ROW, load_arrays
from .ledger import NOT_RECORDED, Ledger

REPORTED = init_net.TARGETS


def _mae(predicted: FabricParams, truth: FabricParams, name: str) -> float:
    a, b = predicted.flat(name), truth.flat(name)
    return sum(abs(x - y) for x, y in zip(a, b)) / len(a)


def parameter_errors(predicted: FabricParams, truth: FabricParams) -> dict[str, float]:
    return {name: _mae(predicted, truth, name) for name in REPORTED}


def _mean_errors(rows: list[dict[str, float]]) -> dict[str, float]:
    return {name: float(np.mean([r[name] for r in rows])) for name in REPORTED} if rows else {}


def _prior_start(pattern: str, tiles) -> FabricParams:
    return priors.typical(pattern).replace(tiles=tuple(tiles))


# -- 1. held-out synthetic set ---------------------------------------------------------------------
def evaluate_heldout(model: init_net.InitModel, folder: str | Path) -> dict:
    arrays = load_arrays(folder)
    targets, logits = model.predict(arrays.features[:, :EXACT_ROW])
    predicted_pattern = logits.argmax(1)
    net_rows, prior_rows = [], []
    per_pattern: dict[str, list[bool]] = {p: [] for p in priors.PATTERNS}
    for k, name in enumerate(arrays.names):
        true_index = int(arrays.patterns[k])
        pattern = priors.PATTERNS[true_index]
        truth = FabricParams.from_interchange(arrays.params[k])
        guess = init_net.params_from_vector(targets[k, true_index].tolist(), pattern, truth.tiles)
        net_rows.append(parameter_errors(guess, truth))
        prior_rows.append(parameter_errors(_prior_start(pattern, truth.tiles), truth))
        per_pattern[pattern].append(int(predicted_pattern[k]) == true_index)
    return {"items": len(arrays), "pattern_accuracy": float((predicted_pattern == arrays.patterns).float().mean()),
            "pattern_accuracy_by_pattern": {p: float(np.mean(v)) for p, v in per_pattern.items() if v},
            "network_mae": _mean_errors(net_rows), "prior_mae": _mean_errors(prior_rows)}


# -- 2. golden targets -----------------------------------------------------------------------------
def golden_cases(folder: str | Path) -> list[tuple[str, Path, Path, FabricParams]]:
    folder = Path(folder)
    out = []
    for case in json.loads((folder / "cases.json").read_text()):
        if case.get("flags"):
            continue
        out.append((case["name"], folder / f"{case['name']}_R.png", folder / f"{case['name']}_T.png",
                    FabricParams.from_interchange(case["params"])))
    return out


def _load(reflection: Path, transmission: Path):
    photos = load_pair(reflection, transmission, size=DEFAULT_RIG.film_size)
    return photos.reflection, photos.transmission


def evaluate_golden(model: init_net.InitModel, folder: str | Path, log=sys.stderr,
                    ledger: Ledger = NOT_RECORDED) -> dict:
    rows, net_rows, prior_rows = [], [], []
    for name, r_path, t_path, truth in golden_cases(folder):
        reflection, transmission = _load(r_path, t_path)
        candidates = propose(Spectra.of([reflection, transmission]), DEFAULT_RIG, priors.PATTERNS, per_pattern=1)
        start = init_net.NetworkStart(reflection, transmission, DEFAULT_RIG, model)
        probabilities = start.pattern_probabilities(candidates)
        best = max(range(len(candidates)), key=lambda k: probabilities[k])
        row = {"case": name, "pattern": truth.pattern, "predicted_pattern": candidates[best].pattern,
               "probability": round(probabilities[best], 3)}
        true_k = next((k for k, c in enumerate(candidates) if c.pattern == truth.pattern), None)
        if true_k is not None:
            errors = parameter_errors(start(candidates[true_k]), truth)
            prior = parameter_errors(_prior_start(truth.pattern, candidates[true_k].tiles), truth)
            net_rows.append(errors)
            prior_rows.append(prior)
            row.update({"network": {k: round(v, 4) for k, v in errors.items()},
                        "prior": {k: round(v, 4) for k, v in prior.items()}})
        rows.append(row)
        network_mae, prior_mae = row.get("network", {}), row.get("prior", {})
        print(f"evaluate-init: golden {name}: predicted {row['predicted_pattern']} ({row['probability']}), "
              f"roughness MAE {network_mae.get('roughness')} (prior {prior_mae.get('roughness')}), "
              f"thickness MAE {network_mae.get('thickness')} (prior {prior_mae.get('thickness')})",
              file=log, flush=True)
        ledger.row({"section": "golden", **row})
    return {"cases": rows, "pattern_accuracy": float(np.mean([r["pattern"] == r["predicted_pattern"] for r in rows])),
            "family_accuracy": float(np.mean([priors.family(r["pattern"]) == priors.family(r["predicted_pattern"])
                                              for r in rows])),
            "network_mae": _mean_errors(net_rows), "prior_mae": _mean_errors(prior_rows)}


# -- 3. fits from the prior and from the network ---------------------------------------------------
def _timed_fit(reflection, transmission, settings, use_network: bool, model) -> dict:
    trace: list[tuple[float, int, float]] = []
    started = time.perf_counter()

    def progress(stage, iteration, total, loss, eta, **_optimiser):
        if stage == "optimise" and loss is not None:
            trace.append((time.perf_counter() - started, iteration, float(loss)))

    hook = init_net.NetworkStart(reflection, transmission, DEFAULT_RIG, model) if use_network else None
    result = fit(reflection, transmission, DEFAULT_RIG, settings, progress=progress, initial_for=hook,
                 pattern_probabilities=hook.pattern_probabilities if hook is not None else None)
    return {"result": result, "trace": trace, "seconds": time.perf_counter() - started}


def _reach(trace, level: float) -> tuple[int | None, float | None]:
    """First optimise iteration (and seconds) whose loss is at or below ``level``."""
    for seconds, iteration, loss in trace:
        if loss <= level:
            return iteration, seconds
    return None, None


def evaluate_fits(model: init_net.InitModel, folder: str | Path, names: list[str] | None, iterations: int | None,
                  log=sys.stderr, ledger: Ledger = NOT_RECORDED) -> dict:
    settings = FitSettings(compile=renderer_compiles()) if iterations is None else FitSettings(
        iterations=iterations, compile=renderer_compiles())
    rows, true_patterns = [], {}
    for name, r_path, t_path, truth in golden_cases(folder):
        if names and name not in names:
            continue
        row = _fit_both_ways(model, name, r_path, t_path, truth, settings)
        rows.append(row)
        true_patterns.setdefault(name, truth.pattern)
        _print_fit(row, log)
        ledger.row({"section": "fits", **row})
    return {"iterations": settings.iterations, "cases": rows, "summary": _fits_summary(rows, true_patterns)}


def _fit_both_ways(model: init_net.InitModel, name: str, r_path: Path, t_path: Path, truth: FabricParams,
                   settings: FitSettings) -> dict:
    """One case fitted from the prior and from the network: each fit's figures, and where the
    network-started fit first reaches the prior-started fit's final loss."""
    reflection, transmission = _load(r_path, t_path)
    runs = {"prior": _timed_fit(reflection, transmission, settings, False, model),
            "network": _timed_fit(reflection, transmission, settings, True, model)}
    row = {"case": name}
    for label, run in runs.items():
        fitted = run["result"].params
        row[label] = {"pattern": fitted.pattern, "loss": round(run["result"].loss, 5),
                      "roughness_mae": round(_mae(fitted, truth, "roughness"), 4),
                      "thickness_mae": round(_mae(fitted, truth, "thickness"), 4),
                      "errors": {k: round(v, 4) for k, v in parameter_errors(fitted, truth).items()},
                      "seconds": round(run["seconds"], 1),
                      "search_seconds": round(run["result"].timings.get("search_s", 0.0), 1)}
    iteration, seconds = _reach(runs["network"]["trace"], runs["prior"]["result"].loss)
    row["network_reaches_prior_loss"] = {"iteration": iteration,
                                         "seconds": None if seconds is None else round(seconds, 1)}
    return row


def _print_fit(row: dict, log) -> None:
    prior, net, reach = row["prior"], row["network"], row["network_reaches_prior_loss"]
    print(f"evaluate-init: fit {row['case']}: prior loss {prior['loss']} ({prior['pattern']}, "
          f"{prior['seconds']} s, roughness MAE {prior['roughness_mae']}, thickness MAE "
          f"{prior['thickness_mae']}); network loss {net['loss']} ({net['pattern']}, "
          f"{net['seconds']} s, roughness MAE {net['roughness_mae']}, thickness MAE "
          f"{net['thickness_mae']}); network reaches the prior's final loss at iteration "
          f"{reach['iteration']} ({reach['seconds']} s)", file=log, flush=True)


def _fits_summary(rows: list[dict], true_patterns: dict[str, str]) -> dict:
    """Per start (prior, network): the means over the cases of the loss, the MAEs and the seconds,
    and the share of cases fitted with the true pattern (None without a case)."""
    summary = {}
    for label in ("prior", "network"):
        summary[label] = {key: float(np.mean([r[label][key] for r in rows])) if rows else None
                          for key in ("loss", "roughness_mae", "thickness_mae", "seconds")}
        summary[label]["pattern_accuracy"] = float(np.mean([r[label]["pattern"] == true_patterns[r["case"]]
                                                            for r in rows])) if rows else None
    return summary


# -- command line ----------------------------------------------------------------------------------
def print_table(title: str, section: dict) -> None:
    family = f", family accuracy {section['family_accuracy']:.3f}" if "family_accuracy" in section else ""
    print(f"\n{title}: pattern accuracy {section['pattern_accuracy']:.3f}{family}")
    print(f"  {'parameter':24s} {'network MAE':>12s} {'prior MAE':>12s}")
    for name in REPORTED:
        if name in section.get("network_mae", {}):
            print(f"  {name:24s} {section['network_mae'][name]:12.4f} {section['prior_mae'][name]:12.4f}")
