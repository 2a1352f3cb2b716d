"""How the cost of a default run grows with the number of fluid nodes (one core):

    python benchmarks/scaling.py [--repeat N] [--levels coarse,paper,fine]

Each resolution's default run is timed (fastest of N, in this process, the kernels compiled or
loaded before), with its steps and the hyperviscosity's operator applications per step.  The
exponent a of wall = C n^a is fitted by least squares on log wall against log n over the
levels, and split into its two factors: steps (the acoustic CFL step shrinks with the smallest
spacing, h ~ n^-1/2) and the wall time per step (the work per step is proportional to n, times
the hyperviscosity's operator applications per step, which the fit reports too: in principle
gamma c h^5 |L^3| dt ~ cfl gamma is independent of h, in practice it grows slowly as nodes
bunch).  About 3 minutes on a quiet machine.
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
    args = ap.parse_args(argv)
    levels = args.levels.split(",")
    if len(levels) < 2:
        ap.error("--levels needs at least two resolutions")
    rows = []
    for level in levels:
        params = RunParams(resolution=level)
        simulate(params.replace(t_end=0.05))  # compile or load the kernels
        walls = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            result = simulate(params)
            walls.append(time.perf_counter() - t0)
        d = result.diagnostics
        rows.append((level, d["n_fluid"], min(walls), d["steps"],
                     d["mean_hyperviscous_substeps"], d["mean_coupling_iterations"]))
        print(f"{level:7s} {d['n_fluid']:6d} nodes  wall {min(walls):7.2f} s (fastest of "
              f"{args.repeat})  {d['steps']:6d} steps  {min(walls) / d['steps'] * 1e3:6.3f} "
              f"ms/step  {min(walls) / d['steps'] / d['n_fluid'] * 1e6:6.3f} us/(step node)  "
              f"HV applications/step {d['mean_hyperviscous_substeps']:.2f}  DN iterations/step "
              f"{d['mean_coupling_iterations']:.2f}", flush=True)
    n = np.array([r[1] for r in rows], float)
    wall = np.array([r[2] for r in rows])
    steps = np.array([r[3] for r in rows], float)
    hv = np.array([r[4] for r in rows])
    print(f"wall ~ n^{fitted_exponent(n, wall):.2f}: steps ~ n^{fitted_exponent(n, steps):.2f}, "
          f"wall per step ~ n^{fitted_exponent(n, wall / steps):.2f}, HV applications per step "
          f"~ n^{fitted_exponent(n, hv):.2f} (least squares over {', '.join(levels)})")
    return rows


if __name__ == "__main__":
    main()
