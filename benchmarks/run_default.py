"""Wall time and solver figures of one default run:

    python -m benchmarks.run_default [resolution] [--repeat N] [--operator OPERATOR] [--threads N]

With ``--repeat N`` the run is made N times in this process (the Numba kernels compiled or loaded
before the first) and the fastest and the median wall time are printed, and the same of the
process's CPU time, which leaves out the time it waited for a core on a shared machine: this
machine's speed varies by up to 20-30 % from minute to minute (other virtual machines on the
host), so one timing alone can mislead.  The metrics are those of the last run (every run gives
the same).
``--operator`` times the run with another hyperviscosity operator (``hyperviscosity_operator``,
docs/model.md section 4) at the default strength.  ``--threads N`` runs the kernels on N threads
(default: every core Numba sees, as ``airpuff run`` does; 1 for the figure of one core).  With
more than one thread the CPU time is the sum over the threads, and it includes the time they
spin while they wait for the next parallel loop.
"""

import argparse
import json
import statistics
import time

from airpuff_core import RunParams, simulate
from airpuff_core.params import CHOICE_DEFAULTS, CHOICES

PAPER = {"P1": 21.96, "P2": 6.82, "CH": 15.14, "IOPg": 14.39, "IOPcc": 19.03, "t_A1": 8.35, "t_A2": 24.3}


def main(resolution="coarse", repeat=1, threads=None, **overrides):
    params = RunParams(resolution=resolution, **overrides)
    # compile or load the kernels: not part of a run's time
    simulate(params.replace(t_end=0.05), threads=threads)
    walls, cpus = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        r = simulate(params, threads=threads)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    wall = min(walls)
    d = r.diagnostics
    particle_steps = d["steps"] * d["n_fluid"]
    print(f"resolution {resolution}: {d['n_fluid']} fluid nodes, {d['n_cornea']} cornea nodes, "
          f"{d['threads']} thread(s)")
    timing = (f"wall {wall:.1f} s (CPU {cpus[0]:.1f} s)" if repeat == 1 else
              f"wall {wall:.1f} s fastest of {repeat} (median {statistics.median(walls):.1f} s; "
              f"CPU {min(cpus):.1f} s fastest, {statistics.median(cpus):.1f} s median)")
    print(f"  {timing}, {d['steps']} steps, dt mean {d['dt_mean_us']:.2f} us "
          f"(min {d['dt_min_us']:.2f}, max {d['dt_max_us']:.2f}), "
          f"{particle_steps / wall / 1e6:.3f} M particle-steps/s")
    print(f"  DN iterations per step: mean {d['mean_coupling_iterations']:.2f}, "
          f"max {d['max_coupling_iterations']}; membrane sub-steps per step "
          f"{d['mean_membrane_substeps']:.2f}, hyperviscous sub-steps per step "
          f"{d['mean_hyperviscous_substeps']:.2f}")
    for k, v in r.metrics.items():
        ref = PAPER.get(k)
        print(f"  {k:10s} {v:9.3f}" + (f"   paper {ref}" if ref is not None else ""))
    print("  Imbert-Fick: fluid pressure at the apex at A1, A2: "
          f"{d.get('fluid_pressure_apex_at_A1', float('nan')):.3f}, "
          f"{d.get('fluid_pressure_apex_at_A2', float('nan')):.3f} mmHg")
    print(json.dumps({"resolution": resolution, "threads": d["threads"], "wall_s": wall,
                      "wall_s_all": walls,
                      "cpu_s_all": cpus,
                      **{k: d[k] for k in ("steps", "dt_mean_us", "n_fluid",
                                           "mean_coupling_iterations")}, **r.metrics_json()}))
    return r


def parse_timing_args(doc, resolution="coarse", repeat=1, operator=False):
    """``[resolution] [--repeat N] [--threads N]`` of the timing scripts (and ``--operator``,
    the hyperviscosity operator, with ``operator``)."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("resolution", nargs="?", default=resolution, choices=("coarse", "paper", "fine"))
    ap.add_argument("--repeat", type=int, default=repeat, help=f"runs to time (default {repeat})")
    ap.add_argument("--threads", type=int, default=None,
                    help="threads of the kernels (default every core Numba sees)")
    if operator:
        ap.add_argument("--operator", default=CHOICE_DEFAULTS["hyperviscosity_operator"],
                        choices=CHOICES["hyperviscosity_operator"],
                        help="hyperviscosity operator (docs/model.md section 4)")
    return ap.parse_args()


if __name__ == "__main__":
    args = parse_timing_args(__doc__, operator=True)
    main(args.resolution, args.repeat, args.threads, hyperviscosity_operator=args.operator)
