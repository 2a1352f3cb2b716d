"""The check behind the default time step (cfl = 0.6): default runs and five parameter corners at
cfl 0.4 (the smaller step, as the reference) and at the default, with the metrics side by side.

    python -m studies.time_step                       # coarse resolution, about 1 min
    python -m studies.time_step --resolution paper    # about 5 min

The stability side is ``tests/core/test_stability.py``: no growing mode of the linearised coupled
step at the default cfl, with gamma and gamma/2.  This script shows the accuracy side: the
larger step moves no metric by more than the tolerance stated in ``tests/core/test_run.py`` (0.05 mmHg,
0.05 ms, 0.005 mm), over stiff, soft, thin, thick corneas and strong jets.
"""

import argparse
import time

from airpuff_core import RunParams, SimulationError, simulate
from airpuff_core.params import PARAMETERS

REFERENCE_CFL = 0.4
CASES = [
    {},
    {"E0": 0.2, "IOP": 8.0},
    {"E0": 2.0, "IOP": 40.0},
    {"thickness": 0.4, "pmax": 20.0},
    {"thickness": 0.7, "E0": 0.3, "IOP": 30.0},
    {"pmax": 25.0, "E0": 0.25, "IOP": 10.0},
]
METRICS = (("P1", "mmHg"), ("P2", "mmHg"), ("t_A1", "ms"), ("t_A2", "ms"), ("DA", "mm"))


def run(resolution, cfl, case):
    t0 = time.perf_counter()
    try:
        r = simulate(RunParams(resolution=resolution, cfl=cfl, **case))
    except SimulationError as err:
        return None, str(err), time.perf_counter() - t0
    return r, None, time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", default="coarse", choices=("coarse", "paper", "fine"))
    args = ap.parse_args(argv)
    default_cfl = PARAMETERS["cfl"].default
    worst = {k: 0.0 for k, _ in METRICS}
    print(f"resolution {args.resolution}: cfl {REFERENCE_CFL} against the default {default_cfl}")
    for case in CASES:
        label = ", ".join(f"{k}={v:g}" for k, v in case.items()) or "default"
        (a, err_a, wall_a), (b, err_b, wall_b) = (run(args.resolution, c, case)
                                                  for c in (REFERENCE_CFL, default_cfl))
        if err_a or err_b:
            print(f"  {label}: FAILED ({err_a or ''} {err_b or ''})")
            continue
        diffs = []
        for k, unit in METRICS:
            va, vb = a.metrics[k], b.metrics[k]
            if va is None or vb is None:
                diffs.append(f"{k} missing")
                continue
            worst[k] = max(worst[k], abs(vb - va))
            diffs.append(f"{k} {va:.3f} -> {vb:.3f} {unit}")
        print(f"  {label}: {a.diagnostics['steps']} -> {b.diagnostics['steps']} steps, "
              f"{wall_a:.1f} -> {wall_b:.1f} s; " + "; ".join(diffs))
    print("largest change: " + ", ".join(f"{k} {worst[k]:.4f} {u}" for k, u in METRICS))
    return worst


if __name__ == "__main__":
    main()
