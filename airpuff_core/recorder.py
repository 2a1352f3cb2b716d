"""What a run keeps of its steps: time histories on the output grid, snapshots, solver figures.

``Recorder`` watches a ``CoupledModel`` after every step and turns what it saw into the
``RunResult`` (user units: ms, mm, mmHg, m/s; docs/model.md section 7):

- the histories of ``result.HISTORIES`` on the grid 0, output_interval, ..., t_end, linearly
  interpolated between solver steps (the air pulse, analytic, is evaluated on the grid exactly);
- the apex curvature, the instrument's applanation signal (``readout.py``) and the fluid
  pressure at every solver step, from which ``metrics.py`` finds the applanations (sign changes
  of the curvature, or the signal's peaks for the ORA and the Corvis ST) between steps;
- the snapshots of ``result.SNAPSHOT_LABELS``: the initial state, the first step after each
  applanation and after the jet peak, the state at the output time of the largest displacement,
  and the end;
- solver diagnostics: steps, dt, coupling iterations, sub-steps, and the largest mismatch
  between the chamber volume bounded by the cornea and the volume implied by the density field
  (both relative to t = 0).
"""

from __future__ import annotations

import math

import numpy as np

from .apex_budget import apex_budget
from .coupling import CoupledModel
from .dataset import decodable_ms
from .energy import EnergyBudget
from .fluid import KAPPA
from .metrics import compute_metrics, peak_distance
from .readout import curvature_crossings
from .params import MMHG_PA
from .result import HISTORIES, SNAPSHOT_LABELS, RunResult
from .threads import current_threads


def probe(model: CoupledModel, budget: EnergyBudget, full: bool = True) -> dict[str, float]:
    """The scalars of the time histories at the model's current state (user units), except the
    air jet (analytic, eq. (11) on the output grid); ``full=False`` leaves out the costlier ones
    (the bending moment and the terms of the energy ``budget``), which only output times
    need."""
    values = {
        "apex_displacement": model.apex_displacement() * 1e3,
        "apex_deformation": model.apex_displacement() * 1e3 + model.eye.displacement * 1e3,
        "eye_displacement": model.eye.displacement * 1e3,
        "eye_velocity": model.eye.velocity,
        "apex_velocity": -model.VY[0],
        "apex_curvature": model.apex_curvature() * 1e-3,
        "ora_reflection_signal": (model.applanation_signal if model.params.instrument == "ora"
                                  else math.nan),
        "corvis_flat_departure": (math.sqrt(-model.applanation_signal)
                                  if model.params.instrument == "corvis" else math.nan),
        "fluid_pressure_apex": model.p_interface[0] / MMHG_PA,
        "chamber_volume": model.chamber_volume() * 1e9,
        "wall_volume_change": model.globe.volume_change() * 1e9,
        "globe_pressure": model.globe.pressure() / MMHG_PA,
        "wall_pressure": model.globe.wall_pressure(model.rho, model.c) / MMHG_PA,
        "coupling_iterations": float(model.coupling.iterations),
        "sound_speed": model.c,
    }
    if full:
        values["apex_bending_moment"] = model.apex_moment() * 1e3
        values["pulse_force"] = model.pulse_force() * 1e3
        values["peak_distance"] = peak_distance(model.X, model.Y) * 1e3
        values.update(budget.terms(model))
    return values


def apex_budget_mmhg(model: CoupledModel) -> tuple[float, ...]:
    """The apex force budget of the current state (``apex_budget.apex_budget``) [mmHg]."""
    return tuple(part / MMHG_PA for part in apex_budget(model))


def snapshot(model: CoupledModel) -> dict[str, np.ndarray]:
    """The fields of a snapshot at the model's current state (user units)."""
    return {
        "cornea_x": model.X * 1e3, "cornea_y": model.Y * 1e3,
        "fluid_x": model.x * 1e3, "fluid_y": model.y * 1e3,
        "fluid_pressure": model.pressure() / MMHG_PA,
        "fluid_vx": model.vx.copy(), "fluid_vy": model.vy.copy(),
    }


class Recorder:
    """Histories, snapshots and diagnostics of one run, an observer of its steps: ``committed``
    (``record_step``) after each step, ``result`` at the end; the energy terms from ``budget``."""

    def __init__(self, model: CoupledModel, budget: EnergyBudget):
        si = model.si
        self.budget = budget
        self.t_end = si.t_end_s
        dt_out = si.output_interval_s
        n_out = int(math.floor(self.t_end / dt_out + 1e-9)) + 1
        self.out_t = np.arange(n_out) * dt_out  # s
        first = probe(model, budget)
        self.histories = {k: np.full(n_out, np.nan) for k in HISTORIES}
        for k, v in first.items():
            self.histories[k][0] = v
        self._next_out = 1
        self._prev, self._t_prev = first, 0.0
        # step-level series for the applanation detection and Imbert-Fick diagnostics
        self.step_t = [0.0]  # ms
        self.step_kappa = [first["apex_curvature"]]
        self.step_fluid_p = [first["fluid_pressure_apex"]]
        self.step_signal = [model.applanation_signal]  # the instrument's (readout.py)
        # the apex's inward velocity as the instrument sees it (metrics: v_A1, v_A2)
        self.step_velocity = [model.apex_deformation_velocity()]
        self.step_budget = [apex_budget_mmhg(model)]  # the apex force budget (metrics.py)
        self.snapshots = {label: None for label in SNAPSHOT_LABELS}
        self.snapshot_t = {label: math.nan for label in SNAPSHOT_LABELS}
        self._take("initial", model)
        self._best_da = -math.inf
        self.iterations = []
        self.dts = []
        self.substeps = []
        self.hv_substeps = []
        self.viscous_limited_steps = 0  # steps whose dt the viscous limit set
        self.max_residual = 0.0
        self._volume0 = first["chamber_volume"]  # mm^3
        self._density_volume0 = model.density_volume()
        self.max_volume_mismatch = 0.0

    def _take(self, label, model):
        self.snapshots[label] = snapshot(model)
        self.snapshot_t[label] = model.t * 1e3

    def coupled(self, model: CoupledModel, dt: float):
        """Nothing to keep before the commit."""

    def committed(self, model: CoupledModel, dt: float):
        """Take in the state after a step of dt [s]."""
        self.record_step(model, dt)

    def record_step(self, model: CoupledModel, dt: float):
        """Take in the state after a step of dt [s]."""
        self.iterations.append(model.coupling.iterations)
        self.dts.append(dt)
        self.substeps.append(model.last_substeps)
        self.hv_substeps.append(model.fluid.last_hv_substeps)
        limits = model.control.dt_limits
        self.viscous_limited_steps += limits["viscous"] < limits["acoustic"]
        self.max_residual = max(self.max_residual, model.coupling.residual)
        t = model.t
        # the full probe only where an output time may fall before the next step ends: the
        # interpolation needs it on both sides of an output time
        next_out = self.out_t[min(self._next_out, self.out_t.shape[0] - 1)]
        cur = probe(model, self.budget, full=next_out <= t + model.control.max_step() + 1e-15)
        self.step_t.append(t * 1e3)
        self.step_kappa.append(cur["apex_curvature"])
        self.step_fluid_p.append(cur["fluid_pressure_apex"])
        self.step_signal.append(model.applanation_signal)
        self.step_velocity.append(model.apex_deformation_velocity())
        self.step_budget.append(apex_budget_mmhg(model))
        self._take_event_snapshots(model)
        self._interpolate_histories(model, cur)
        volume0 = self._volume0
        volume_mismatch = abs((cur["chamber_volume"] - volume0) * 1e-9
                              - (model.density_volume() - self._density_volume0)) / (volume0 * 1e-9)
        self.max_volume_mismatch = max(self.max_volume_mismatch, volume_mismatch)
        self._prev, self._t_prev = cur, t

    def _take_event_snapshots(self, model):
        """Snapshots at the applanations (sign changes of the apex curvature) and the jet peak."""
        t, kappa = self.step_t[-2:], self.step_kappa[-2:]
        if (self.snapshots["first_applanation"] is None
                and curvature_crossings(t, kappa, downward=True)):
            self._take("first_applanation", model)
        if curvature_crossings(t, kappa, downward=False):
            self._take("second_applanation", model)
        # the peak of a pulse switched off by the eye (the ORA's) is known once it is passed
        if self.snapshots["jet_peak"] is None and model.t >= model.jet.peak_time:
            self._take("jet_peak", model)

    def _interpolate_histories(self, model, cur):
        """Fill the output times passed in this step, linearly between the last two steps."""
        t, t_prev, prev = model.t, self._t_prev, self._prev
        out_t, hist = self.out_t, self.histories
        while self._next_out < out_t.shape[0] and out_t[self._next_out] <= t + 1e-15:
            i = self._next_out
            if len(prev) != len(cur):
                raise RuntimeError("the step before an output time was probed only in part")
            s = (out_t[i] - t_prev) / (t - t_prev)
            for k in cur:
                hist[k][i] = prev[k] + s * (cur[k] - prev[k])
            if hist["apex_deformation"][i] > self._best_da:
                self._best_da = hist["apex_deformation"][i]
                self._take("max_displacement", model)
            self._next_out += 1

    def result(self, model: CoupledModel, wall_s: float) -> RunResult:
        """The RunResult of the finished run (``wall_s``: its wall time [s])."""
        self._take("end", model)
        hist = self.histories
        # the pulse is analytic: store it exactly on the output grid, not interpolated (a pulse
        # switched off by the eye has its switch-off time by now, and is unchanged before it)
        hist["jet_pressure_apex"] = (np.array([model.jet.at_apex(t) for t in self.out_t])
                                     / MMHG_PA)
        metrics, notes, extra = compute_metrics(
            self.out_t * 1e3, hist, np.array(self.step_t), np.array(self.step_kappa),
            np.array(self.step_fluid_p),
            lambda t_ms: model.jet.at_apex(t_ms * 1e-3) / MMHG_PA, model.jet.peak_time * 1e3,
            np.array(self.step_budget), np.array(self.step_velocity),
            np.array(self.step_signal) if model.readout is not None else None,
            model.readout is not None and model.readout.passages)
        diagnostics = self._diagnostics(model, wall_s)
        diagnostics.update(extra)
        # the output times as the run's netCDF stores them (``decodable_ms``), so that the result
        # in memory and its file agree bit for bit
        return RunResult(params=model.params, time=decodable_ms(self.out_t * 1e3), histories=hist,
                         snapshot_time=np.array([self.snapshot_t[lbl] for lbl in SNAPSHOT_LABELS]),
                         snapshots=self._snapshot_arrays(), metrics=metrics, metric_notes=notes,
                         diagnostics=diagnostics)

    def _snapshot_arrays(self):
        """(snapshot, node) arrays, NaN where the instant did not occur."""
        template = self.snapshots["initial"]
        arrays = {}
        for name in template:
            rows = [self.snapshots[lbl][name] if self.snapshots[lbl] is not None
                    else np.full_like(template[name], np.nan) for lbl in SNAPSHOT_LABELS]
            arrays[name] = np.stack(rows)
        return arrays

    def _diagnostics(self, model, wall_s):
        """The recorder's step statistics and what the model reports of its parts."""
        dts = np.array(self.dts) if self.dts else np.array([0.0])
        iters = self.iterations
        return {
            "steps": len(self.dts),
            "dt_mean_us": float(dts.mean() * 1e6),
            "dt_min_us": float(dts.min() * 1e6),
            "dt_max_us": float(dts.max() * 1e6),
            "mean_coupling_iterations": float(np.mean(iters)) if iters else 0.0,
            "max_coupling_iterations": int(np.max(iters)) if iters else 0,
            "max_coupling_residual": float(self.max_residual),
            "mean_membrane_substeps": float(np.mean(self.substeps)) if self.substeps else 0.0,
            "mean_hyperviscous_substeps": (float(np.mean(self.hv_substeps)) if self.hv_substeps
                                           else 0.0),
            "wall_s": wall_s,
            "threads": current_threads(),  # of the kernels; the result does not depend on it
            "max_volume_mismatch": self.max_volume_mismatch,
            "kappa_support": KAPPA,
            "viscous_limited_steps": int(self.viscous_limited_steps),
            **model.diagnostics(),
        }
