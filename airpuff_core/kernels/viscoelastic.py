"""Quasi-linear viscoelasticity (Fung) with a Prony series, by Simo's recursive update (SI units).

Fung's QLV law gives a stress resultant S (membrane force N [N/m] or bending moment M [N]) as the
hereditary integral of an elastic response S_e with a reduced relaxation function G:

    S(t) = int_{-inf}^{t} G(t - s) dS_e/ds ds,     G(t) = 1 - sum_i g_i (1 - exp(-t / tau_i))

G(0) = 1: S_e is the instantaneous response.  G(inf) = G_inf = 1 - sum_i g_i: a strain held long
enough carries G_inf S_e.

Modulus convention (docs/model.md, "Viscoelasticity"): the elastic law written with the user's E0
is the EQUILIBRIUM (fully relaxed) law S_eq, and S_e = S_eq / G_inf.  The cornea at rest has carried
the IOP for ever, so it is fully relaxed and carries S_eq: its rest state is exactly the elastic
model's, and nothing moves without the jet.  The instantaneous modulus is E0 / G_inf.

Writing h_i(t) = int exp(-(t - s)/tau_i) dS_e/ds ds, the law is S = G_inf S_e + sum_i g_i h_i,
i.e. with the overstresses q_i = g_i h_i (zero in the relaxed state)

    S = S_eq + sum_i q_i,
    q_i^{n+1} = exp(-dt/tau_i) q_i^n + (g_i / G_inf) (tau_i/dt) (1 - exp(-dt/tau_i)) (S_eq^{n+1} - S_eq^n)

which is exact when S_eq varies linearly in time within each step (Simo and Hughes,
Computational Inelasticity, Springer 1998, section 10.3; Simo, Comput. Methods Appl. Mech. Eng.
60 (1987) 153).  With every g_i = 0 the weights vanish and S = S_eq + 0 exactly.
"""

import numpy as np
from numba import njit

from .sums import numpy_sum


@njit(cache=True)
def prony_step_factors(dt, g, tau, decay, weight):
    """Per-term factors of one step dt [s] (written into ``decay`` and ``weight``):

        decay_i  = exp(-dt / tau_i)
        weight_i = g_i / G_inf * (tau_i / dt) (1 - exp(-dt / tau_i)),   G_inf = 1 - sum g_i

    ``g`` [1] and ``tau`` [s] are the Prony terms.  (tau_i/dt)(1 - exp(-dt/tau_i)) is computed with
    expm1, so a step much shorter than tau_i loses no digits; its limit dt -> 0 is 1.
    """
    g_inf = 1.0
    for i in range(g.shape[0]):
        g_inf -= g[i]
    for i in range(g.shape[0]):
        x = dt / tau[i]
        decay[i] = np.exp(-x)
        weight[i] = g[i] / g_inf * (-np.expm1(-x) / x if x > 0.0 else 1.0)


@njit(cache=True)
def relax_resultant(s_eq_old, s_eq_new, decay, weight, overstress):
    """One Simo update of the overstresses of one resultant; returns the total resultant.

    ``overstress`` (one entry per Prony term, updated in place) holds q_i at the start of the
    step; s_eq_old and s_eq_new are the equilibrium-law resultants at its start and end.
    Returns S = s_eq_new + sum_i q_i^{n+1}.
    """
    ds = s_eq_new - s_eq_old
    total = s_eq_new
    for i in range(decay.shape[0]):
        q = decay[i] * overstress[i] + weight[i] * ds
        overstress[i] = q
        total += q
    return total


@njit(cache=True)
def relax_in_place(values, previous, decay, weight, overstress, advance):
    """Turn the equilibrium-law resultants ``values`` into total resultants, in place.

    advance: one Simo step from ``previous`` (the equilibrium resultants at the start of the
    step, then set to ``values``' equilibrium values) with the factors decay, weight; otherwise
    the stored overstresses are only added (the state at the start of a step).  overstress has
    shape (terms, n)."""
    for k in range(values.shape[0]):
        s_new = values[k]
        if advance:
            values[k] = relax_resultant(previous[k], s_new, decay, weight, overstress[:, k])
            previous[k] = s_new
        else:
            total = s_new
            for i in range(decay.shape[0]):
                total += overstress[i, k]
            values[k] = total


def relaxation_function(t, g, tau):
    """G(t) = 1 - sum_i g_i (1 - exp(-t / tau_i)) [1] for times t [s] (numpy broadcasting)."""
    t = np.asarray(t, dtype=float)
    G = np.ones_like(t)
    for gi, ti in zip(g, tau):
        G = G - gi * (1.0 - np.exp(-t / ti))
    return G


@njit(cache=True)
def paired_overstress_work(area, q_a, q_b, a_new, a_old, b_new, b_old):
    """Work [J] of two rows of mean overstresses q_a, q_b over the changes of their strains
    a_old -> a_new and b_old -> b_new, on the areas ``area`` [m^2]:

        sum area (q_a (a_new - a_old) + q_b (b_new - b_old)),

    term by term as numpy forms it, summed as ``np.sum`` does (``sums.numpy_sum``)."""
    terms = np.empty(area.shape[0])
    for i in range(area.shape[0]):
        terms[i] = area[i] * (q_a[i] * (a_new[i] - a_old[i]) + q_b[i] * (b_new[i] - b_old[i]))
    return numpy_sum(terms)


@njit(cache=True)
def row_overstress_work(area, q, new, old):
    """Work [J] of one row of mean overstresses q over the change of its strain old -> new on
    the areas ``area`` [m^2]: sum (area q) (new - old), summed as ``np.sum`` does."""
    terms = np.empty(area.shape[0])
    for i in range(area.shape[0]):
        terms[i] = area[i] * q[i] * (new[i] - old[i])
    return numpy_sum(terms)


@njit(cache=True)
def membrane_overstress_energy(area, c11, c12, c22, q1, q2):
    """q . C^-1 q [J] of the membrane overstresses q1, q2 on the areas ``area`` [m^2], with the
    compliance (c11, c12, c22) per segment [m/N]:

        sum area (c11 q1^2 + 2 c12 q1 q2 + c22 q2^2),

    term by term as numpy forms it, summed as ``np.sum`` does (``sums.numpy_sum``)."""
    terms = np.empty(area.shape[0])
    for i in range(area.shape[0]):
        terms[i] = area[i] * (c11[i] * q1[i] * q1[i] + 2.0 * c12[i] * q1[i] * q2[i]
                              + c22[i] * q2[i] * q2[i])
    return numpy_sum(terms)


@njit(cache=True)
def bending_overstress_energy(area, inverse, nu, q_s, q_t):
    """q . C^-1 q [J] of the bending overstresses q_s, q_t with C = D [[1, nu], [nu, 1]],
    inverse = 1 / (D (1 - nu^2)):

        sum area inverse (q_s^2 - 2 nu q_s q_t + q_t^2),

    term by term as numpy forms it, summed as ``np.sum`` does."""
    two_nu = 2.0 * nu
    terms = np.empty(area.shape[0])
    for i in range(area.shape[0]):
        terms[i] = area[i] * inverse * (q_s[i] * q_s[i] - two_nu * q_s[i] * q_t[i]
                                        + q_t[i] * q_t[i])
    return numpy_sum(terms)


@njit(cache=True)
def row_overstress_energy(area, q):
    """sum area q^2 of one row of overstresses q on the areas ``area`` [m^2] (its energy times
    the row's stiffness), term by term as numpy forms it, summed as ``np.sum`` does."""
    terms = np.empty(area.shape[0])
    for i in range(area.shape[0]):
        terms[i] = area[i] * q[i] * q[i]
    return numpy_sum(terms)
