"""The clinical preset against the artificial sound speed: c0 = 10, 20, 40 m/s (c_slope = 2 c0).

The weakly compressible fluid is right only where the results do not depend on c (docs/model.md
section 4).  This study runs the clinical preset (normal eye: CCT 0.54 mm) at each IOP and sound
speed and reports, per run, P1, P2, CH, DA, the chamber's acoustic ringing (rms of the fluid's mean
wall pressure minus the globe's pressure, t > 1 ms) and the parts of CH at the apex (the apex force
budget, docs/model.md section 7), how near the apex's rebound after the second applanation comes
to a further one (``rebound_dip``), how far P2 moves for an error of 0.01/mm in the apex
curvature at A2 (``p2_conditioning``), and per IOP the largest change of each metric from c0 = 10.
Tolerances (docs/validation.md): P1, P2 0.2 mmHg, CH 0.3 mmHg, DA 0.01 mm.

The whole matrix of issue 25 (paper resolution at IOP 10, 16, 25; fine resolution for the normal
eye, IOP 16; c0 = 10, 20, 40 each), on two processes (the preset sets the seven stabilisations
that make it independent of c, ``SOUND_SPEED_OPTIONS`` of airpuff_core/params.py; ``--set
NAME=0`` switches one off):

    python -m studies.clinical_sound_speed --out soundspeed --fine-IOP 16 --workers 2

Every finished run is kept as <out>/<name>.nc; --reuse reads back a run whose file has the same
parameters.  A failed run (blow-up) is a row with its message.  The table (with the model
version) goes to <out>/table.md and <out>/rows.json.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import math
import multiprocessing
import time
from pathlib import Path

import numpy as np

from airpuff_core import RunParams, SimulationError, simulate
from airpuff_core.dataset import open_dataset, params_from_dataset, write_netcdf
from airpuff_core.provenance import model_version
from sweep.numba_cache import warm_numba_cache

TOLERANCE = {"P1": 0.2, "P2": 0.2, "CH": 0.3, "DA": 0.01}
FORMAT = {"DA": "%.3f", "rebound_dip": "%.3f", "convex_crossings": "%d"}
PARTS = ("CH_profile", "CH_fluid", "CH_equilibrium", "CH_overstress", "CH_inertia", "CH_residual")


def ringing_rms(ds) -> float:
    """rms [mmHg] of the fluid's mean wall pressure minus the globe's pressure, t > 1 ms."""
    if "wall_pressure" not in ds:
        return math.nan
    t = ds["time"].values
    dev = (ds["wall_pressure"] - ds["globe_pressure"]).values[t > 1.0]
    return float(np.sqrt(np.nanmean(dev ** 2)))


def rebound_dip(ds, window_ms=3.0):
    """How near the apex comes to a further applanation after the cornea first turns convex again:
    (the smallest apex curvature [1/mm] after the curvature's first peak within ``window_ms`` of
    the first concave -> convex crossing following A1 (NaN without such a rebound), the number of
    concave -> convex crossings after A1).  A2 is the last such crossing (docs/model.md section
    7), so where the rebound dips to within a few 0.01/mm of zero, a small change of the run moves
    A2 across the rebound and P2 by the jet's fall over it (several mmHg)."""
    t = ds["time"].values
    kappa = ds["apex_curvature"].values
    after = t > float(ds["t_A1"])
    t, kappa = t[after], kappa[after]
    up = np.flatnonzero((kappa[:-1] < 0) & (kappa[1:] >= 0))
    if up.size == 0:
        return math.nan, 0
    start = up[0] + 1
    window = kappa[start:np.searchsorted(t, t[start] + window_ms, side="right")]
    peaks = np.flatnonzero(np.diff(window) <= 0)  # the first sample from which it falls
    if peaks.size == 0:
        return math.nan, int(up.size)
    return float(window[peaks[0]:].min()), int(up.size)


def p2_conditioning(ds, half_width_ms=0.1, curvature_error=0.01):
    """How far P2 moves [mmHg] for an error of ``curvature_error`` [1/mm] in the apex curvature:
    the jet's fall over the time the curvature takes to change by that much at A2, from the
    histories' slopes over +-``half_width_ms``.  Where the apex creeps through flat (a slow
    crossing while the jet falls ~8 mmHg/ms) this is several mmHg."""
    t_a2 = float(ds["t_A2"])
    if not math.isfinite(t_a2):
        return math.nan
    t = ds["time"].values
    lo, hi = t_a2 - half_width_ms, t_a2 + half_width_ms
    dkappa = np.interp(hi, t, ds["apex_curvature"].values) - np.interp(lo, t, ds["apex_curvature"].values)
    djet = np.interp(hi, t, ds["jet_pressure_apex"].values) - np.interp(lo, t, ds["jet_pressure_apex"].values)
    return float(abs(djet / dkappa) * curvature_error) if dkappa else math.inf


def row_of(ds) -> dict:
    row = {k: float(ds[k]) for k in ("P1", "P2", "CH", "DA", "IOPg", "t_A1", "t_A2")}
    row["ringing_rms"] = ringing_rms(ds)
    row["rebound_dip"], row["convex_crossings"] = rebound_dip(ds)
    row["P2_per_0.01_curvature"] = p2_conditioning(ds)
    for k in PARTS:
        row[k] = float(ds[k]) if k in ds else math.nan
    row["wall_s"] = float(ds.attrs.get("solver_wall_s", math.nan))
    return row


def run(name, params, out, reuse):
    nc = out / f"{name}.nc"
    if reuse and nc.exists():
        with open_dataset(nc) as ds:
            if params_from_dataset(ds).to_dict() == params.to_dict():
                return {"status": "ok", **row_of(ds)}
    t0 = time.perf_counter()
    try:
        result = simulate(params)
    except SimulationError as err:
        return {"status": "failed", "message": str(err), "wall_s": time.perf_counter() - t0}
    write_netcdf(result.to_dataset(), nc)
    with open_dataset(nc) as ds:
        return {"status": "ok", **row_of(ds)}


def run_points(points, out, reuse=False, workers=1, report=None):
    """``run`` each (name, RunParams) of ``points``, in ``workers`` processes (1: in this one),
    the costliest first (finer resolution, higher c0) so that the processes finish together.
    Returns {name: row}; ``report(name, row)`` is called as each run ends."""
    cost = {"coarse": 0, "paper": 1, "fine": 2}
    points = sorted(points, key=lambda p: (cost[p[1].resolution], p[1].c0), reverse=True)
    rows = {}

    def done(name, row):
        rows[name] = row
        if report is not None:
            report(name, row)

    if workers <= 1:
        for name, params in points:
            done(name, run(name, params, out, reuse))
        return rows
    # Compiled here first, so that the workers load the kernels from the Numba cache instead of
    # compiling into it at once (sweep/numba_cache.py); spawn: fresh interpreters, no fork of
    # this process's Numba state.
    warm_numba_cache(points[0][1])
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(workers, mp_context=ctx) as pool:
        futures = {pool.submit(run, name, params, out, reuse): name for name, params in points}
        for future in concurrent.futures.as_completed(futures):
            done(futures[future], future.result())
    return rows


def table(rows, c0s, groups) -> str:
    """The rows of each (resolution, IOPs, name prefix) of ``groups`` at each c0, then per
    resolution and IOP the largest change of each metric from the first c0."""
    cols = ("P1", "P2", "CH", "DA", "ringing_rms", "rebound_dip", "convex_crossings",
            "P2_per_0.01_curvature") + PARTS + ("wall_s",)
    lines = [f"Model version {model_version()}.", "",
             "| resolution | IOP | c0 | " + " | ".join(cols) + " | status |",
             "|" + "---|" * (len(cols) + 4)]
    for resolution, iops, prefix in groups:
        for iop in iops:
            for c0 in c0s:
                r = rows[f"{prefix}IOP{iop:g}_c{c0:g}"]
                head = f"| {resolution} | {iop:g} | {c0:g} | "
                if r["status"] != "ok":
                    lines.append(head + " | ".join("" for _ in cols) + f" | {r['message']} |")
                    continue
                lines.append(head + " | ".join(FORMAT.get(k, "%.2f") % r[k] for k in cols)
                             + " | ok |")
    lines += ["", "Largest change from c0 = %g (tolerance):" % c0s[0], "",
              "| resolution | IOP | " + " | ".join(f"{k} ({v:g})" for k, v in TOLERANCE.items())
              + " | within |", "|" + "---|" * (len(TOLERANCE) + 3)]
    for resolution, iops, prefix in groups if len(c0s) > 1 else ():
        for iop in iops:
            base = rows[f"{prefix}IOP{iop:g}_c{c0s[0]:g}"]
            others = [rows[f"{prefix}IOP{iop:g}_c{c0:g}"] for c0 in c0s[1:]]
            head = f"| {resolution} | {iop:g} | "
            if base["status"] != "ok" or any(o["status"] != "ok" for o in others):
                lines.append(head + " | ".join("failed" for _ in TOLERANCE) + " | no |")
                continue
            change = {k: max(abs(o[k] - base[k]) for o in others) for k in TOLERANCE}
            ok = all(change[k] < TOLERANCE[k] for k in TOLERANCE)
            lines.append(head + " | ".join(
                ("%.4f" if k == "DA" else "%.3f") % change[k] for k in TOLERANCE)
                + f" | {'yes' if ok else 'no'} |")
    return "\n".join(lines) + "\n"


def sound_speed_points(iops, c0s, resolution, extra):
    """(name, RunParams) of the clinical preset's normal eye (thickness 0.54 mm) at each IOP
    [mmHg] and base sound speed c0 [m/s] (c_slope = 2 c0), ``extra`` any other parameters."""
    for iop in iops:
        for c0 in c0s:
            yield f"IOP{iop:g}_c{c0:g}", RunParams.from_dict(
                {"model": "clinical", "thickness": 0.54, "IOP": iop, "c0": c0,
                 "c_slope": 2 * c0, "resolution": resolution, **extra})


def sound_speed_parser(description, resolution):
    """The options of a study over ``sound_speed_points`` (``resolution``: the default)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--resolution", default=resolution, choices=("coarse", "paper", "fine"))
    ap.add_argument("--c0", default="10,20,40", help="base sound speeds [m/s]; c_slope = 2 c0")
    ap.add_argument("--IOP", default="10,16,25", help="true IOPs [mmHg]")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="any other run parameter")
    ap.add_argument("--reuse", action="store_true")
    return ap


def main(argv=None):
    ap = sound_speed_parser(__doc__.splitlines()[0], "paper")
    ap.add_argument("--fine-IOP", default="",
                    help="true IOPs [mmHg] also run at fine resolution (issue 25: 16)")
    ap.add_argument("--workers", type=int, default=1, help="processes running the points")
    args = ap.parse_args(argv)
    c0s = [float(v) for v in args.c0.split(",")]
    iops = [float(v) for v in args.IOP.split(",")]
    extra = dict(s.split("=", 1) for s in args.set)
    groups = [(args.resolution, iops, "")]
    if args.fine_IOP and args.resolution != "fine":
        groups.append(("fine", [float(v) for v in args.fine_IOP.split(",")], "fine_"))
    points = [(prefix + name, params) for resolution, group_iops, prefix in groups
              for name, params in sound_speed_points(group_iops, c0s, resolution, extra)]
    args.out.mkdir(parents=True, exist_ok=True)
    finished = {}

    def report(name, row):
        finished[name] = row
        print(name, json.dumps(row), flush=True)
        (args.out / "rows.json").write_text(json.dumps(finished, indent=1))

    rows = run_points(points, args.out, args.reuse, args.workers, report)
    text = table(rows, c0s, groups)
    (args.out / "table.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
