"""Cost of the shell cornea against the membrane: one default run of each, interleaved (one core);
the shell both rigid in transverse shear (Kirchhoff-Love) and shear-deformable (G_t 9.48 kPa).

    python -m benchmarks.bench_shell [resolution] [--repeat N] [--threads N (default 1)]

The three runs alternate N times in this process (kernels compiled or loaded first), so that the
machine's drift (20-30 % from minute to minute here) hits both alike; the fastest and the median
wall time of each, the ratio of the fastest and the median ratio of the pairs are printed, with
the steps and the cornea sub-steps that explain it.  Aim: the shell at most 1.3 times the
membrane at paper resolution.
"""

import statistics
import time

from airpuff_core import RunParams, simulate
from benchmarks.run_default import parse_timing_args

# the corneas compared: the paper's membrane, the Kirchhoff-Love shell and the shear-deformable
# shell with the clinical preset's transverse shear modulus (docs/model.md section 3b)
CORNEAS = {"membrane": {"cornea": "membrane"}, "shell": {"cornea": "shell"},
           "mindlin": {"cornea": "shell", "transverse_shear_modulus": 9.48}}


def main(resolution="paper", repeat=3, threads=1):
    params = {c: RunParams(resolution=resolution, **options) for c, options in CORNEAS.items()}
    for p in params.values():
        simulate(p.replace(t_end=0.05), threads=threads)  # compile or load the kernels
    walls = {c: [] for c in CORNEAS}
    last = {}
    for _ in range(repeat):
        for c in CORNEAS:
            t0 = time.perf_counter()
            last[c] = simulate(params[c], threads=threads)
            walls[c].append(time.perf_counter() - t0)
    print(f"shell against membrane, {resolution} resolution, {repeat} interleaved pairs")
    for c in CORNEAS:
        d = last[c].diagnostics
        print(f"  {c:8s}: wall {min(walls[c]):.1f} s fastest (median "
              f"{statistics.median(walls[c]):.1f} s), {d['steps']} steps, dt mean "
              f"{d['dt_mean_us']:.2f} us, cornea sub-steps per step "
              f"{d['mean_membrane_substeps']:.2f}, DN iterations {d['mean_coupling_iterations']:.2f}")
    for c in ("shell", "mindlin"):
        pairs = [s / m for s, m in zip(walls[c], walls["membrane"])]
        print(f"  ratio {c} / membrane: {min(walls[c]) / min(walls['membrane']):.2f} "
              f"(fastest), {statistics.median(pairs):.2f} (median of pairs); aim <= 1.3")
    return walls


if __name__ == "__main__":
    args = parse_timing_args(__doc__, "paper", 3)
    main(args.resolution, args.repeat, 1 if args.threads is None else args.threads)
