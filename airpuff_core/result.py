"""The result of one run: time histories, snapshots and metrics, in user units, and its
CF-annotated ``xarray.Dataset``.

``RunResult`` is what :func:`airpuff_core.simulate` returns.  ``METRICS``, ``HISTORIES`` and
``SNAPSHOT_FIELDS`` name its contents with their units: they are the netCDF variables of
docs/model.md section 7, a contract for the sweep and users' scripts.  Run parameters are scalar
coordinates of the dataset (user units, with a ``units`` attribute) and are repeated as global
attributes; ``dataset.py`` writes the file.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .params import CHOICES, PARAMETERS, RunParams
from .calibration import calibrate_metrics, variable_attrs
from .provenance import model_version, provenance

# metric name -> (unit, long name).  Missing metrics are NaN in arrays and None in JSON.  The
# applanation readings are raw (the instrument's pressure at the apex, no calibration); their
# calibrated forms are ``calibration.CALIBRATED`` (``<name>_cal``).
METRICS: dict[str, tuple[str, str]] = {
    "P1": ("mmHg", "jet pressure at the apex at the first applanation (raw)"),
    "P2": ("mmHg", "jet pressure at the apex at the second applanation (raw)"),
    "CH": ("mmHg", "corneal hysteresis P1 - P2 (raw)"),
    "IOPg": ("mmHg", "Goldmann-equivalent IOP 0.5 (P1 + P2) (raw: not on Goldmann's scale)"),
    "IOPcc": ("mmHg", "corneal-compensated IOP P1 - 0.43 P2 (paper's definition, raw)"),
    "CRF": ("mmHg", "corneal resistance factor P1 - 0.7 P2 (ORA, Luce 2006; raw, without the "
                    "device's constant)"),
    "IOPcc_ora": ("mmHg", "corneal-compensated IOP P2 - 0.43 P1 (ORA, Luce 2006; raw, without "
                          "the device's scale and constant)"),
    "t_A1": ("ms", "time of the first applanation"),
    "t_A2": ("ms", "time of the second applanation"),
    "t_HC": ("ms", "time of highest concavity (the maximum of apex_deformation; Corvis HC time)"),
    "hc_delay": ("ms", "delay of the highest concavity after the jet peak"),
    "DA": ("mm", "deformation amplitude: maximum inward apex displacement as the instrument sees "
                 "it, the deflection plus the whole eye's movement (Corvis DA)"),
    "deflection_amplitude": ("mm", "maximum inward apex displacement against the limbus, without "
                                   "the whole eye's movement (Corvis deflection amplitude max)"),
    "deflection_amplitude_HC": ("mm", "apex displacement against the limbus at the highest "
                                      "concavity (DA = deflection_amplitude_HC + WEM_HC)"),
    "WEM_max": ("mm", "maximum whole-eye movement away from the nozzle (Corvis WEM max; 0 with "
                      "eye_motion=none)"),
    "t_WEM_max": ("ms", "time of the maximum whole-eye movement"),
    "WEM_HC": ("mm", "whole-eye movement at the highest concavity"),
    "peak_distance": ("mm", "distance between the two peaks (most anterior points) of the deformed "
                            "cornea's mid-surface at the highest concavity (Corvis peak distance)"),
    "v_A1": ("m/s", "inward apex velocity at the first applanation as the instrument sees it, the "
                    "eye's movement included (Corvis A1 velocity)"),
    "v_A2": ("m/s", "inward apex velocity at the second applanation as the instrument sees it, "
                    "negative outward (Corvis A2 velocity)"),
    "v_in_max": ("m/s", "peak inward apex velocity against the limbus"),
    "v_out_max": ("m/s", "peak outward apex velocity against the limbus"),
}
# the raw readings that have a calibrated form (netCDF attribute calibration = "raw")
RAW_READINGS = ("P1", "P2", "CH", "IOPg", "IOPcc", "CRF", "IOPcc_ora")
# the apex force budget at each applanation and its difference, CH's parts (metrics.py,
# docs/model.md section 7)
_BUDGET_NAMES = {
    "profile": "the jet pressure at the apex minus its mean over the apex nodes",
    "fluid": "fluid pressure under the apex (IOP included)",
    "equilibrium": "the cornea's equilibrium resistance (internal forces of the elastic law)",
    "overstress": "the cornea's viscoelastic overstress",
    "inertia": "minus the inertia of the apex nodes",
    "residual": "the jet's mean over the apex nodes minus the four parts before",
}
for _name, _long in (("P1", "first applanation"), ("P2", "second applanation"),
                     ("CH", "hysteresis P1 - P2")):
    for _part, _text in _BUDGET_NAMES.items():
        METRICS[f"{_name}_{_part}"] = ("mmHg", f"apex force budget, {_long}: {_text}")

# history name -> (unit, long name)
HISTORIES: dict[str, tuple[str, str]] = {
    "apex_displacement": ("mm", "apex displacement against the limbus (the deflection), positive "
                          "inward"),
    "apex_velocity": ("m/s", "apex velocity against the limbus, positive inward"),
    "apex_deformation": ("mm", "apex displacement as the instrument sees it: apex_displacement "
                         "plus eye_displacement, positive inward"),
    "eye_displacement": ("mm", "whole-eye movement away from the nozzle (0 with eye_motion=none)"),
    "eye_velocity": ("m/s", "whole-eye velocity away from the nozzle"),
    "pulse_force": ("mN", "net axial force of the air pulse on the deformed cornea, positive away "
                    "from the nozzle: what pushes the whole eye back"),
    "peak_distance": ("mm", "distance between the two peaks (most anterior points) of the "
                      "cornea's mid-surface; NaN while the apex is the most anterior point"),
    "apex_curvature": ("1/mm", "apical curvature of the cornea, positive convex"),
    "ora_reflection_signal": ("1", "the ORA's applanation signal: the fraction of the light "
                              "reflected from the central zone that reaches its detector (1 for "
                              "a flat zone; NaN with another instrument)"),
    "corvis_flat_departure": ("mm", "the Corvis ST's applanation signal: the rms departure from "
                              "flat of the central cornea over the applanation length (NaN with "
                              "another instrument)"),
    "jet_pressure_apex": ("mmHg", "air-jet pressure at the apex"),
    "fluid_pressure_apex": ("mmHg", "fluid pressure at the apex"),
    "chamber_volume": ("mm^3", "volume of the anterior chamber"),
    "wall_volume_change": ("mm^3", "volume by which the compliant walls have given way "
                           "(0 with globe=rigid)"),
    "globe_pressure": ("mmHg", "pressure of the globe's pressure-volume law for the volume the "
                       "cornea has pushed in (the IOP with globe=rigid)"),
    "wall_pressure": ("mmHg", "the fluid's mean pressure on the walls behind it (weighted by the "
                      "volume each sweeps when compliant); minus globe_pressure: the chamber's "
                      "acoustic ringing"),
    "apex_bending_moment": ("mN", "meridional bending moment M_s at the apex, per unit length "
                            "(N m/m; 0 for the membrane)"),
    # the energy budget, cumulative from t = 0 (energy.py)
    "jet_work": ("uJ", "work of the air jet on the cornea"),
    "kinetic_energy": ("uJ", "kinetic energy of cornea and fluid, change since t = 0"),
    "elastic_energy": ("uJ", "stored energy (cornea strain and viscoelastic overstress, fluid "
                       "compression), change since t = 0"),
    "tissue_dissipation": ("uJ", "energy dissipated by the cornea's viscoelasticity"),
    "fluid_dissipation": ("uJ", "energy removed by the fluid's viscosity and hyperviscosity"),
    "globe_work": ("uJ", "work of the fluid on the compliant walls (0 with globe=rigid)"),
    "energy_residual": ("uJ", "jet work minus the terms above, plus the energy that sound-speed "
                        "changes add: what the discretisation does not conserve"),
    "coupling_iterations": ("1", "Dirichlet-Neumann iterations in the last solver step"),
    "sound_speed": ("m/s", "artificial sound speed c"),
}

# snapshot field name -> (dims, unit, long name)
SNAPSHOT_FIELDS: dict[str, tuple[str, str, str]] = {
    "cornea_x": ("node", "mm", "cornea node distance from the axis"),
    "cornea_y": ("node", "mm", "cornea node position along the axis"),
    "fluid_x": ("particle", "mm", "fluid node distance from the axis"),
    "fluid_y": ("particle", "mm", "fluid node position along the axis"),
    "fluid_pressure": ("particle", "mmHg", "fluid pressure (gauge)"),
    "fluid_vx": ("particle", "m/s", "fluid velocity, x component"),
    "fluid_vy": ("particle", "m/s", "fluid velocity, y component"),
}

SNAPSHOT_LABELS = (
    "initial",
    "first_applanation",
    "jet_peak",
    "max_displacement",
    "second_applanation",
    "end",
)


@dataclass
class RunResult:
    """Everything one run produced, in user units (ms, mm, mmHg, m/s)."""

    params: RunParams
    time: np.ndarray  # ms
    histories: dict[str, np.ndarray]
    snapshot_time: np.ndarray  # ms, NaN where the instant does not exist
    snapshots: dict[str, np.ndarray]  # (snapshot, node|particle)
    metrics: dict[str, float]  # NaN where missing
    metric_notes: dict[str, str] = field(default_factory=dict)  # reason a metric is missing
    diagnostics: dict[str, Any] = field(default_factory=dict)  # solver figures (steps, dt, ...)

    def metrics_json(self) -> dict[str, Any]:
        """Metrics with None in place of NaN (JSON has no NaN)."""
        return {k: (None if v is None or not np.isfinite(v) else float(v))
                for k, v in self.metrics.items()}

    def to_dataset(self, calibrations=None):
        """The CF-annotated ``xarray.Dataset`` of the run (docs/model.md section 7), with the
        calibrated readings beside the raw ones (``calibration.py``; ``calibrations``: the
        calibrations to look in, default the package's)."""
        import xarray as xr  # only here: the solver does not need xarray

        from .dataset import global_attributes, time_coordinate

        data_vars = {}
        for name, (unit, long_name) in HISTORIES.items():
            data_vars[name] = xr.Variable(("time",), np.asarray(self.histories[name], float),
                                          {"units": unit, "long_name": long_name})
        for name, (dim, unit, long_name) in SNAPSHOT_FIELDS.items():
            data_vars[name] = xr.Variable(("snapshot", dim),
                                          np.asarray(self.snapshots[name], float),
                                          {"units": unit, "long_name": long_name})
        for name, (unit, long_name) in METRICS.items():
            attrs = {"units": unit, "long_name": long_name}
            if name in RAW_READINGS:
                attrs["calibration"] = "raw"
            note = self.metric_notes.get(name)
            if note:
                attrs["comment"] = note
            data_vars[name] = xr.Variable((), float(self.metrics.get(name, np.nan)), attrs)
        calibrated, cal, reason = calibrate_metrics(self.params.to_dict(), self.metrics,
                                                    model_version(), calibrations)
        for name, value in calibrated.items():
            data_vars[name] = xr.Variable((), float(value), variable_attrs(name, cal, reason))

        coords = {
            "time": time_coordinate(self.time),
            "snapshot": ("snapshot", np.arange(len(SNAPSHOT_LABELS)),
                         {"long_name": "snapshot index"}),
            "snapshot_label": ("snapshot", np.array(SNAPSHOT_LABELS, dtype=object),
                               {"long_name": "instant of the snapshot"}),
            "snapshot_time": ("snapshot", np.asarray(self.snapshot_time, float),
                              {"units": "ms", "long_name": "time of the snapshot"}),
        }
        p = self.params
        for name, spec in PARAMETERS.items():
            coords[name] = ((), float(getattr(p, name)),
                            {"units": spec.unit, "long_name": spec.description})

        attrs = global_attributes(
            f"airpuff: coupled {p.cornea} / MFPM simulation of the corneal air-puff test",
            f"simulate ({p.resolution} resolution, t_end {p.t_end:g} ms)")
        attrs.update(provenance())  # airpuff, model and library versions, git commit
        attrs["parameters_json"] = json.dumps(p.to_dict(), sort_keys=True)
        for name in CHOICES:
            attrs[name] = getattr(p, name)
        for name, spec in PARAMETERS.items():
            attrs[f"param_{name}"] = float(getattr(p, name))
        for k, v in self.diagnostics.items():
            if isinstance(v, (int, float, str, np.integer, np.floating)):
                attrs[f"solver_{k}"] = v if not isinstance(v, np.generic) else v.item()
        return xr.Dataset(data_vars, coords=coords, attrs=attrs)
