"""`make bench`: every benchmark figure of docs/performance.md, printed (about 16 minutes).

The default runs are timed on one thread (the figure of one core) and on every thread Numba has
(what `airpuff run` uses); the fine run, the shell's cost and the cost against resolution as
their docstrings say.  The clinical preset's paper-resolution point, a sweep's unit of work, is
timed on one core against ``BASELINE`` (the code before issue 31), the two alternated in one
process and each run divided by the yardstick around it (``benchmarks/interleaved.py``,
``benchmarks/yardstick.py``), and then this tree's point with each option of ``STEP_INTERVALS``
at its value against the same option at 1 (every step; docs/performance.md).

    python -m benchmarks.run_all            # all
    python -m benchmarks.run_all --quick    # skip the paper- and fine-resolution runs, the sweep
                                            # and the cost against resolution

Timings on this machine vary by 20-30 % from minute to minute, so the runs are repeated and the
fastest and median are printed.
"""

import os
import platform
import sys

from benchmarks import (bench_compile, bench_mfpm, bench_pulse, bench_shell, bench_sweep,
                        interleaved, run_default, scaling, yardstick)

# the main of 2026-12-04 before issue 31's changes: the "before" of the clinical point
BASELINE = "c8ce7b3"
# the step intervals whose speed-up over an interval of 1 is printed, at the values measured
# (docs/performance.md, issue 31; node_shifting_interval 8 is the default)
STEP_INTERVALS = ({"node_shifting_interval": 8},)


def main(argv):
    quick = "--quick" in argv
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}")
    yardstick.main(["--repeat", "3"])
    bench_compile.main()
    bench_mfpm.main()
    bench_pulse.main([])
    run_default.main("coarse", repeat=3, threads=1)
    run_default.main("coarse", repeat=3)
    if not quick:
        interleaved.interleaved_runs(BASELINE, "paper", repeat=2, threads=1, model="clinical")
        for option in STEP_INTERVALS:
            interleaved.interleaved_runs("HEAD", "paper", repeat=2, threads=1, model="clinical",
                                         settings=dict.fromkeys(option, 1), new_settings=option)
        run_default.main("paper", repeat=3, threads=1)
        run_default.main("paper", repeat=3)
        run_default.main("fine", repeat=1)
        bench_shell.main("paper", repeat=3)
        bench_sweep.main(["--repeat", "2"])
        scaling.main([])


if __name__ == "__main__":
    main(sys.argv[1:])
