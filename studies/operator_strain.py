"""The check behind the kept MFPM operator's strain limit (``fluid_stepper.STRAIN_LIMIT``):
clinical-preset runs with the operator built at every evaluation (strain limit 0, the reference)
and kept up to each given strain, metrics side by side, with the operator builds and the CPU time.

    python -m studies.operator_strain                                  # paper, normal eye
    python -m studies.operator_strain --limits 0.005,0.01,0.02,0.05    # the error against the limit
    python -m studies.operator_strain --corners                        # and the four corners

The corners are those of a clinical sweep: IOP 10 and 25 mmHg times corneal thickness 0.45 and
0.65 mm.  The stated accuracy of a clinical point at paper resolution is 0.05 mmHg on P1, P2
and CH and 0.002 mm on DA (docs/performance.md, "The clinical point at paper resolution"); the
script prints the largest difference of each over the cases.  One run is about 10 s of one core
at paper resolution (quiet machine); run it with ``nice``.
"""

from __future__ import annotations

import argparse
import time

from airpuff_core import RunParams
from airpuff_core.fluid_stepper import STRAIN_LIMIT
from airpuff_core.solver import simulate

NORMAL = {}
CORNERS = [{"IOP": iop, "thickness": cct} for iop in (10.0, 25.0) for cct in (0.45, 0.65)]
METRICS = (("P1", "mmHg", 0.05), ("P2", "mmHg", 0.05), ("CH", "mmHg", 0.05), ("DA", "mm", 0.002),
           ("t_A1", "ms", None), ("t_A2", "ms", None))


def run(params, limit):
    """The run's metrics, operator builds and CPU time [s] with strain limit ``limit``."""
    c0 = time.process_time()
    result = simulate(params, threads=1, strain_limit=limit)
    return result.metrics, result.diagnostics["operator_builds"], time.process_time() - c0


def compare(resolution, corners, reference, variants, run, name, count, normal=NORMAL):
    """Each case's metrics with the option at ``reference`` and their differences at each of
    ``variants``, ``run(params, value)`` -> (metrics, ``count`` of the run, CPU time [s]); the
    option is printed as ``name``; then the largest difference of each metric over the cases
    (the eye ``normal``, and the corners if ``corners``)."""
    cases = [normal] + (CORNERS if corners else [])
    simulate(RunParams(model="clinical", resolution=resolution, t_end=0.05), threads=1)
    worst = {(value, k): 0.0 for value in variants for k, _, _ in METRICS}
    for case in cases:
        params = RunParams(model="clinical", resolution=resolution, **case)
        label = ", ".join(f"{k} {v:g}" for k, v in case.items()) or "normal eye"
        ref, counted, cpu = run(params, reference)
        print(f"{label}, {name} {reference:g}: {counted} {count}, CPU {cpu:.1f} s; "
              + ", ".join(f"{k} {ref[k]:.6f}" for k, _, _ in METRICS), flush=True)
        for value in variants:
            metrics, counted, cpu = run(params, value)
            diffs = []
            for k, unit, _ in METRICS:
                d = metrics[k] - ref[k]
                worst[value, k] = max(worst[value, k], abs(d))
                diffs.append(f"{k} {d:+.2e} {unit}")
            print(f"{label}, {name} {value:g}: {counted} {count}, CPU {cpu:.1f} s; "
                  + ", ".join(diffs), flush=True)
    for value in variants:
        print(f"largest difference at {name} {value:g} over {len(cases)} case(s): "
              + ", ".join(f"{k} {worst[value, k]:.2e} {unit}"
                          + ("" if tol is None else f" (accuracy {tol:g})")
                          for k, unit, tol in METRICS), flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", default="paper", choices=("coarse", "paper", "fine"))
    ap.add_argument("--limits", default=str(STRAIN_LIMIT),
                    help="comma-separated strain limits to compare with 0")
    ap.add_argument("--corners", action="store_true", help="also the four corners")
    args = ap.parse_args(argv)
    limits = [float(v) for v in args.limits.split(",")]
    compare(args.resolution, args.corners, 0.0, limits, run, "strain limit", "builds")


if __name__ == "__main__":
    main()
