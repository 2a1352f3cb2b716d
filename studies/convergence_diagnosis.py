"""What limits the convergence of P2: one run with the cornea's apex region, the apex fluid
pressure and the sound speed recorded at every solver step.

    python -m studies.convergence_diagnosis --resolution paper --out diag
    python -m studies.convergence_diagnosis --resolution fine --out diag --set cfl=0.3

The run is the solver's own (``CoupledModel`` stepped under the ``Recorder``, as ``simulate``
does), so its metrics are those of ``airpuff run``.  Beside them it prints the second
applanation found with other measures of the apex curvature, from the same steps:

- ``fit``: the solver's measure (docs/model.md section 3: the even quartic over 0.6 mm,
  ``quart_0.6`` below);
- ``pair``: 2 (y0 - y1) / x1^2 from the apex and its neighbour (curvature at the apex, O(h^2));
- ``quad_R``: least-squares y = c0 + c2 x^2 over the nodes with reference x <= R;
- ``quart_R``: least-squares y = c0 + c2 x^2 + c4 x^4 over the same nodes;

and the apex fluid pressure at each A2, the largest sound speed (running-maximum rule) and where
the fastest fluid node was when it was set.  Writes ``<out>/<name>.json`` and the step series
``<out>/<name>.npz``.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import time
from pathlib import Path

import numpy as np

from airpuff_core import RunParams
from airpuff_core.coupling import CoupledModel
from airpuff_core.kernels.membrane import even_fit_curvature
from airpuff_core.params import MMHG_PA
from airpuff_core.blowup import BlowUpCheck
from airpuff_core.energy import EnergyBudget
from airpuff_core.recorder import Recorder

APEX_REGION_MM = 1.2  # cornea nodes recorded: reference x up to this


def parse_changes(items):
    changes = {}
    for item in items:
        name, _, value = item.partition("=")
        try:
            changes[name] = float(value)
        except ValueError:
            changes[name] = value
    return changes


def fitted_curvature(X, Y, n_fit, quartic):
    """kappa = -2 c2 [1/m] of y = c0 + c2 x^2 (+ c4 x^4) by least squares over n_fit nodes."""
    x = X[:n_fit]
    cols = [np.ones_like(x), x * x] + ([x ** 4] if quartic else [])
    coef = np.linalg.lstsq(np.stack(cols, 1), Y[:n_fit], rcond=None)[0]
    return -2.0 * coef[1]


def crossing_up(t, f, after):
    """Last upward zero crossing of f after ``after`` (linear interpolation), or NaN."""
    last = math.nan
    for i in range(1, len(f)):
        if t[i] > after and f[i - 1] < 0 <= f[i]:
            s = f[i - 1] / (f[i - 1] - f[i])
            last = t[i - 1] + s * (t[i] - t[i - 1])
    return last


def crossing_down(t, f):
    for i in range(1, len(f)):
        if f[i - 1] > 0 >= f[i]:
            s = f[i - 1] / (f[i - 1] - f[i])
            return t[i - 1] + s * (t[i] - t[i - 1])
    return math.nan


def run(params: RunParams):
    model = CoupledModel(params)
    budget = EnergyBudget(model)
    recorder = Recorder(model, budget)
    observers = (budget, BlowUpCheck(), recorder)
    X_ref = model.X.copy()
    n_region = int(np.searchsorted(X_ref, APEX_REGION_MM * 1e-3, side="right"))
    steps_t, steps_X, steps_Y, steps_p, steps_c, steps_vmax_node = [0.0], [], [], [], [], []
    steps_X.append(model.X[:n_region].copy())
    steps_Y.append(model.Y[:n_region].copy())
    steps_p.append(model.p_interface[0] / MMHG_PA)
    steps_c.append(model.c)
    steps_vmax_node.append(-1)
    t_end = model.si.t_end_s
    wall0 = time.monotonic()
    while model.t < t_end - 1e-15:
        model.step(t_stop=t_end, observers=observers)
        steps_t.append(model.t * 1e3)
        steps_X.append(model.X[:n_region].copy())
        steps_Y.append(model.Y[:n_region].copy())
        steps_p.append(model.p_interface[0] / MMHG_PA)
        steps_c.append(model.c)
        steps_vmax_node.append(int(np.argmax(model.vx ** 2 + model.vy ** 2)))
    result = recorder.result(model, time.monotonic() - wall0)
    series = {"t_ms": np.array(steps_t), "X": np.array(steps_X), "Y": np.array(steps_Y),
              "p_apex_mmHg": np.array(steps_p), "c": np.array(steps_c),
              "vmax_node": np.array(steps_vmax_node), "X_ref": X_ref[:n_region],
              "node_x": model.chamber.x, "node_y": model.chamber.y,
              "node_kind": model.chamber.kind}
    return model, result, series


def analyse(model, result, series):
    t = series["t_ms"]
    X, Y = series["X"], series["Y"]
    X_ref = series["X_ref"]
    p_jet = lambda t_ms: model.jet.at_apex(t_ms * 1e-3) / MMHG_PA  # noqa: E731
    measures = {"fit": lambda x, y: even_fit_curvature(x, y, model.n_apex_fit),
                "pair": lambda x, y: 2.0 * (y[0] - y[1]) / (x[1] ** 2)}
    for R in (0.3, 0.6, 1.0):
        n = int(np.searchsorted(X_ref, R * 1e-3 * (1 + 1e-9), side="right"))
        for form, quartic, least in (("quad", False, 2), ("quart", True, 3)):
            if n >= least:
                measures[f"{form}_{R}"] = functools.partial(fitted_curvature, n_fit=n,
                                                            quartic=quartic)
    out = {}
    for name, f in measures.items():
        kappa = np.array([f(X[k], Y[k]) for k in range(len(t))])
        tA1 = crossing_down(t, kappa)
        tA2 = crossing_up(t, kappa, tA1)
        pA2 = float(np.interp(tA2, t, series["p_apex_mmHg"])) if math.isfinite(tA2) else math.nan
        pA1 = float(np.interp(tA1, t, series["p_apex_mmHg"])) if math.isfinite(tA1) else math.nan
        out[name] = {"t_A1": tA1, "P1": p_jet(tA1), "t_A2": tA2, "P2": p_jet(tA2),
                     "fluid_p_A1": pA1, "fluid_p_A2": pA2}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", default="paper")
    ap.add_argument("--out", required=True)
    ap.add_argument("--name", default=None)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    args = ap.parse_args(argv)
    changes = parse_changes(args.set)
    params = RunParams(resolution=args.resolution).replace(**changes)
    name = args.name or "_".join([args.resolution] + [f"{k}{v}" for k, v in changes.items()])
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    model, result, series = run(params)
    measures = analyse(model, result, series)
    c = series["c"]
    i_c = int(np.argmax(c))
    node = int(series["vmax_node"][i_c])
    m = result.metrics
    summary = {"name": name, "params": changes, "resolution": args.resolution,
               "metrics": {k: m[k] for k in ("P1", "P2", "CH", "DA", "t_A1", "t_A2")},
               "fluid_p_A1": result.diagnostics.get("fluid_pressure_apex_at_A1"),
               "fluid_p_A2": result.diagnostics.get("fluid_pressure_apex_at_A2"),
               "c_max": float(c.max()), "c_max_set_at_ms": float(series["t_ms"][i_c]),
               "c_max_node": node,
               "c_max_node_xy_mm": [float(series["node_x"][node] * 1e3),
                                    float(series["node_y"][node] * 1e3)],
               "c_max_node_kind": int(series["node_kind"][node]),
               "steps": int(result.diagnostics["steps"]),
               "wall_s": time.perf_counter() - t0, "measures": measures}
    (out / f"{name}.json").write_text(json.dumps(summary, indent=1))
    np.savez_compressed(out / f"{name}.npz", **series)
    print(json.dumps({k: v for k, v in summary.items() if k != "measures"}))
    for k, v in measures.items():
        print(f"  {k:10s} t_A1 {v['t_A1']:.4f} P1 {v['P1']:.3f}  t_A2 {v['t_A2']:.4f} "
              f"P2 {v['P2']:.3f}  fluid p at A2 {v['fluid_p_A2']:.3f}")


if __name__ == "__main__":
    main()
