"""Sweep throughput on a LocalCluster with 1 and with 2 worker processes, on the same grid
(4 coarse points of 10 ms; each measurement in a fresh output folder, Numba cache warm)."""

import tempfile
import time

from sweep.grid import SweepSpec
from sweep.runner import run_sweep


def grid():
    return SweepSpec(E0=[0.4, 0.6], IOP=[12.0, 20.0], thickness=[0.5], pmax=[10.0],
                     options={"resolution": "coarse", "t_end": 10.0})


def main():
    rates = {}
    for workers in (1, 2):
        with tempfile.TemporaryDirectory() as out:
            t0 = time.perf_counter()
            outcome = run_sweep(grid(), out, workers=workers)
            wall = time.perf_counter() - t0
        rates[workers] = outcome.computed / wall
        print(f"sweep, {workers} worker(s): {outcome.computed} points in {wall:.1f} s "
              f"({rates[workers] * 60:.1f} points/min, cluster start-up included)")
    print(f"sweep speed-up 2 workers / 1 worker: {rates[2] / rates[1]:.2f}")
    return rates


if __name__ == "__main__":
    main()
