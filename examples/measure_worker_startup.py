"""Measure what a warmed Numba cache saves a sweep's workers (cold start vs warm start).

    python examples/measure_worker_startup.py [--points 4] [--t-end 3]

Each mode runs in a fresh process with a NUMBA_CACHE_DIR in a temporary folder, starts a LocalCluster of 2 worker processes (one thread each) and runs the same short
coarse points through ``sweep.worker.compute_point``:

* cold: no warm-up -- every worker compiles the solver's kernels itself, both at once into the
  same empty cache (the situation the runner avoids);
* warm: ``sweep.numba_cache.warm_numba_cache()`` in the client first (what ``run_sweep`` does), so the
  workers only load compiled code;
* rewarm: as warm, with the cache that warm filled (a later sweep): the client only loads too.

Reported per mode: the client warm-up, the wall time of the first point on each worker (which
carries the compilation or the cache load) and of the later points, the Numba compiles and cache
loads counted inside the workers, and the total wall time from submission to the last result.
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


def measure(mode: str, n_points: int, t_end: float) -> dict:
    """Runs in the child process; NUMBA_CACHE_DIR is already set to an empty folder."""
    from distributed import as_completed

    from sweep.cluster import close_client, make_client
    from sweep.numba_cache import warm_numba_cache
    from sweep.grid import SweepSpec
    from sweep.worker import compute_point

    spec = SweepSpec(E0=[0.4 + 0.05 * i for i in range(n_points)],
                     options={"resolution": "coarse", "t_end": t_end}).validate()
    warmup = None if mode == "cold" else warm_numba_cache()
    t0 = time.perf_counter()
    client = make_client(workers=2)
    try:
        client.wait_for_workers(2)
        t_cluster = time.perf_counter() - t0
        t1 = time.perf_counter()
        futures = [client.submit(compute_point, p, pure=False) for p in spec.points()]
        records = [f.result()[0] for f in as_completed(futures)]
        t_points = time.perf_counter() - t1
    finally:
        close_client(client)
    return {"mode": mode, "warmup_s": warmup, "cluster_start_s": t_cluster, "points_s": t_points,
            "records": [{k: getattr(r, k) for k in ("pid", "first_in_process", "wall_s", "jit_compiled",
                                           "jit_loaded", "status")} for r in records]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--points", type=int, default=4, help="points per mode (default 4)")
    parser.add_argument("--t-end", type=float, default=3.0, help="simulated time per point [ms]")
    parser.add_argument("--child", choices=("cold", "warm", "rewarm"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args.child:
        print(json.dumps(measure(args.child, args.points, args.t_end)))
        return 0

    results = []
    with tempfile.TemporaryDirectory(prefix="airpuff-numba-") as tmp:
        # cold and warm start from empty caches; "rewarm" reuses warm's cache (a second sweep)
        for mode, cache in (("cold", "a"), ("warm", "b"), ("rewarm", "b")):
            env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(tmp, cache))
            out = subprocess.run([sys.executable, __file__, "--child", mode, "--points",
                                  str(args.points), "--t-end", str(args.t_end)],
                                 env=env, capture_output=True, text=True, check=True)
            result = json.loads(out.stdout.strip().splitlines()[-1])
            result["mode"] = mode
            results.append(result)

    print(f"{args.points} coarse points of {args.t_end:g} ms on a LocalCluster of 2 worker processes; "
          "cold and warm start with an empty NUMBA_CACHE_DIR, rewarm with warm's filled cache\n")
    print(f"{'mode':7s} {'client warm-up':>15s} {'1st point/worker':>22s} {'later points':>14s} "
          f"{'worker compiles':>16s} {'cache loads':>12s} {'points wall':>12s}")
    for res in results:
        recs = res["records"]
        first = sorted(r["wall_s"] for r in recs if r["first_in_process"])
        later = [r["wall_s"] for r in recs if not r["first_in_process"]]
        warm = "-" if res["warmup_s"] is None else f"{res['warmup_s']:.1f} s"
        print(f"{res['mode']:7s} {warm:>15s} {', '.join(f'{w:.1f}' for w in first) + ' s':>22s} "
              f"{(f'{statistics.mean(later):.1f} s' if later else '-'):>14s} "
              f"{sum(r['jit_compiled'] for r in recs):>16d} {sum(r['jit_loaded'] for r in recs):>12d} "
              f"{res['points_s']:>10.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
