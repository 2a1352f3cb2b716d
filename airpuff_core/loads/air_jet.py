"""The air jet of the paper, eq. (11) (``instrument = paper``): the pressure it puts on the
cornea from outside (SI).

    p_a(t, phi) = pmax exp(-a sin^2 phi) exp(-b (t - t0)^2 / T^2)

with phi the reference angle of a cornea node (0 at the apex).
"""

from __future__ import annotations

import numpy as np

from ..kernels.air_jet import PAPER
from .pulse import AirPulse


class AirJet(AirPulse):
    """The air jet of a run (``SIParams`` si: pmax_Pa, a, b, T_s, t0_s) on the cornea's nodes of
    reference angles phi [rad]."""

    name = "paper"

    def __init__(self, si, phi):
        # (PAPER, pmax [Pa], a, b, T [s], t0 [s]): the arguments of the kernels, in their order
        self.kernel_args = np.array([PAPER, si.pmax_Pa, si.a, si.b, si.T_s, si.t0_s])
        self._peak_time = si.t0_s  # s
        self.set_nodes(phi)

    @property
    def peak_time(self):
        return self._peak_time
