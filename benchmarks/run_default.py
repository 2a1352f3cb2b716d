"""Wall time and solver figures of one default run: python benchmarks/run_default.py [resolution]."""

import json
import sys
import time

from airpuff_core import RunParams, simulate

PAPER = {"P1": 21.96, "P2": 6.82, "CH": 15.14, "IOPg": 14.39, "IOPcc": 19.03, "t_A1": 8.35, "t_A2": 24.3}


def main(resolution="coarse", **overrides):
    params = RunParams(resolution=resolution, **overrides)
    t0 = time.perf_counter()
    r = simulate(params)
    wall = time.perf_counter() - t0
    d = r.diagnostics
    particle_steps = d["steps"] * d["n_fluid"]
    print(f"resolution {resolution}: {d['n_fluid']} fluid nodes, {d['n_cornea']} cornea nodes")
    print(f"  wall {wall:.1f} s, {d['steps']} steps, dt mean {d['dt_mean_us']:.2f} us "
          f"(min {d['dt_min_us']:.2f}, max {d['dt_max_us']:.2f}), "
          f"{particle_steps / wall / 1e6:.3f} M particle-steps/s")
    print(f"  DN iterations per step: mean {d['mean_coupling_iterations']:.2f}, "
          f"max {d['max_coupling_iterations']}; membrane sub-steps per step {d['mean_membrane_substeps']:.2f}")
    for k, v in r.metrics.items():
        ref = PAPER.get(k)
        print(f"  {k:10s} {v:9.3f}" + (f"   paper {ref}" if ref is not None else ""))
    print("  Imbert-Fick: fluid pressure at the apex at A1, A2: "
          f"{d.get('fluid_pressure_apex_at_A1', float('nan')):.3f}, "
          f"{d.get('fluid_pressure_apex_at_A2', float('nan')):.3f} mmHg")
    print(json.dumps({"resolution": resolution, "wall_s": wall, **{k: d[k] for k in (
        "steps", "dt_mean_us", "n_fluid", "mean_coupling_iterations")}, **r.metrics_json()}))
    return r


if __name__ == "__main__":
    main(*(sys.argv[1:2] or ["coarse"]))
