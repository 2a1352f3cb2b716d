"""The result of one run: time histories, snapshots and metrics, in user units.

``RunResult`` is what :func:`airpuff_core.simulate` returns.  Its field names are the netCDF
variable names of SPEC section 7 (a contract for the sweep and users' scripts); ``dataset.py``
turns it into a CF-annotated ``xarray.Dataset``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .params import RunParams

# metric name -> (unit, long name).  Missing metrics are NaN in arrays and None in JSON.
METRICS: dict[str, tuple[str, str]] = {
    "P1": ("mmHg", "jet pressure at the apex at the first applanation"),
    "P2": ("mmHg", "jet pressure at the apex at the second applanation"),
    "CH": ("mmHg", "corneal hysteresis P1 - P2"),
    "IOPg": ("mmHg", "Goldmann-equivalent IOP 0.5 (P1 + P2)"),
    "IOPcc": ("mmHg", "corneal-compensated IOP P1 - 0.43 P2 (paper's definition)"),
    "CRF": ("mmHg", "corneal resistance factor P1 - 0.7 P2 (ORA, Luce 2006)"),
    "IOPcc_ora": ("mmHg", "corneal-compensated IOP P2 - 0.43 P1 (ORA, Luce 2006)"),
    "t_A1": ("ms", "time of the first applanation"),
    "t_A2": ("ms", "time of the second applanation"),
    "t_HC": ("ms", "time of highest concavity (maximum apex displacement)"),
    "hc_delay": ("ms", "delay of the highest concavity after the jet peak"),
    "DA": ("mm", "deformation amplitude (maximum inward apex displacement)"),
    "v_in_max": ("m/s", "peak inward apex velocity"),
    "v_out_max": ("m/s", "peak outward apex velocity"),
}

# history name -> (unit, long name)
HISTORIES: dict[str, tuple[str, str]] = {
    "apex_displacement": ("mm", "apex displacement, positive inward"),
    "apex_velocity": ("m/s", "apex velocity, positive inward"),
    "apex_curvature": ("1/mm", "apical curvature of the cornea, positive convex"),
    "jet_pressure_apex": ("mmHg", "air-jet pressure at the apex"),
    "fluid_pressure_apex": ("mmHg", "fluid pressure at the apex"),
    "chamber_volume": ("mm^3", "volume of the anterior chamber"),
    "wall_volume_change": ("mm^3", "volume by which the compliant walls have given way "
                           "(0 with globe=rigid)"),
    "globe_pressure": ("mmHg", "pressure of the globe's pressure-volume law for the volume the "
                       "cornea has pushed in (the IOP with globe=rigid)"),
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

    def to_dataset(self):
        from .dataset import result_to_dataset

        return result_to_dataset(self)
