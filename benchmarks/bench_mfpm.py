"""MFPM operator throughput on one core, in particle-evaluations per second.

One particle-evaluation = the operator at one node: its moment matrix factored and its pair weights
computed from the current positions (``Operators.build``), then the full derivative vector
(f_x, f_y, f_xx, f_xy, f_yy) of all four flow fields (density, pressure, v_x, v_y) at that node.
The positions cycle through eight clouds that differ by 1 % of the spacing, as consecutive time
steps do (the neighbour table is searched once, as in the solver, where the skin makes searches
rare).  Also printed: the build alone and the derivatives alone.

    python benchmarks/bench_mfpm.py [resolution]
"""

import math
import sys
import time

import numpy as np

from airpuff_core.fluid import Operators
from airpuff_core.geometry import build_chamber
from airpuff_core.kernels.mfpm import derivatives_pair
from airpuff_core.solver import KAPPA


def best_of(repeats, fn):
    """Smallest mean wall time [s] of ``fn()`` over 5 rounds of ``repeats`` calls (the other
    rounds absorb interruptions by the operating system)."""
    best = math.inf
    for _ in range(5):
        t0 = time.perf_counter()
        for k in range(repeats):
            fn(k)
        best = min(best, (time.perf_counter() - t0) / repeats)
    return best


def main(resolution="paper", repeats=100):
    ch = build_chamber("sector", "isotropic", resolution, 7e-3, 2.04e-3, math.radians(60))
    rng = np.random.default_rng(0)
    moving = ch.kind == 0
    clouds = [(ch.x + 0.01 * ch.h * rng.standard_normal(ch.n) * moving,
               ch.y + 0.01 * ch.h * rng.standard_normal(ch.n) * moving) for _ in range(8)]
    rho, p, vx, vy = (np.cos(300 * ch.x + k) * np.sin(200 * ch.y) for k in range(4))
    d_rho, d_p, d_vx, d_vy = (np.empty((ch.n, 5)) for _ in range(4))
    ops = Operators(ch.h, ch.area, KAPPA)

    def build(k):
        ops.build(*clouds[k % 8])

    def apply(k):
        derivatives_pair(vx, -1.0, vy, 1.0, *ops.args(), d_vx, d_vy)
        derivatives_pair(rho, 1.0, p, 1.0, *ops.args(), d_rho, d_p)

    def both(k):
        build(k)
        apply(k)

    both(0)  # compile, first search
    searches = ops.table.searches
    t_build = best_of(repeats, build)
    t_apply = best_of(repeats, apply)
    t_both = best_of(repeats, both)
    assert ops.table.searches == searches  # no search inside the timed loops
    n = ch.n
    print(f"MFPM operator ({resolution}, {n} nodes, {ops.count.mean():.1f} pairs/node in the "
          f"support, {ops.table.count.mean():.1f} in the table): "
          f"{n / t_both / 1e6:.2f} M particle-evaluations/s (build + derivatives of 4 fields); "
          f"build alone {t_build / n * 1e6:.3f} us/node, 4 fields' derivatives alone "
          f"{t_apply / n * 1e6:.3f} us/node ({4 * n / t_apply / 1e6:.1f} M field-derivative "
          f"evaluations/s)")
    return n / t_both


if __name__ == "__main__":
    main(*(sys.argv[1:2] or ["paper"]))
