"""MFPM operator throughput on one core, in particle-evaluations per CPU second.

One particle-evaluation = the operator at one node built from the current positions (its support
found, its moment matrix assembled and inverted, its condition number checked), then the full
derivative vector (f_x, f_y, f_xx, f_xy, f_yy) of all four flow fields (density, pressure, v_x,
v_y) at that node: one call of ``Operators.derivatives`` with the four fields.  The positions cycle
through eight clouds that differ by 1 % of the spacing, as consecutive time steps do (the neighbour
table is searched once, as in the solver, where the skin makes searches rare).  Also printed: the
build with no field, the cost of each further field, and the build that also keeps the Brookshaw
pair lists (as the solver's full build at t^{n+1} does).

    python -m benchmarks.bench_mfpm [resolution]
"""

import math
import sys
import time

import numpy as np

from airpuff_core.fluid import KAPPA, Operators
from airpuff_core.geometry import build_chamber
from airpuff_core.threads import solver_threads


def interleaved(rounds, repeats, fns):
    """Mean CPU time [s] of one call of each function, per round: every round times ``repeats``
    calls of each in turn, so that a slow minute of the machine hits all of them alike.  CPU time
    of this process, not wall time: on a machine shared with other work it leaves out the time
    the process waited for a core.  Returns one sorted list of per-round times per function."""
    times = [[] for _ in fns]
    for _ in range(rounds):
        for t, fn in zip(times, fns):
            t0 = time.process_time()
            for k in range(repeats):
                fn(k)
            t.append((time.process_time() - t0) / repeats)
    return [sorted(t) for t in times]


def moving_clouds(resolution):
    """The benchmark's chamber, eight clouds of its nodes moved by 1 % of a spacing, and four
    smooth fields (density, pressure, v_x, v_y; v_x odd in x) with their parities."""
    ch = build_chamber("sector", "isotropic", resolution, 7e-3, 2.04e-3, math.radians(60))
    rng = np.random.default_rng(0)
    moving = ch.kind == 0
    clouds = [(ch.x + 0.01 * ch.h * rng.standard_normal(ch.n) * moving,
               ch.y + 0.01 * ch.h * rng.standard_normal(ch.n) * moving) for _ in range(8)]
    fields = np.array([np.cos(300 * ch.x + k) * np.sin(200 * ch.y) for k in range(4)])
    parity = np.array([1.0, 1.0, -1.0, 1.0])
    return ch, clouds, fields, parity


def main(resolution="paper", repeats=40, rounds=15):
    with solver_threads(1):  # the build is serial (docs/performance.md, "Threads")
        return one_core(resolution, repeats, rounds)


def one_core(resolution, repeats, rounds):
    ch, clouds, fields, parity = moving_clouds(resolution)
    out = np.empty((4, ch.n, 5))
    ops = Operators(ch.h, ch.area, KAPPA)

    def evaluate(n_fields, laplacian=False):
        def run(k):
            ops.derivatives(*clouds[k % 8], fields[:n_fields], parity[:n_fields],
                            out[:n_fields], laplacian=laplacian)
        return run

    evaluate(4)(0)  # compile, first search
    evaluate(0, True)(0)
    searches = ops.table.searches
    t_four, t_none, t_lap = interleaved(rounds, repeats,
                                        [evaluate(4), evaluate(0), evaluate(0, True)])
    assert ops.table.searches == searches  # no search inside the timed loops
    n = ch.n
    mid = rounds // 2
    print(f"MFPM operator ({resolution}, {n} nodes, {ops.count.mean():.1f} pairs/node in the "
          f"support, {ops.table.count.mean():.1f} candidates in the table), {rounds} rounds: "
          f"{n / t_four[0] / 1e6:.2f} M particle-evaluations per CPU second fastest, "
          f"{n / t_four[mid] / 1e6:.2f} median (build + derivatives of 4 fields, "
          f"{t_four[0] / n * 1e6:.3f} us/node); build with no field {t_none[0] / n * 1e6:.3f} "
          f"us/node, each field {(t_four[0] - t_none[0]) / 4 / n * 1e6:.3f} us/node; keeping "
          f"the Brookshaw lists adds {(t_lap[0] - t_none[0]) / n * 1e6:.3f} us/node (fastest "
          f"rounds)")
    return n / t_four[0]


if __name__ == "__main__":
    main(*(sys.argv[1:2] or ["paper"]))
