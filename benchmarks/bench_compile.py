"""Start-up of a solver process: cold (empty Numba cache: compiles) and warm (cache filled).

"Warm worker start" is the wall time from launching a fresh Python process, with the environment
of a sweep worker (one thread each for Numba, OpenMP and BLAS: ``sweep.cluster.WORKER_THREAD_ENV``)
and a filled Numba cache, until it has imported the solver and finished a tiny run (coarse,
0.05 ms).  It is split into

* interpreter: launch until the first line of the script runs (Python and site start-up);
* import: ``import airpuff_core.solver`` (numpy, Numba, the solver's modules);
* first run: ``simulate(RunParams(t_end=0.05))``, mostly Numba's one-time set-up and loading each
  kernel from the cache, then the model set-up (static equilibrium) and a few steps.

Process exit is timed too but is no part of the start (a worker does not exit after its first
run).  Each phase is timed on the system-wide monotonic clock, shared by parent and child.  The
machine may be busy (another process on the cores stretches every phase), so the warm start is
repeated and the minimum and median are printed; a warm run that compiled anything is flagged.

    python -m benchmarks.bench_compile                  # cold start, then 5 warm starts
    python -m benchmarks.bench_compile --cache DIR      # warm starts only, on the cache in DIR
    python -m benchmarks.bench_compile --repeat 9
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from sweep.cluster import WORKER_THREAD_ENV  # stdlib only: no solver import here

ROOT = Path(__file__).resolve().parents[1]

CLOCK = time.CLOCK_MONOTONIC  # system-wide on Linux: comparable between parent and child

# The child: timestamps on CLOCK, and the CPU time used so far by the process, when the interpreter
# is up, after the import and after the run; then (untimed) the Numba statistics, to tell a warm
# start from one that compiled.
CHILD = """
import time
C = time.CLOCK_MONOTONIC
t_main, c_main = time.clock_gettime(C), time.process_time()
import airpuff_core.solver
t_import, c_import = time.clock_gettime(C), time.process_time()
airpuff_core.simulate(airpuff_core.RunParams(t_end=0.05))
t_run, c_run = time.clock_gettime(C), time.process_time()
import json
from sweep.numba_cache import jit_counts
n = jit_counts()
print(json.dumps({"t_main": t_main, "t_import": t_import, "t_run": t_run,
                  "c_main": c_main, "c_import": c_import, "c_run": c_run,
                  "compiled": sum(v[1] for v in n.values()),
                  "loaded": sum(v[0] for v in n.values())}))
"""

PHASES = ("start", "interpreter", "import", "first_run", "exit", "cpu_start", "cpu_import",
          "cpu_first_run")


def start_once(cache_dir: str) -> dict[str, float]:
    """One fresh process: its phase durations [s] and Numba compile/load counts."""
    env = dict(os.environ, **WORKER_THREAD_ENV, NUMBA_CACHE_DIR=cache_dir)
    t_launch = time.clock_gettime(CLOCK)
    out = subprocess.run([sys.executable, "-c", CHILD], env=env, cwd=ROOT, capture_output=True,
                         text=True, check=True)
    t_exit = time.clock_gettime(CLOCK)
    c = json.loads(out.stdout.strip().splitlines()[-1])
    return {"start": c["t_run"] - t_launch, "interpreter": c["t_main"] - t_launch,
            "import": c["t_import"] - c["t_main"], "first_run": c["t_run"] - c["t_import"],
            "exit": t_exit - c["t_run"], "compiled": c["compiled"], "loaded": c["loaded"],
            # CPU time of the child [s]: what the start costs on an idle core (the wall times
            # above also contain waiting for a core when other processes run)
            "cpu_start": c["c_run"], "cpu_import": c["c_import"] - c["c_main"],
            "cpu_first_run": c["c_run"] - c["c_import"]}


def warm_starts(cache_dir: str, repeat: int) -> dict[str, dict[str, float]]:
    """``repeat`` warm starts: min and median of each phase [s], and the largest compile count."""
    runs = [start_once(cache_dir) for _ in range(repeat)]
    stats = {p: {"min": min(r[p] for r in runs), "median": statistics.median(r[p] for r in runs)}
             for p in PHASES}
    stats["compiled"] = max(r["compiled"] for r in runs)
    stats["loaded"] = max(r["loaded"] for r in runs)
    return stats


def report_warm(s: dict) -> None:
    def fig(p):
        return f"{s[p]['min']:.2f} s (median {s[p]['median']:.2f} s)"

    def cpu(p):
        return f"{s[p]['min']:.2f} s"

    print(f"warm worker start: {fig('start')}   [CPU time {cpu('cpu_start')}]")
    print(f"  interpreter      {fig('interpreter')}")
    print(f"  import           {fig('import')}   [CPU {cpu('cpu_import')}]")
    print(f"  first run        {fig('first_run')}   [CPU {cpu('cpu_first_run')}; "
          f"{s['loaded']} kernels loaded from the cache, {s['compiled']} compiled]")
    print(f"  (process exit    {fig('exit')}, not part of the start)")
    if s["compiled"]:
        print("  WARNING: a warm start compiled kernels: the cache was not (fully) warm")
    if sys.flags.dont_write_bytecode or os.environ.get("PYTHONDONTWRITEBYTECODE"):
        print("  note: PYTHONDONTWRITEBYTECODE is set, so the project's own modules are compiled "
              "to bytecode in every start (an installed package has its .pyc files)")


def main(argv=()):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", help="use this Numba cache folder (warmed first if needed) and "
                                    "skip the cold start")
    ap.add_argument("--repeat", type=int, default=5, help="warm starts to time (default 5)")
    args = ap.parse_args(list(argv))

    if args.cache:
        Path(args.cache).mkdir(parents=True, exist_ok=True)
        start_once(args.cache)  # fills the cache if it is empty or stale; not timed
        stats = warm_starts(args.cache, args.repeat)
        report_warm(stats)
        return None, stats
    with tempfile.TemporaryDirectory() as cache:
        cold = start_once(cache)
        stats = warm_starts(cache, args.repeat)
    print(f"cold start (empty Numba cache): {cold['start']:.1f} s = import {cold['import']:.2f} s "
          f"+ compile and run {cold['first_run']:.1f} s ({cold['compiled']} kernels compiled)")
    report_warm(stats)
    return cold, stats


if __name__ == "__main__":
    main(sys.argv[1:])
