"""`airpuff run` (one simulation, its metrics and netCDF) and `airpuff plot` (its figures)."""

from __future__ import annotations

import json
import math
import os
import sys
import time

from airpuff_core.params import ParameterError

from .common import TerminalProgress, add_run_options, fail, params_from_args


def add_run_parser(sub) -> None:
    p = sub.add_parser("run", help="run one coupled simulation", description=(
        "Run one air-puff simulation and print its ORA and Corvis-style metrics."))
    add_run_options(p)
    p.add_argument("--out", metavar="FILE.nc", default=None, help="write the run's netCDF here")
    p.add_argument("--json", action="store_true",
                   help="print exactly one JSON object with the metrics on stdout (raw, and "
                        "calibrated: <name>_cal and the calibration used or why none)")
    p.add_argument("--threads", metavar="N", default=None,
                   help="threads of the solver's kernels, 1 to the cores Numba sees (default all "
                        "of them); the results do not depend on it")
    p.set_defaults(func=run_command)


def format_metrics(metrics: dict, notes: dict | None = None) -> str:
    from airpuff_core.result import METRICS

    lines = []
    for name, (unit, long_name) in METRICS.items():
        v = metrics.get(name)
        if v is None or (isinstance(v, float) and not math.isfinite(v)):
            why = (notes or {}).get(name, "")
            lines.append(f"  {name:10s} {'missing':>10s}        {why}")
        else:
            lines.append(f"  {name:10s} {v:10.3f} {unit:6s} {long_name}")
    return "\n".join(lines)


def format_calibrated(values: dict, calibration: str) -> str:
    """The calibrated readings (``airpuff_core.calibration.CALIBRATED``) under the raw metrics,
    with the calibration used or why there is none."""
    from airpuff_core.calibration import CALIBRATED

    lines = [f"  calibration: {calibration}"]
    for name, (unit, long_name) in CALIBRATED.items():
        v = values.get(name, math.nan)
        if math.isfinite(v):
            lines.append(f"  {name:13s} {v:10.3f} {unit:6s} {long_name}")
        else:
            lines.append(f"  {name:13s} {'missing':>10s}")
    return "\n".join(lines)


def run_command(args) -> int:
    from airpuff_core import simulate
    from airpuff_core.budget import check_step_budget
    from airpuff_core.errors import SimulationError
    from airpuff_core.threads import check_threads

    prog = "airpuff run"
    try:
        params = params_from_args(args)
        check_step_budget(params)
        threads = check_threads(args.threads)
    except ParameterError as err:
        fail(prog, err)
    progress = TerminalProgress(f"run {params.resolution}") if not args.json else None
    t_start = time.monotonic()
    failure = None
    try:
        result = simulate(params, progress=progress, threads=threads)
    except SimulationError as err:
        failure = err
    finally:
        if progress:
            progress.close()  # before any message: the bar's line ends first
    if failure is not None:
        sys.stderr.write(f"{prog}: simulation failed: {failure}\n")
        return 1
    wall = time.monotonic() - t_start
    if args.out:
        from airpuff_core.dataset import write_netcdf

        write_netcdf(result.to_dataset(), args.out)
    from airpuff_core.calibration import calibrate_metrics
    from airpuff_core.provenance import model_version

    calibrated, cal, reason = calibrate_metrics(params.to_dict(), result.metrics,
                                                model_version())
    calibration = cal.label if cal is not None else f"none: {reason}"
    if args.json:
        out = result.metrics_json()
        out.update({k: (v if math.isfinite(v) else None) for k, v in calibrated.items()})
        out["calibration"] = calibration
        sys.stdout.write(json.dumps(out) + "\n")
    else:
        d = result.diagnostics
        print(f"airpuff run: {params.resolution} resolution, {d.get('n_fluid')} fluid nodes, "
              f"{d.get('n_cornea')} cornea nodes, {d.get('steps')} steps, "
              f"dt {d.get('dt_mean_us', float('nan')):.3g} us, wall {wall:.1f} s on "
              f"{d.get('threads')} thread(s)")
        print(format_metrics(result.metrics, result.metric_notes))
        print(format_calibrated(calibrated, calibration))
        if args.out:
            print(f"wrote {args.out}")
    return 0


def add_plot_parser(sub) -> None:
    p = sub.add_parser("plot", help="write the paper's figures from a run's netCDF",
                       description="Write apex_and_jet.png, hysteresis.png, applanation.png and "
                                   "shapes.png from the netCDF of one run.")
    p.add_argument("run", metavar="RUN.nc", help="netCDF written by `airpuff run --out`")
    p.add_argument("--out", metavar="DIR", default=".", help="folder for the PNG files")
    p.set_defaults(func=plot_command)


def plot_command(args) -> int:
    prog = "airpuff plot"
    if not os.path.isfile(args.run):
        fail(prog, ValueError(f"invalid RUN.nc={args.run!r}: accepted an existing netCDF file"))
    from airpuff_core.plots import plot_run

    try:
        paths = plot_run(args.run, args.out)
    except (OSError, KeyError, ValueError) as err:
        fail(prog, ValueError(f"invalid RUN.nc={args.run!r}: accepted a run netCDF written by "
                              f"airpuff ({type(err).__name__}: {err})"))
    for p in paths:
        print(p)
    return 0
