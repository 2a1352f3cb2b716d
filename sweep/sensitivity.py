"""Global sensitivity of every metric over a sweep: Sobol indices of a response surface.

A sweep is a grid, not the Saltelli sample that Sobol estimators need, so the indices are those of
a **surrogate**: for each metric, the polynomial of ``sweep.correction`` (total degree chosen by
k-fold cross-validation on the sweep's points) in the swept parameters E0, IOP, thickness and
pmax (those with more than one value).  SALib (Herman and Usher, JOSS 2 (2017) 97) samples the
sweep's box uniformly with Saltelli's scheme and estimates the first-order index S1 and the total
index ST of each parameter on the surrogate (Saltelli et al., Comput Phys Commun 181 (2010) 259),
with bootstrap 95 % confidence half-widths.  The surrogate's own held-out RMS is reported beside
the indices: where it is not small against the metric's spread, the indices describe the
surrogate more than the model.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from airpuff_core.params import PARAMETERS
from airpuff_core.result import METRICS

from .correction import (AXES, FOLDS, MAX_DEGREE, SEED, CorrectionError, fit_by_cross_validation,
                         sweep_points)
from .identification import SweepTable


def sobol_indices(table: SweepTable, metrics: Sequence[str] | None = None, n_base: int = 1024,
                  max_degree: int = MAX_DEGREE, folds: int = FOLDS,
                  seed: int = SEED) -> dict[str, Any]:
    """First-order and total Sobol indices of each metric's surrogate over the sweep's box.

    Returns ``{"parameters": [...], "bounds": {...}, "method": ..., "metrics": {name: {"S1":
    {param: value}, "S1_conf", "ST", "ST_conf", "surrogate": {degree, held_out_rms,
    relative_held_out_rms, points}} or {"skipped": reason}}}``."""
    from SALib.analyze import sobol as sobol_analyze
    from SALib.sample import sobol as sobol_sample

    metrics = list(metrics or table.metrics)
    params = [a for a in AXES if np.unique(getattr(table, a)).size > 1]
    if not params:
        raise CorrectionError("sweep", "the sweep has one point per parameter: nothing varies")
    pts = sweep_points(table)
    bounds = [[float(np.min(getattr(table, a))), float(np.max(getattr(table, a)))] for a in params]
    problem = {"num_vars": len(params), "names": params, "bounds": bounds}
    sample = sobol_sample.sample(problem, n_base, calc_second_order=False, seed=seed)
    x_all = np.stack([pts[a] for a in params], axis=1)
    out: dict[str, Any] = {}
    for name in metrics:
        y = pts[name]
        keep = np.isfinite(y)
        if keep.sum() < 2 or np.ptp(y[keep]) == 0:
            out[name] = {"skipped": "fewer than 2 points with a value" if keep.sum() < 2
                         else "constant over the sweep"}
            continue
        try:
            fit = fit_by_cross_validation(x_all[keep], y[keep], params, name, max_degree,
                                          folds, seed)
        except CorrectionError as err:
            out[name] = {"skipped": str(err)}
            continue
        si = sobol_analyze.analyze(problem, fit.surface(sample), calc_second_order=False,
                                   seed=seed)
        out[name] = {
            "unit": METRICS[name][0],
            **{k: {p: float(v) for p, v in zip(params, si[k])}
               for k in ("S1", "S1_conf", "ST", "ST_conf")},
            "surrogate": {"degree": fit.surface.degree, "held_out_rms": fit.rms,
                          "relative_held_out_rms": fit.rms / float(np.std(y[keep])),
                          "points": int(keep.sum()), "left_out": int((~keep).sum())},
        }
    return {"parameters": params,
            "bounds": {p: b for p, b in zip(params, bounds)},
            "units": {p: PARAMETERS[p].unit for p in params},
            "method": (f"Sobol indices of a polynomial surrogate (degree by {folds}-fold "
                       f"cross-validation, at most {max_degree}) fitted on the sweep's grid; "
                       f"SALib Saltelli sampling, N = {n_base} "
                       f"({n_base * (len(params) + 2)} surrogate evaluations), uniform over "
                       "the sweep's box"),
            "model_version": table.model_version,
            "metrics": out}


def format_indices(result: dict[str, Any]) -> str:
    """A plain-text table: one row per metric, S1 and ST of each parameter."""
    params = result["parameters"]
    w = max([10, *(len(n) + 1 for n in result["metrics"])])
    head = f"{'metric':<{w}}" + "".join(f"{'S1 ' + p:>13}{'ST ' + p:>13}" for p in params) \
        + f"{'surrogate RMS':>16}{'/ std':>8}"
    lines = [result["method"], head]
    for name, m in result["metrics"].items():
        if "skipped" in m:
            lines.append(f"{name:<{w}} skipped: {m['skipped']}")
            continue
        s = m["surrogate"]
        lines.append(f"{name:<{w}}" + "".join(f"{m['S1'][p]:>13.3f}{m['ST'][p]:>13.3f}"
                                             for p in params)
                     + f"{s['held_out_rms']:>12.3g} {m['unit']:<4}{s['relative_held_out_rms']:>7.3f}")
    return "\n".join(lines)
