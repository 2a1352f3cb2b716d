"""The air pulse of an instrument on the cornea's nodes (Numba kernels, SI units).

A pulse is one float64 array, ``jet`` (``loads.*.kernel_args``), whose first entry names its
kind:

- ``PAPER`` (0): the paper's jet, eq. (11), jet = (PAPER, pmax, a, b, T, t0):
      p_a(t, phi) = pmax exp(-a sin^2 phi) exp(-b (t - t0)^2 / T^2)
- ``RAMP`` (1) and ``TABLE`` (2): a time profile A(t) [Pa] times the spatial profile
  exp(-a sin^2 phi), switched off at t_off:
      p_a(t, phi) = A(t) exp(-a sin^2 phi),
      A(t) = f(t)                                    for t <= t_off,
      A(t) = max(0, f(t_off) - r_fall (t - t_off))   for t >  t_off,
  jet = (kind, a, t_off, r_fall, profile...), with f the kind's rise:
  RAMP, profile (t_on, r_rise, tau): the rate rising linearly from 0 to r_rise over tau
  from t_on (a pump's pressure rate cannot jump), then constant: with u = t - t_on,
      f = 0 (u <= 0),   r_rise u^2 / (2 tau) (0 < u < tau),   r_rise (u - tau/2) (u >= tau)
  (tau = 0: the sharp ramp r_rise max(0, t - t_on));
  TABLE, profile (t_start, dt, f_0, ..., f_{n-1}): f linear between the samples f_k at
  t_start + k dt, 0 outside them.
  t_off = inf (never switched off) unless the pulse sets it while the run goes on
  (``loads/ora.py``: a fixed delay after the first applanation it detects).

Every kind is a factor of phi times a factor of t (``pulse_space_factor``, ``pulse_time_factor``):
the cornea kernels take the space factor on their nodes, made once per run (``pulse_space``), and
evaluate the time factor once per sub-step.
"""

import numpy as np
from numba import njit

PAPER = 0
RAMP = 1
TABLE = 2
# entries of a RAMP or TABLE pulse
KIND, SPATIAL_DECAY, SWITCH_OFF, FALL_RATE, PROFILE = 0, 1, 2, 3, 4


@njit(cache=True)
def air_jet(t, phi, pmax, a, b, T, t0):
    """Eq. (11): p_a = pmax exp(-a sin^2 phi) exp(-b (t - t0)^2 / T^2)  [Pa]."""
    s = np.sin(phi)
    return pmax * np.exp(-a * s * s) * np.exp(-b * (t - t0) * (t - t0) / (T * T))


@njit(cache=True)
def rise(t, jet):
    """f(t) [Pa], the pulse's time profile before its switch-off (RAMP or TABLE)."""
    if jet[KIND] == RAMP:
        u = max(0.0, t - jet[PROFILE])
        tau = jet[PROFILE + 2]
        if u < tau:
            return jet[PROFILE + 1] * u * u / (2.0 * tau)
        return jet[PROFILE + 1] * (u - 0.5 * tau)
    t_start, dt = jet[PROFILE], jet[PROFILE + 1]
    n = jet.shape[0] - PROFILE - 2
    u = (t - t_start) / dt
    if u < 0.0 or u > n - 1:
        return 0.0
    k = min(int(u), n - 2)
    s = u - k
    return (1.0 - s) * jet[PROFILE + 2 + k] + s * jet[PROFILE + 3 + k]


@njit(cache=True)
def pulse_amplitude(t, jet):
    """A(t) [Pa]: the rise f(t) until the switch-off t_off, then falling from f(t_off) at
    r_fall down to 0 (RAMP or TABLE)."""
    t_off = jet[SWITCH_OFF]
    if t <= t_off:
        return rise(t, jet)
    return max(0.0, rise(t_off, jet) - jet[FALL_RATE] * (t - t_off))


@njit(cache=True)
def pulse_space_factor(phi, jet):
    """The pulse's factor of the reference angle phi: pmax exp(-a sin^2 phi) [Pa] for the
    paper's jet, exp(-a sin^2 phi) for the others."""
    s = np.sin(phi)
    if jet[KIND] == PAPER:
        return jet[1] * np.exp(-jet[2] * s * s)
    return np.exp(-jet[SPATIAL_DECAY] * s * s)


@njit(cache=True)
def pulse_time_factor(t, jet):
    """The pulse's factor of the time t [s]: exp(-b (t - t0)^2 / T^2) for the paper's jet, A(t)
    [Pa] for the others."""
    if jet[KIND] == PAPER:
        b, T, t0 = jet[3], jet[4], jet[5]
        return np.exp(-b * (t - t0) * (t - t0) / (T * T))
    return pulse_amplitude(t, jet)


@njit(cache=True)
def pulse_pressure(t, phi, jet):
    """p_a(t, phi) [Pa] of any pulse kind (module docstring): the space factor times the time
    factor, in the order of eq. (11) (``air_jet``), so the paper's jet has the same bits."""
    return pulse_space_factor(phi, jet) * pulse_time_factor(t, jet)


@njit(cache=True)
def pulse_space(phi, jet, out):
    """out[k] = the pulse's space factor at the reference angle phi[k] (``pulse_space_factor``):
    made once per run, the cornea kernels multiply it by the time factor at every sub-step."""
    for k in range(phi.shape[0]):
        out[k] = pulse_space_factor(phi[k], jet)


@njit(cache=True)
def jet_pressures(t, phi, jet, out):
    """out[k] = p_a(t, phi[k]) [Pa], the pulse ``jet`` at time t [s] on the node of reference
    angle phi[k]."""
    for k in range(phi.shape[0]):
        out[k] = pulse_pressure(t, phi[k], jet)
