"""`airpuff sweep`: a grid of runs on Dask, stored as netCDF.

    airpuff sweep --E0 0.3,0.5,0.7 --IOP 10:25:4 --resolution coarse --out results/

Axes are given as a comma list or start:stop:num, in the units of `airpuff run` (E0 MPa, IOP mmHg,
thickness mm, pmax kPa); an axis left out takes the parameter's default.  Every other option of
`airpuff run` applies to all points.  Re-running the same command into the same --out folder
computes only the points that are missing.

Exit codes: 0 every point ok; 1 the sweep finished but some points failed (see the table and
sweep.nc); 2 bad input (one line on stderr naming the parameter and accepted range), or another
`airpuff sweep` is writing into the same --out (it holds OUT/sweep.lock; this one refuses at once
rather than wait behind a run of unknown length); 130 interrupted (finished points stay stored).
"""

from __future__ import annotations

import json
import sys

from airpuff_core.params import CHOICES, PARAMETERS, SWEPT, ParameterError
from api.settings import DEFAULT_MAX_POINTS, DEFAULT_TIME_LIMIT_S
from sweep.grid import AXIS_SYNTAX

from .common import RUN_OPTIONS, add_run_options, escape_percent, fail, parse_whole

PROG = "airpuff sweep"
DEFAULT_OUT = "sweep_out"
# Held in --out while a sweep runs: a second run into the same folder is refused (exit code 2).
LOCK_FILE = "sweep.lock"


def add_sweep_parser(sub) -> None:
    """Register the ``sweep`` sub-command on the ``airpuff`` parser."""
    p = sub.add_parser("sweep", help="run a parameter sweep on Dask", description=(
        "Run a grid over E0 x IOP x thickness x pmax on a Dask cluster; each point is stored as "
        "its own netCDF file, and all are combined into OUT/sweep.nc. Re-running the same sweep "
        "into the same OUT computes only the missing points."))
    for name in SWEPT:
        s = PARAMETERS[name]
        p.add_argument("--" + name, dest=name, metavar="LIST", default=None,
                       help=f"{s.description} [{s.unit}]: {AXIS_SYNTAX}; each value "
                            f"{s.accepted()}; default {s.default:g}")
    add_run_options(p, swept=False)
    escape_percent(p)
    p.add_argument("--workers", default="2", metavar="N",
                   help="number of local worker processes, one thread each (default 2)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="use the Dask scheduler at ADDRESS (e.g. tcp://host:8786) instead of "
                        "starting local workers; each point's file comes back through Dask, so "
                        "the workers need not see OUT")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"folder for the point files and sweep.nc (default {DEFAULT_OUT})")
    p.add_argument("--max-points", default=str(DEFAULT_MAX_POINTS), metavar="N",
                   help=f"largest grid accepted, as `airpuff serve` (default {DEFAULT_MAX_POINTS})")
    p.add_argument("--task-time-limit", default=f"{DEFAULT_TIME_LIMIT_S:g}", metavar="SECONDS",
                   help="wall-clock limit of one point; a point running longer is stopped (its "
                        f"worker restarted) and fails (default {DEFAULT_TIME_LIMIT_S:g})")
    p.add_argument("--retry-failed", action="store_true",
                   help="re-run points stored as failed by the model (a blow-up, no "
                        "convergence); failures of the infrastructure (a lost worker, a write "
                        "error) are re-run anyway")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (counts and the path of sweep.nc) instead of the table")
    p.set_defaults(func=sweep_command)


def spec_from_args(args, max_points: int = DEFAULT_MAX_POINTS):
    """The SweepSpec of parsed arguments; raises ParameterError on any bad value, and on a grid
    above ``max_points`` before any value of it is made."""
    from sweep.grid import SweepSpec, axis_length, check_grid_size, parse_axis

    texts = {name: getattr(args, name) for name in SWEPT if getattr(args, name, None) is not None}
    check_grid_size({name: axis_length(name, text) for name, text in texts.items()}, max_points,
                    " (raise the limit with --max-points)")
    axes = {name: parse_axis(name, text) for name, text in texts.items()}
    options = {}
    for name in list(RUN_OPTIONS) + list(CHOICES):
        v = getattr(args, name, None)
        if v is not None:
            options[name] = v
    return SweepSpec(**axes, options=options).validate()


def _whole(name: str, text, low: int = 1) -> int:
    try:
        n = parse_whole(str(text))
    except ValueError:
        raise ParameterError(name, text, f"a whole number >= {low}") from None
    if n < low:
        raise ParameterError(name, text, f"a whole number >= {low}")
    return n


def sweep_command(args) -> int:
    from sweep.combine import DamagedPointFiles
    from sweep.folder_lock import FolderLocked, hold_folder_lock
    from sweep.report import SweepProgress, summary_table
    from sweep.runner import run_sweep

    try:
        spec = spec_from_args(args, _whole("max-points", args.max_points))
        workers = _whole("workers", args.workers)
        time_limit = _whole("task-time-limit", args.task_time_limit)
    except ParameterError as err:
        fail(PROG, err)
    try:
        lock = hold_folder_lock(args.out, LOCK_FILE)
    except FolderLocked as err:
        fail(PROG, ValueError(f"another airpuff sweep is writing into --out {args.out} (it holds "
                              f"{LOCK_FILE}{', pid ' + err.holder if err.holder else ''}): wait "
                              "for it to end, or choose another --out"))
    except OSError as err:
        fail(PROG, ValueError(f"invalid --out {args.out!r}: accepted a writable folder "
                              f"({err.strerror})"))
    progress = None if args.json else SweepProgress()
    stopped = None  # (exit code, message) if the sweep did not finish
    try:
        outcome = run_sweep(spec, args.out, workers=workers, scheduler=args.scheduler,
                            progress=progress, retry_failed=args.retry_failed,
                            time_limit_s=float(time_limit))
    except KeyboardInterrupt:
        stopped = (130, f"interrupted; finished points are stored in {args.out}; "
                        "run the same command again to resume")
    except (OSError, TimeoutError, DamagedPointFiles) as err:
        # e.g. no scheduler at --scheduler, unwritable --out, point files that stay unreadable
        stopped = (1, f"error: {' '.join(str(err).split())}")
    finally:
        lock.close()
        if progress:
            progress.close()  # before any message: the bar's line ends first
    if stopped:
        sys.stderr.write(f"{PROG}: {stopped[1]}\n")
        return stopped[0]
    for w in outcome.warnings:
        sys.stderr.write(f"{PROG}: warning: {w}\n")
    if args.json:
        sys.stdout.write(json.dumps({
            "path": str(outcome.path), "n_points": outcome.n_points, "ok": outcome.ok,
            "failed": outcome.failed, "computed": outcome.computed, "reused": outcome.reused,
            "model_version": outcome.model_version,
            "wall_s": outcome.wall_s}) + "\n")
    else:
        print(summary_table(outcome))
    return 1 if outcome.failed else 0
