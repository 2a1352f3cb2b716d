"""Where the time of one run goes, by part of the step (one core):

    python -m benchmarks.profile_point [resolution] [--model paper|clinical] [--repeat N]
                                       [--set NAME=VALUE ...]

The parts' methods are wrapped by timers (``time.perf_counter`` around each call, about 1 us a
call, small against the parts), the run is made ``--repeat`` times (the kernels compiled or
loaded before) and the shares of the fastest run are printed, with the yardstick ratio of its
wall time (``benchmarks/yardstick.py``).  Parts, in the order of a step:

- step control: the sound speed and dt, with the hyperviscosity's spectral-radius refresh
  (power iterations), shown apart;
- hyperviscosity: its Runge-Kutta-Legendre super-steps in the predictor;
- MFPM: the operators built (grad p at t^{n+1/2}, the velocity derivatives and the Brookshaw
  lists at t^{n+1}), or mapped from a kept operator (``FluidStepper``'s ``strain_limit``), at
  all nodes or at the interface nodes in the coupling iterations;
- coupling iterations: the Dirichlet-Neumann iterations, split into the cornea's sub-steps
  (``advance``), the globe's walls (``impose``), and the rest of an iteration (Python, the density and pressure at the interface);
- the sound-speed stabilisations of the clinical preset: the divergence damping's assembly
  (at each build of the operator) and sub-steps, the node shifting (in the commit);
- observers: the energy budget, the blow-up checks, the recorder (each shown apart);
- the rest: the predictor's other kernels, the commit, Python's orchestration.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

from airpuff_core import RunParams
from airpuff_core.solver import simulate
from airpuff_core.coupling import CoupledModel
from airpuff_core.dirichlet_neumann import DirichletNeumann
from airpuff_core.divergence_damping import DivergenceDamping
from airpuff_core.fluid import Operators
from airpuff_core.fluid_stepper import FluidStepper
from airpuff_core.step_control import StepControl
from benchmarks.interleaved import parse_settings
from benchmarks.yardstick import yardstick_data, yardstick_seconds


class Timers:
    """Seconds and calls per part, from wrapped methods (nested parts are subtracted from the part
    they run in, so the shares add up to the run)."""

    def __init__(self):
        self.seconds = defaultdict(float)
        self.calls = defaultdict(int)
        self._stack = []

    def wrap(self, owner, name, part, select=None):
        """Time ``owner.name`` as ``part`` (``select(args, kwargs)`` may name another part)."""
        method = getattr(owner, name)
        timers = self

        def timed(*args, **kwargs):
            label = select(args, kwargs) if select else part
            timers._stack.append(0.0)
            t0 = time.perf_counter()
            try:
                return method(*args, **kwargs)
            finally:
                elapsed = time.perf_counter() - t0
                inner = timers._stack.pop()
                timers.seconds[label] += elapsed - inner
                timers.calls[label] += 1
                if timers._stack:
                    timers._stack[-1] += elapsed

        setattr(owner, name, timed)
        return method

    def reset(self):
        self.seconds.clear()
        self.calls.clear()


def _mfpm_part(kind):
    """The part of an MFPM evaluation (``kind``: build or mapped): the interface nodes' (in the
    coupling), or all nodes'."""
    def part(args, kwargs):
        nodes = args[6] if len(args) > 6 else kwargs.get("nodes")
        return f"MFPM {kind}, " + ("interface nodes (coupling)" if nodes is not None
                                   else "all nodes")
    return part


def instrument():
    """Wrap the parts' methods; returns the timers and a function that unwraps them."""
    timers = Timers()
    cornea_classes = []
    from airpuff_core.cornea import kirchhoff, membrane, mindlin
    from airpuff_core.globe import compliant, rigid
    for module, cls in ((mindlin, "MindlinShell"), (kirchhoff, "KirchhoffShell"),
                        (membrane, "Membrane")):
        cornea_classes.append(getattr(module, cls))
    wrapped = [
        (StepControl, "_hv_spectral_radius", "hyperviscosity: spectral-radius refresh", None),
        (StepControl, "begin_step", "step control", None),
        (FluidStepper, "_hyperviscous_rates", "hyperviscosity: RKL super-steps", None),
        (FluidStepper, "predict", "predictor: the rest", None),
        (Operators, "derivatives", None, _mfpm_part("build")),
        (Operators, "mapped_derivatives", None, _mfpm_part("mapped")),
        (DirichletNeumann, "iterate", "coupling: the rest of the iterations", None),
        (compliant.CompliantGlobe, "impose", "coupling: globe walls", None),
        (rigid.RigidGlobe, "impose", "coupling: globe walls", None),
        (CoupledModel, "commit", "commit", None),
        (FluidStepper, "shift", "node shifting", None),
        (DivergenceDamping, "assemble", "divergence damping: assembly (at each build)", None),
        (DivergenceDamping, "increments", "divergence damping: sub-steps", None),
    ]
    wrapped += [(cls, "advance", "coupling: cornea sub-steps", None) for cls in cornea_classes]
    from airpuff_core import blowup, energy, recorder
    for cls, label in ((energy.EnergyBudget, "energy budget"),
                       (blowup.BlowUpCheck, "blow-up checks"), (recorder.Recorder, "recorder")):
        for name in ("coupled", "committed"):
            wrapped.append((cls, name, f"observers: {label}", None))
    wrapped.append((CoupledModel, "step", "the rest (Python, small kernels)", None))
    originals = []
    seen = set()
    for owner, name, part, select in wrapped:
        if (owner, name) in seen or name not in vars(owner):
            continue
        seen.add((owner, name))
        originals.append((owner, name, timers.wrap(owner, name, part, select)))

    def restore():
        for owner, name, method in originals:
            setattr(owner, name, method)

    return timers, restore


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("resolution", nargs="?", default="paper", choices=("coarse", "paper", "fine"))
    ap.add_argument("--model", default="clinical", choices=("paper", "clinical"))
    ap.add_argument("--repeat", type=int, default=2, help="runs (the fastest is shown)")
    ap.add_argument("--strain-limit", type=float, default=None,
                    help="the fluid operator's strain limit (FluidStepper; default the solver's)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="a numeric run parameter, e.g. node_shifting_interval=8 (repeatable)")
    args = ap.parse_args(argv)
    params = RunParams(resolution=args.resolution, model=args.model,
                       **parse_settings(ap, "--set", args.set))
    simulate(params.replace(t_end=0.05), threads=1)  # compile or load the kernels
    timers, restore = instrument()
    data = yardstick_data()
    best = None
    try:
        for _ in range(args.repeat):
            stick = yardstick_seconds(data)
            timers.reset()
            t0 = time.perf_counter()
            result = simulate(params, threads=1, strain_limit=args.strain_limit)
            wall = time.perf_counter() - t0
            stick = 0.5 * (stick + yardstick_seconds(data))
            if best is None or wall < best[0]:
                best = (wall, stick, dict(timers.seconds), dict(timers.calls), result)
    finally:
        restore()
    wall, stick, seconds, calls, result = best
    d = result.diagnostics
    steps = d["steps"]
    print(f"{args.model} preset, {args.resolution} resolution, one thread: wall {wall:.2f} s "
          f"(fastest of {args.repeat}), yardstick {stick:.3f} s, ratio {wall / stick:.2f}; "
          f"{steps} steps, {d['mean_coupling_iterations']:.2f} coupling iterations, "
          f"{d['mean_membrane_substeps']:.2f} cornea sub-steps and "
          f"{d['mean_hyperviscous_substeps']:.2f} hyperviscous applications per step")
    accounted = sum(seconds.values())
    rows = sorted(seconds.items(), key=lambda kv: -kv[1])
    rows.append(("outside the steps (set-up, result)", wall - accounted))
    for part, s in rows:
        n = calls.get(part, 0)
        per = f"{n / steps:6.2f} calls/step, {s / n * 1e6:8.1f} us/call" if n else ""
        print(f"  {part:42s} {s:7.3f} s  {100 * s / wall:5.1f} %  {per}")
    return best


if __name__ == "__main__":
    main()
