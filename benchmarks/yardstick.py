"""The yardstick: a fixed reference loop whose time measures the machine's speed of the moment.

    python -m benchmarks.yardstick [--repeat N]

This machine's speed changes by 20-30 % from minute to minute, and by a factor of 2 or more when
other work shares its two cores (docs/performance.md).  A timing divided by the yardstick's,
taken in the same minutes, is a figure that survives both: a "yardstick ratio" of 3.6 means the
run took as long as 3.6 yardsticks.  The loop is the solver's kind of work on one core (gathers
through a neighbour list, multiply-adds, a division per node, arrays of about 1 MB) on fixed
data, and it is deliberately NOT the project's code: it must not change when the solver does.
About 1 s on the CI machine when it is quiet.  Never change this file's loop or its data: ratios
from before and after such a change would not compare.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from numba import njit

NODES = 1104  # a paper-resolution chamber's fluid nodes
NEIGHBOURS = 29  # candidates per node
SWEEPS = 20000  # passes over the nodes: about 1 s on the CI machine


def yardstick_data():
    """Fixed positions, fields and neighbour lists (the same on every machine and every day)."""
    rng = np.random.default_rng(20261204)
    x = rng.random(NODES)
    y = rng.random(NODES)
    f = rng.random(NODES)
    offsets = rng.integers(-40, 41, size=(NODES, NEIGHBOURS))
    nbr = ((np.arange(NODES)[:, None] + offsets) % NODES).astype(np.uint32).ravel()
    return x, y, f, nbr


@njit(cache=True)
def yardstick_loop(x, y, f, nbr, sweeps):
    """``sweeps`` smoothing passes f_i <- sum_j w_ij f_j / sum_j w_ij, w_ij = 1 / (1 + r_ij^2)
    over each node's fixed neighbours; returns a checksum (so that nothing is optimised away)."""
    n = x.shape[0]
    k = nbr.shape[0] // n
    g = f.copy()
    out = np.empty(n)
    for _ in range(sweeps):
        for i in range(n):
            num = 0.0
            den = 0.0
            for p in range(i * k, (i + 1) * k):
                j = nbr[p]
                dx = x[j] - x[i]
                dy = y[j] - y[i]
                w = 1.0 / (1.0 + dx * dx + dy * dy)
                num += w * g[j]
                den += w
            out[i] = num / den
        g, out = out, g
    return g.sum()


def yardstick_seconds(data=None):
    """Wall time [s] of one yardstick loop (compiled or loaded before it is timed)."""
    data = yardstick_data() if data is None else data
    yardstick_loop(*data, 1)
    t0 = time.perf_counter()
    yardstick_loop(*data, SWEEPS)
    return time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="loops to time (default 5)")
    args = ap.parse_args(argv)
    data = yardstick_data()
    times = [yardstick_seconds(data) for _ in range(args.repeat)]
    print(f"yardstick: {min(times):.3f} s fastest of {args.repeat}, "
          f"{statistics.median(times):.3f} s median")
    return times


if __name__ == "__main__":
    main()
