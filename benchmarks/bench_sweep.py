"""Sweep throughput on a LocalCluster of 1 and of 2 worker processes, in the steady state.

Throughput [points/min] = points / (time from the cluster being ready to the last point done).
"Ready" means: the client is connected, the workers are checked (one task thread each, Numba,
OpenMP and BLAS pools limited to one thread) and warm -- each has run one tiny point
(``sweep.cluster.warm_workers``: imports, Numba's set-up, kernels loaded from the cache), through
``run_sweep``'s ``on_cluster_ready`` hook.  The start-up before that (the Numba warm-up in this
process, starting the cluster, warming the workers) and the end after the last point (combining
``sweep.nc``, closing the cluster) are printed separately: they are paid once per sweep, not per
point, and would hide the scaling of a short sweep.

Same grid for 1 and 2 workers: 16 coarse points of 35 ms, the default run (E0 x IOP = 4 x 4;
``--points 8``: 4 x 2), each measurement in a fresh output folder.  Points differ in cost, so at
the end of a sweep one worker may idle while the other finishes its last point; that end effect
is part of the figure.  It weighs less in a longer sweep (its share with 8 and with 16 points:
docs/performance.md), and the sweeps this service runs have tens to hundreds of points.

Per worker, the solver time of its points (``wall_s`` of the records) is summed: busy / steady
close to 1 means the worker never waited for work (the rest, about 0.1 s a point, is writing the
point's netCDF file and Dask's bookkeeping); a mean point time that grows with the number of
workers means the workers slow each other down (shared cores, caches or memory bandwidth, or
other load on the machine).

    python -m benchmarks.bench_sweep                # 1 worker, then 2
    python -m benchmarks.bench_sweep --workers 2    # one configuration only
    python -m benchmarks.bench_sweep --repeat 3     # 1, 2, 1, 2, 1, 2 workers; medians compared
    python -m benchmarks.bench_sweep --points 8     # 8 points instead of 16
    python -m benchmarks.bench_sweep --workers 2 --clinical-paper 100   # a sweep's real points

``--clinical-paper N``: N clinical-preset points at paper resolution, the unit of work of a
clinical sweep (IOP 10-25 mmHg x CCT 0.45-0.65 mm, a grid of a x b = N values, a >= b).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

from airpuff_core.params import RunParams
from sweep.cluster import warm_workers
from sweep.grid import SweepSpec
from sweep.runner import run_sweep


def grid(t_end: float = 35.0, points: int = 16) -> SweepSpec:
    """``points`` (8 or 16) coarse points of ``t_end`` [ms]: 4 values of E0 times 2 or 4 of IOP
    (about 2-3 s of solver time each at 35 ms)."""
    iop = {8: [12.0, 20.0], 16: [12.0, 16.0, 20.0, 24.0]}[points]
    return SweepSpec(E0=[0.4, 0.5, 0.6, 0.7], IOP=iop, thickness=[0.5], pmax=[10.0],
                     options={"resolution": "coarse", "t_end": t_end})


def clinical_paper_grid(points: int) -> SweepSpec:
    """``points`` clinical-preset points at paper resolution: IOP x CCT over the clinic's range,
    a x b = points values (b the largest divisor of points not above its square root)."""
    b = max(d for d in range(1, int(points ** 0.5) + 1) if points % d == 0)
    a = points // b
    iop = [round(10.0 + 15.0 * k / max(1, a - 1), 3) for k in range(a)]
    cct = [round(0.45 + 0.2 * k / max(1, b - 1), 4) for k in range(b)]
    return SweepSpec(IOP=iop, thickness=cct,
                     options={"resolution": "paper", "model": "clinical"})


def measure(workers: int, spec: SweepSpec) -> dict:
    """One sweep of ``spec`` on a new LocalCluster of ``workers`` processes; times [s]."""
    marks: dict = {"done": []}

    def on_ready(client):
        client.wait_for_workers(workers, timeout=120)
        marks["warm"] = warm_workers(client, RunParams.from_dict(spec.options))
        marks["ready"] = time.perf_counter()

    def on_progress(record, counts):
        if record is not None:
            marks["done"].append(time.perf_counter())

    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        outcome = run_sweep(spec, out, workers=workers, on_cluster_ready=on_ready,
                            progress=on_progress)
        t_end = time.perf_counter()
    steady = marks["done"][-1] - marks["ready"]
    per_worker: dict = {}
    for rec in outcome.records:
        w = per_worker.setdefault(rec.pid, {"points": 0, "busy": 0.0})
        w["points"] += 1
        w["busy"] += rec.wall_s or 0.0
    return {"workers": workers, "points": outcome.computed, "failed": outcome.failed,
            "startup": marks["ready"] - t0, "client_warmup": outcome.warmup_s,
            "worker_warmup": marks["warm"], "steady": steady,
            "finish": t_end - marks["done"][-1], "wall": t_end - t0,
            "rate": outcome.computed / steady * 60.0, "per_worker": per_worker,
            "mean_point": sum(w["busy"] for w in per_worker.values()) / max(1, outcome.computed),
            "point_range": (min(r.wall_s or 0.0 for r in outcome.records),
                            max(r.wall_s or 0.0 for r in outcome.records)),
            "warnings": outcome.warnings}


def report(m: dict) -> None:
    warm = m["worker_warmup"]
    warm_s = ", ".join(f"{r.get('seconds', float('nan')):.2f} s"
                       + ("" if r.get("status") == "ok" else f" ({r.get('message')})")
                       + (f" [{r['jit_compiled']} kernels COMPILED]" if r.get("jit_compiled")
                          else "")
                       for r in warm.values())
    print(f"sweep, {m['workers']} worker(s): {m['points']} points in {m['steady']:.1f} s "
          f"steady state = {m['rate']:.1f} points/min "
          f"(solver time per point {m['mean_point']:.2f} s, "
          f"{m['point_range'][0]:.2f}-{m['point_range'][1]:.2f} s)")
    print(f"  start-up {m['startup']:.1f} s (Numba warm-up here {m['client_warmup']:.1f} s, "
          f"workers warmed in {warm_s}); after the last point {m['finish']:.1f} s; "
          f"wall {m['wall']:.1f} s")
    for pid, w in sorted(m["per_worker"].items()):
        print(f"  worker pid {pid}: {w['points']} points, busy {w['busy']:.1f} s "
              f"({w['busy'] / m['steady']:.0%} of the steady state)")
    for warning in m["warnings"]:
        print(f"  WARNING: {warning}")
    if m["failed"]:
        print(f"  WARNING: {m['failed']} points failed")


def main(argv=()):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", default="1,2", help="worker counts to measure (default 1,2)")
    ap.add_argument("--t-end", type=float, default=35.0,
                    help="simulated time per point [ms] (default 35, a whole default run)")
    ap.add_argument("--points", type=int, choices=(8, 16), default=16,
                    help="grid size (default 16); the last points leave a worker idle while "
                         "another finishes, which weighs less in a longer sweep")
    ap.add_argument("--clinical-paper", type=int, default=0, metavar="N",
                    help="N clinical-preset points at paper resolution instead (module docstring)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="measure each worker count this many times, alternating (default 1); "
                         "the median throughput is compared")
    args = ap.parse_args(list(argv))
    counts = [int(w) for w in args.workers.split(",")]
    print(f"sweep benchmark: {os.cpu_count()} cores, load average "
          f"{', '.join(f'{v:.2f}' for v in os.getloadavg())} (other load slows the workers)")
    spec = (clinical_paper_grid(args.clinical_paper) if args.clinical_paper
             else grid(args.t_end, args.points))
    rates: dict[int, list[float]] = {w: [] for w in counts}
    for _ in range(args.repeat):
        for workers in counts:
            m = measure(workers, spec)
            report(m)
            rates[workers].append(m["rate"])
    median = {w: statistics.median(r) for w, r in rates.items()}
    if 1 in median and len(median) > 1:
        for workers, rate in median.items():
            if workers != 1:
                speedup = rate / median[1]
                print(f"sweep speed-up {workers} workers / 1 worker (steady state"
                      f"{', medians' if args.repeat > 1 else ''}): {speedup:.2f} "
                      f"(parallel efficiency {speedup / workers:.0%})")
    return median


if __name__ == "__main__":
    main(sys.argv[1:])
