"""How the cost of a default run grows with the number of fluid nodes (one core):

    python -m benchmarks.scaling [--repeat N] [--levels coarse,paper,fine] [--threads N]

Each resolution's default run is timed (fastest of N, in this process, the kernels compiled or
loaded before; the process's CPU time, which leaves out the time it waited for a core on a
shared machine, and the wall time), with its steps and the hyperviscosity's operator
applications per step.  The exponent a of CPU time = C n^a is fitted by least squares on log
CPU time against log n over the levels, and split into its two factors: steps (the acoustic CFL
step shrinks with the smallest spacing, h ~ n^-1/2) and the CPU time per step (the work per
step is proportional to n, times the hyperviscosity's operator applications per step, which
the fit reports too: in principle gamma c h^5 |L^3| dt ~ cfl gamma does not depend on h; in
practice it grows slowly as nodes bunch).  One thread unless ``--threads`` says otherwise (then
the CPU time sums the threads).  About 2 minutes on a quiet machine.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from airpuff_core import RunParams, simulate


def fitted_exponent(n, y):
    """a of y = C n^a, least squares on the logarithms."""
    return float(np.polyfit(np.log(n), np.log(y), 1)[0])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1, help="runs per resolution (fastest kept)")
    ap.add_argument("--levels", default="coarse,paper,fine",
                    help="comma-separated resolutions, at least two")
    ap.add_argument("--threads", type=int, default=1, help="threads of the kernels (default 1)")
    args = ap.parse_args(argv)
    levels = args.levels.split(",")
    if len(levels) < 2:
        ap.error("--levels needs at least two resolutions")
    rows = []
    for level in levels:
        params = RunParams(resolution=level)
        simulate(params.replace(t_end=0.05), threads=args.threads)  # compile or load
        walls, cpus = [], []
        for _ in range(args.repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            result = simulate(params, threads=args.threads)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
        d = result.diagnostics
        cpu = min(cpus)
        rows.append((level, d["n_fluid"], cpu, d["steps"],
                     d["mean_hyperviscous_substeps"], d["mean_coupling_iterations"]))
        print(f"{level:7s} {d['n_fluid']:6d} nodes, {d['threads']} thread(s)  CPU {cpu:7.2f} s, wall {min(walls):7.2f} s "
              f"(fastest of {args.repeat})  {d['steps']:6d} steps  {cpu / d['steps'] * 1e3:6.3f} "
              f"ms/step  {cpu / d['steps'] / d['n_fluid'] * 1e6:6.3f} us/(step node)  "
              f"HV applications/step {d['mean_hyperviscous_substeps']:.2f}  DN iterations/step "
              f"{d['mean_coupling_iterations']:.2f}", flush=True)
    n = np.array([r[1] for r in rows], float)
    cpu = np.array([r[2] for r in rows])
    steps = np.array([r[3] for r in rows], float)
    hv = np.array([r[4] for r in rows])
    print(f"CPU time ~ n^{fitted_exponent(n, cpu):.2f}: steps ~ n^{fitted_exponent(n, steps):.2f}, "
          f"CPU time per step ~ n^{fitted_exponent(n, cpu / steps):.2f}, HV applications per step "
          f"~ n^{fitted_exponent(n, hv):.2f} (least squares over {', '.join(levels)})")
    return rows


if __name__ == "__main__":
    main()
