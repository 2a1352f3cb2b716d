"""The check behind the options ``hyperviscosity_interval`` and ``node_shifting_interval``
(``fluid_stepper.py``, docs/model.md section 4): clinical-preset runs with the part at every
fluid step (interval 1, the default, the reference) and at every N-th step over the span of the
N steps, metrics side by side, with the hyperviscosity's applications per step and the CPU time.

    python -m studies.step_interval                                  # paper, normal eye
    python -m studies.step_interval --intervals 2,3,4 --corners      # and the four corners
    python -m studies.step_interval --option node_shifting_interval --intervals 4,8,16
    python -m studies.step_interval --thickness 0.54                 # the normal eye's CCT

The cases and the stated accuracy are those of ``studies.operator_strain`` (the normal eye and
the four corners IOP 10 / 25 mmHg x CCT 0.45 / 0.65 mm; 0.05 mmHg on P1, P2, CH and 0.002 mm on
DA).  One run is about 7-15 s of one core at paper resolution (quiet machine); run it with
``nice``.
"""

from __future__ import annotations

import argparse
import time

from airpuff_core.solver import simulate
from studies.operator_strain import compare

OPTIONS = ("hyperviscosity_interval", "node_shifting_interval")


def runner(option):
    """run(params, interval) -> the run's metrics, hyperviscous applications per step and CPU
    time [s] with ``option`` = interval."""
    def run(params, interval):
        c0 = time.process_time()
        result = simulate(params.replace(**{option: int(interval)}), threads=1)
        applications = f"{result.diagnostics['mean_hyperviscous_substeps']:.2f}"
        return result.metrics, applications, time.process_time() - c0
    return run


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", default="paper", choices=("coarse", "paper", "fine"))
    ap.add_argument("--option", default=OPTIONS[0], choices=OPTIONS)
    ap.add_argument("--intervals", default="2", help="comma-separated intervals to compare with 1")
    ap.add_argument("--corners", action="store_true", help="also the four corners")
    ap.add_argument("--thickness", type=float, default=None,
                    help="the normal eye's corneal thickness [mm] (default the parameter's)")
    args = ap.parse_args(argv)
    intervals = [int(v) for v in args.intervals.split(",")]
    normal = {} if args.thickness is None else {"thickness": args.thickness}
    compare(args.resolution, args.corners, 1, intervals, runner(args.option),
            args.option.replace("_", " "), "hyperviscous applications per step", normal)


if __name__ == "__main__":
    main()
