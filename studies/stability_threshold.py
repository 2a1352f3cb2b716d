"""Eigenvalue check of the linearised coupled step (fluid and cornea DOFs, about rest) at a given
resolution: the largest growth rate and the number of growing modes for a list of hyperviscosity
strengths, and the smallest stable strength by bisection.

    python -m studies.stability_threshold --resolution coarse            # about 1 min
    python -m studies.stability_threshold --resolution paper             # ~3,300 DOFs, 15-30 min
    python -m studies.stability_threshold --resolution paper --gammas 0.15,0.075 --no-bisect
    python -m studies.stability_threshold --operator consistent_velocity --gammas 0.15,0.03

``--operator`` picks the hyperviscosity operator (``hyperviscosity_operator``: brookshaw, the
default, consistent or consistent_velocity; docs/model.md section 4).

A mode grows when its growth rate ln|mu| / dt exceeds ``NOISE`` (1/s, an e-folding time of 1 s,
30 times a run; real instabilities grow at 1e2-1e4 /s), the criterion of tests/core/test_stability.py.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from airpuff_core import RunParams
from airpuff_core.params import CHOICE_DEFAULTS, CHOICES
from airpuff_core.stability import linearised_step

NOISE = 1.0  # 1/s


def check(resolution: str, gamma: float, log=print, operator: str = "brookshaw",
          extra=None) -> tuple[float, int]:
    """(largest growth rate [1/s], number of growing modes) at strength ``gamma`` of the
    hyperviscosity ``operator``; ``extra``: other run parameters (name -> value)."""
    t0 = time.perf_counter()
    report = linearised_step(RunParams.from_dict({
        "resolution": resolution, "hyperviscosity": gamma, "hyperviscosity_operator": operator,
        **(extra or {})}))
    rates = report.growth_rates
    growing = int(np.count_nonzero(rates > NOISE))
    log(f"  gamma {gamma:.4g}: largest growth rate {rates[0]:.4g} /s, {growing} growing modes "
        f"({report.n_dof} DOFs, dt {report.dt * 1e6:.3f} us, {time.perf_counter() - t0:.0f} s)",
        flush=True)
    return float(rates[0]), growing


def smallest_stable(resolution: str, low: float, high: float, steps: int, log=print,
                    operator: str = "brookshaw", extra=None) -> tuple:
    """Bisection between an unstable ``low`` and a stable ``high`` strength."""
    for _ in range(steps):
        mid = 0.5 * (low + high)
        if check(resolution, mid, log, operator, extra)[1] == 0:
            high = mid
        else:
            low = mid
    return low, high


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", default="coarse", choices=("coarse", "paper", "fine"))
    ap.add_argument("--gammas", default="0,0.15,0.075",
                    help="comma-separated strengths to check")
    ap.add_argument("--operator", default=CHOICE_DEFAULTS["hyperviscosity_operator"],
                    choices=CHOICES["hyperviscosity_operator"],
                    help="hyperviscosity operator (docs/model.md section 4)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="any other run parameter (e.g. hyperviscosity_speed=10)")
    ap.add_argument("--bisect-steps", type=int, default=4)
    ap.add_argument("--no-bisect", action="store_true")
    args = ap.parse_args(argv)
    extra = dict(s.split("=", 1) for s in args.set)
    print(f"resolution {args.resolution}, operator {args.operator}, {extra}", flush=True)
    results = {g: check(args.resolution, g, operator=args.operator, extra=extra)
               for g in map(float, args.gammas.split(","))}
    if args.no_bisect:
        return
    stable = sorted(g for g, (_, n) in results.items() if n == 0)
    unstable = sorted(g for g, (_, n) in results.items() if n > 0)
    if not stable or not unstable or unstable[-1] > stable[0]:
        print("bisection needs a stable strength above an unstable one")
        return
    low, high = smallest_stable(args.resolution, unstable[-1], stable[0], args.bisect_steps,
                                operator=args.operator, extra=extra)
    print(f"smallest stable strength at {args.resolution} resolution: between {low:.4g} (unstable) "
          f"and {high:.4g} (stable)")


if __name__ == "__main__":
    main()
