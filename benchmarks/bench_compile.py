"""Numba compile time: a tiny run in a fresh process with an empty cache (cold) and again with the
cache filled (warm)."""

import os
import subprocess
import sys
import tempfile
import time

SNIPPET = ("import time; t=time.perf_counter(); from airpuff_core import RunParams, simulate; "
           "simulate(RunParams(t_end=0.05)); print(time.perf_counter()-t)")


def timed(cache_dir):
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", SNIPPET], env=env, capture_output=True, text=True,
                         check=True)
    return time.perf_counter() - t0, float(out.stdout.strip().splitlines()[-1])


def main():
    with tempfile.TemporaryDirectory() as cache:
        cold_proc, cold_in = timed(cache)
        warm_proc, warm_in = timed(cache)
    print(f"Numba compile: cold start {cold_proc:.1f} s (import + compile + 0.05 ms run: {cold_in:.1f} s), "
          f"warm start {warm_proc:.2f} s (in-process {warm_in:.2f} s)")
    return cold_proc, warm_proc


if __name__ == "__main__":
    main()
