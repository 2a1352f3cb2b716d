"""Cost of the air pulse in the cornea's sub-steps: ``kernels/shell.net_inside_pressure`` (the
pulse's space factor on the nodes, made once per run, times its time factor, once per call)
against eq. (11) evaluated at every node as the kernels did before the instruments' pulses (a
sine and two exponentials per node; the reference kernel is written here).

    python -m benchmarks.bench_pulse [--nodes N (default 51)] [--calls N] [--repeat N]

Both kernels give the same bits (checked); the two alternate ``--repeat`` times in this process
and the fastest and median nanoseconds per call are printed.  One coupled step at paper resolution
calls it (sub-steps + 1) x coupling iterations times, about 25 times.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from numba import njit

from airpuff_core.kernels.air_jet import PAPER, air_jet, pulse_space
from airpuff_core.kernels.shell import net_inside_pressure


@njit(cache=True)
def eq11_at_every_node(phi, p_start, p_end, frac, t, jet, q):
    """The reference: q = p_start + frac (p_end - p_start) - eq. (11) at every node (jet = pmax,
    a, b, T, t0)."""
    for i in range(phi.shape[0]):
        q[i] = p_start[i] + frac * (p_end[i] - p_start[i]) - air_jet(t, phi[i], jet[0], jet[1],
                                                                      jet[2], jet[3], jet[4])


@njit(cache=True)
def _calls(kernel, nodes, p_start, p_end, jet, q, n):
    """n calls at times 0, 1 us, ... (the sum keeps the calls from being optimised away)."""
    total = 0.0
    for k in range(n):
        kernel(nodes, p_start, p_end, 0.5, 1e-6 * k, jet, q)
        total += q[0]
    return total


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--nodes", type=int, default=51)
    ap.add_argument("--calls", type=int, default=200_000)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args(argv)
    phi = np.linspace(0.0, np.pi / 3, args.nodes)
    p = np.full(args.nodes, 2133.152)
    reference_jet = np.array([1e4, 21.5, 25.0, 0.03, 0.015])
    jet = np.concatenate(([PAPER], reference_jet))
    space = np.empty(args.nodes)
    pulse_space(phi, jet, space)
    q_ref, q_new = np.empty(args.nodes), np.empty(args.nodes)
    for t in (0.0, 0.0123, 0.03):
        eq11_at_every_node(phi, p, p, 0.5, t, reference_jet, q_ref)
        net_inside_pressure(space, p, p, 0.5, t, jet, q_new)
        assert np.array_equal(q_ref, q_new), "the two kernels differ"
    runs = {"eq. (11) at every node": (eq11_at_every_node, phi, reference_jet),
            "space factor x time factor": (net_inside_pressure, space, jet)}
    for kernel, nodes, args_jet in runs.values():
        _calls(kernel, nodes, p, p, args_jet, q_new, 10)
    ns = {name: [] for name in runs}
    for _ in range(args.repeat):
        for name, (kernel, nodes, args_jet) in runs.items():
            t0 = time.perf_counter()
            _calls(kernel, nodes, p, p, args_jet, q_new, args.calls)
            ns[name].append((time.perf_counter() - t0) / args.calls * 1e9)
    print(f"net inside pressure on {args.nodes} cornea nodes, {args.calls} calls x {args.repeat}:")
    for name, values in ns.items():
        print(f"  {name:28s} {min(values):8.1f} ns per call fastest, "
              f"{statistics.median(values):8.1f} median")


if __name__ == "__main__":
    main()
