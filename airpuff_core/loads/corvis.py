"""The Corvis ST's air pulse (``instrument = corvis``; docs/model.md section 6).

The Corvis's pulse does not depend on the eye: a fixed time profile on the cornea, tabulated
below, times the spatial profile exp(-a sin^2 phi) (SI):

    p_a(t, phi) = f(t) exp(-a sin^2 phi),   f linear between the samples of ``CORVIS_APEX_MMHG``.

The time profile is the pressure on the cornea's apex of the Corvis ST's puff, "Pressure on the
Cornea", supplementary material of Eliasy et al., Curr Eye Res 48 (2023) 382 (CFD of the
Corvis puff matched to its measurements, Elsheikh's group), as digitised in the public R
package onEyeAirpuff (0.05 ms steps, smoothed), sampled here every 0.5 ms: onset at 4.5 ms,
peak 94.2 mmHg (12.6 kPa) at 18 ms, back to 0 at 26 ms.  docs/model.md section 6 sets it
beside the same group's earlier curve (Joda et al. 2016) and the other sources.
"""

from __future__ import annotations

import math

import numpy as np

from ..kernels.air_jet import TABLE
from ..params import MMHG_PA
from .pulse import AirPulse

CORVIS_START_MS = 4.5  # ms, the first sample
CORVIS_STEP_MS = 0.5  # ms between samples
# the pressure on the apex [mmHg] at CORVIS_START_MS + k CORVIS_STEP_MS
CORVIS_APEX_MMHG = (
    0.0, 2.13, 5.17, 10.78, 15.50, 19.94, 24.39, 28.69, 32.99, 37.35, 41.59, 46.04, 50.00,
    54.18, 58.32, 62.47, 66.62, 70.77, 74.60, 78.43, 82.11, 85.52, 87.74, 89.82, 91.74, 93.18,
    93.90, 94.21, 94.13, 93.38, 91.89, 89.63, 86.68, 83.02, 78.56, 72.79, 66.01, 58.60, 50.28,
    41.00, 30.76, 19.51, 8.06, 0.0,
)


class CorvisPulse(AirPulse):
    """The Corvis ST's pulse of a run (``SIParams`` si: a) on the cornea's nodes of reference
    angles phi [rad]."""

    name = "corvis"

    def __init__(self, si, phi):
        samples = np.asarray(CORVIS_APEX_MMHG) * MMHG_PA  # Pa
        # (TABLE, a, t_off [s] (never), r_fall [Pa/s] (unused), t_start [s], dt [s], f_k [Pa])
        self.kernel_args = np.concatenate((
            [TABLE, si.a, math.inf, 0.0, CORVIS_START_MS * 1e-3, CORVIS_STEP_MS * 1e-3],
            samples))
        self._peak_time = (CORVIS_START_MS + CORVIS_STEP_MS * int(np.argmax(samples))) * 1e-3
        self.set_nodes(phi)

    @property
    def peak_time(self):
        return self._peak_time
