"""`airpuff run` and `airpuff plot`, and the run options shared with `airpuff sweep`.

Bad input exits with code 2 and one line on stderr naming the parameter and its accepted range.
The `airpuff` command itself is assembled in ``api/cli.py`` (the top of the dependency chain).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

from .params import CHOICE_DEFAULTS, CHOICE_DESCRIPTIONS, CHOICES, PARAMETERS, ParameterError, RunParams

# Options of `airpuff run` besides the four swept parameters.  Flags are spelled with dashes.
RUN_OPTIONS = (
    "R", "r_post", "alpha0", "rho_cornea", "rho_fluid", "mu", "nu", "fung_k", "a", "b", "T", "t0",
    "tait_gamma", "c0", "c_slope", "coupling_tol", "t_end", "hyperviscosity", "output_interval",
    "cfl",
)


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports errors in one line (exit code 2), without the usage block."""

    def error(self, message):  # noqa: D401 - argparse API
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def add_run_options(parser: argparse.ArgumentParser, swept: bool = True) -> None:
    """Add the run options (user units).  Values are parsed as strings and validated by
    RunParams, so that errors name the accepted range.  ``swept=False`` leaves out E0, IOP,
    thickness and pmax (the sweep gives those as lists)."""
    names = (("E0", "IOP", "thickness", "pmax") if swept else ()) + RUN_OPTIONS
    for name in names:
        s = PARAMETERS[name]
        parser.add_argument(flag(name), dest=name, metavar=s.unit if s.unit != "1" else "X",
                            default=None,
                            help=f"{s.description} [{s.unit}], {s.accepted()}, default {s.default:g}")
    for name, allowed in CHOICES.items():
        text = CHOICE_DESCRIPTIONS[name].replace("%", "%%")  # argparse formats help with %
        parser.add_argument(flag(name), dest=name, default=None, metavar="|".join(allowed),
                            help=f"{text} (default {CHOICE_DEFAULTS[name]})")


def params_from_args(args: argparse.Namespace, **overrides) -> RunParams:
    """RunParams from parsed options; raises ParameterError on bad values."""
    values = {}
    for name in list(PARAMETERS) + list(CHOICES):
        v = getattr(args, name, None)
        if v is not None:
            values[name] = v
    values.update(overrides)
    return RunParams.from_dict(values)


def fail(prog: str, err: Exception) -> None:
    sys.stderr.write(f"{prog}: error: {err}\n")
    raise SystemExit(2)


class TerminalProgress:
    """A one-line progress display on stderr (only when stderr is a terminal)."""

    def __init__(self, label: str, enabled: bool | None = None):
        self.label = label
        self.enabled = sys.stderr.isatty() if enabled is None else enabled
        self.start = time.monotonic()
        self.last = 0.0

    def __call__(self, t_ms: float, t_end_ms: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self.last < 0.2 and t_ms < t_end_ms:
            return
        self.last = now
        frac = min(1.0, t_ms / t_end_ms) if t_end_ms > 0 else 1.0
        elapsed = now - self.start
        eta = elapsed * (1 - frac) / frac if frac > 0 else float("nan")
        bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
        sys.stderr.write(f"\r{self.label} [{bar}] {t_ms:6.2f}/{t_end_ms:.2f} ms "
                         f"elapsed {elapsed:5.1f} s eta {eta:5.1f} s")
        sys.stderr.flush()

    def close(self):
        if self.enabled:
            sys.stderr.write("\n")
            sys.stderr.flush()


def add_run_parser(sub) -> None:
    p = sub.add_parser("run", help="run one coupled simulation", description=(
        "Run one air-puff simulation and print its ORA and Corvis-style metrics."))
    add_run_options(p)
    p.add_argument("--out", metavar="FILE.nc", default=None, help="write the run's netCDF here")
    p.add_argument("--json", action="store_true",
                   help="print exactly one JSON object with the metrics on stdout")
    p.set_defaults(func=run_command)


def format_metrics(metrics: dict, notes: dict | None = None) -> str:
    from .result import METRICS

    lines = []
    for name, (unit, long_name) in METRICS.items():
        v = metrics.get(name)
        if v is None or (isinstance(v, float) and not math.isfinite(v)):
            why = (notes or {}).get(name, "")
            lines.append(f"  {name:10s} {'missing':>10s}        {why}")
        else:
            lines.append(f"  {name:10s} {v:10.3f} {unit:6s} {long_name}")
    return "\n".join(lines)


def run_command(args) -> int:
    from . import simulate
    from .errors import SimulationError

    prog = "airpuff run"
    try:
        params = params_from_args(args)
    except ParameterError as err:
        fail(prog, err)
    progress = TerminalProgress(f"run {params.resolution}") if not args.json else None
    t_start = time.monotonic()
    try:
        result = simulate(params, progress=progress)
    except SimulationError as err:
        if progress:
            progress.close()
        sys.stderr.write(f"{prog}: simulation failed: {err}\n")
        return 1
    if progress:
        progress.close()
    wall = time.monotonic() - t_start
    if args.out:
        from .dataset import write_netcdf

        write_netcdf(result.to_dataset(), args.out)
    if args.json:
        out = result.metrics_json()
        sys.stdout.write(json.dumps(out) + "\n")
    else:
        d = result.diagnostics
        print(f"airpuff run: {params.resolution} resolution, {d.get('n_fluid')} fluid nodes, "
              f"{d.get('n_cornea')} cornea nodes, {d.get('steps')} steps, "
              f"dt {d.get('dt_mean_us', float('nan')):.3g} us, wall {wall:.1f} s")
        print(format_metrics(result.metrics, result.metric_notes))
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
    import os

    prog = "airpuff plot"
    if not os.path.isfile(args.run):
        fail(prog, ValueError(f"invalid RUN.nc={args.run!r}: accepted an existing netCDF file"))
    from .plots import plot_run

    try:
        paths = plot_run(args.run, args.out)
    except (OSError, KeyError, ValueError) as err:
        fail(prog, ValueError(f"invalid RUN.nc={args.run!r}: accepted a run netCDF written by "
                              f"airpuff ({type(err).__name__}: {err})"))
    for p in paths:
        print(p)
    return 0
