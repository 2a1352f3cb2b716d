"""`make bench`: every benchmark figure of docs/performance.md, printed (about 16 minutes).

The default runs are timed on one thread (the figure of one core) and on every thread Numba has
(what `airpuff run` uses); the fine run, the shell's cost and the cost against resolution as
their docstrings say.

    python -m benchmarks.run_all            # all
    python -m benchmarks.run_all --quick    # skip the paper- and fine-resolution runs, the sweep
                                            # and the cost against resolution

Timings on this machine vary by 20-30 % from minute to minute, so the runs are repeated and the
fastest and median are printed.
"""

import os
import platform
import sys

from benchmarks import bench_compile, bench_mfpm, bench_shell, bench_sweep, run_default, scaling


def main(argv):
    quick = "--quick" in argv
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}")
    bench_compile.main()
    bench_mfpm.main()
    run_default.main("coarse", repeat=3, threads=1)
    run_default.main("coarse", repeat=3)
    if not quick:
        run_default.main("paper", repeat=3, threads=1)
        run_default.main("paper", repeat=3)
        run_default.main("fine", repeat=1)
        bench_shell.main("paper", repeat=3)
        bench_sweep.main(["--repeat", "2"])
        scaling.main([])


if __name__ == "__main__":
    main(sys.argv[1:])
