"""The air jet of eq. (11) on the cornea's nodes (Numba kernels, SI units)."""

import numpy as np
from numba import njit


@njit(cache=True)
def air_jet(t, phi, pmax, a, b, T, t0):
    """Eq. (11): p_a = pmax exp(-a sin^2 phi) exp(-b (t - t0)^2 / T^2)  [Pa]."""
    s = np.sin(phi)
    return pmax * np.exp(-a * s * s) * np.exp(-b * (t - t0) * (t - t0) / (T * T))


@njit(cache=True)
def jet_pressures(t, phi, jet, out):
    """out[k] = the air jet, eq. (11), at time t [s] on the node of reference angle phi[k]
    [Pa]; jet = (pmax, a, b, T, t0) as ``loads.AirJet.kernel_args``."""
    for k in range(phi.shape[0]):
        out[k] = air_jet(t, phi[k], jet[0], jet[1], jet[2], jet[3], jet[4])
