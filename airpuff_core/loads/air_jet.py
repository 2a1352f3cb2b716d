"""The air jet of the paper, eq. (11): the pressure it puts on the cornea from outside (SI).

    p_a(t, phi) = pmax exp(-a sin^2 phi) exp(-b (t - t0)^2 / T^2)

with phi the reference angle of a cornea node (0 at the apex).  The cornea kernels evaluate it
inside their sub-steps from ``kernel_args``; the start at rest, the energy budget and the
recorder use the methods here.
"""

from __future__ import annotations

import numpy as np

from ..kernels.air_jet import air_jet, jet_pressures


class AirJet:
    """The air jet of a run (``SIParams`` si: pmax_Pa, a, b, T_s, t0_s)."""

    def __init__(self, si):
        # (pmax [Pa], a, b, T [s], t0 [s]): the arguments of the kernels, in their order
        self.kernel_args = np.array([si.pmax_Pa, si.a, si.b, si.T_s, si.t0_s])
        self.peak_time = si.t0_s  # s

    def pressures(self, t, phi, out):
        """out[k] = p_a(t, phi[k]) [Pa] at time t [s] on the nodes of reference angles phi."""
        jet_pressures(t, phi, self.kernel_args, out)

    def at_apex(self, t):
        """p_a(t, 0) [Pa] at time t [s]."""
        return air_jet(t, 0.0, *self.kernel_args)
