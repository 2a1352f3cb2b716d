"""Time integration of the stabilising hyperviscosity over one fluid step: first-order
Runge-Kutta-Legendre super-time-stepping (RKL1; Meyer, Balsara & Aslam, MNRAS 422, 2102, 2012).

The hyperviscous system d f/dt = S H f (S = diag(gamma c h^5), H = L^3 or K^* L K,
``kernels.mfpm.hyperviscous_flow_operator``) is stiff: forward Euler is stable only for
tau |lambda| <= 2 (lambda the eigenvalues of S H, real and non-positive).  One RKL1 super-step
of length tau with s stages is the recursion (w1 = 2 / (s^2 + s))

    Y_0 = f,  Y_1 = Y_0 + w1 tau S H Y_0,
    Y_j = mu_j Y_{j-1} + nu_j Y_{j-2} + mu_j w1 tau S H Y_{j-1},  mu_j = (2j - 1)/j,
    nu_j = (1 - j)/j,  j = 2 ... s,

whose amplification factor is the Legendre polynomial P_s(1 + w1 tau lambda): first-order
accurate, |P_s| <= 1 for tau |lambda| <= s^2 + s, i.e. (s^2 + s)/2 forward-Euler steps for s
operator applications.  s = 1 is one forward-Euler step.

P_s has negative lobes down to about -0.45 inside that interval.  In the fluid step the
hyperviscous increment is added to the explicit viscous and pressure increments of the same
state, and a factor near -0.45 plus a viscous factor near -0.7 (mu at its time-step limit)
leaves the unit circle (a run at mu = 2.5 Pa s blows up with one super-step per fluid step:
docs/model.md section 4).  The step is therefore covered by K >= 2 equal super-steps whenever
s >= 2, so the factor P_s^K is never below -0.125 (K = 3, s = 2), while forward Euler's sub-steps
(s = 1) stay no lower than 1 - HV_SAFETY / HV_MARGIN.
``legendre_plan`` picks the cheapest such (K, s); it never needs more operator applications
than forward-Euler sub-cycling.
"""

import math

import numpy as np
from numba import njit

from .mfpm import FUSED_MULTIPLY_ADD, flow_operator_work, hyperviscous_flow_operator


def legendre_plan(steps):
    """(K super-steps, s stages each) with the fewest operator applications K s that cover
    ``steps`` forward-Euler steps, K (s^2 + s) / 2 >= steps, with K >= 2 when s >= 2 (module
    docstring); at equal cost the smaller s (s = 1 is forward-Euler sub-cycling)."""
    best = (max(1, math.ceil(steps - 1e-12)), 1)
    s = 2
    while s <= best[0] * best[1]:
        k = max(2, math.ceil(2.0 * steps / (s * s + s) - 1e-12))
        if k * s < best[0] * best[1]:
            best = (k, s)
        s += 1
    return best


def increments_work(n):
    """Scratch arrays of ``hyperviscous_flow_increments`` for n nodes."""
    return np.empty((12, n)), flow_operator_work(n)


@njit(cache=True, fastmath=FUSED_MULTIPLY_ADD)
def hyperviscous_flow_increments(rho, vx, vy, pinned_vx, pinned_vy, start, nbr, sign, count,
                                 lap_b, lap_c, area, consistent_density, consistent_velocity,
                                 scale, velocity_factor, rho_source, dt, stages, supersteps,
                                 n_chunks, work, operator_work, out_rho, out_vx, out_vy):
    """Change of rho, v_x and v_y over dt [s] under d f/dt = scale H f by ``supersteps`` RKL1
    super-steps of dt / supersteps with ``stages`` stages each (module docstring):
    out_f = Y - f.  H and its arguments (start ... consistent_velocity) as
    ``hyperviscous_flow_operator``; ``scale`` = the density's gamma c h^5 per node, the
    velocity's ``velocity_factor`` times it.

    ``rho_source`` [kg/m^3/s]: a rate held fixed over dt that the density's stages integrate
    together with the hyperviscosity, d rho/dt = scale H rho + rho_source, and that is taken out
    of the increment again: out_rho = Y - rho - dt rho_source.  The caller adds the source itself
    (the continuity equation's rate); integrated together, a density that the hyperviscosity
    balances against it, scale H rho = -rho_source, is the steady state of the stages at any dt
    (docs/model.md section 4).  Zero: the hyperviscosity alone.

    Nodes with ``pinned_vx`` / ``pinned_vy`` keep their velocity component in every stage
    (Dirichlet nodes: walls, the cornea, v_x on the axis); no density is pinned.  ``work`` and
    ``operator_work`` are the scratch arrays of ``increments_work``; ``n_chunks``: the operator's
    node chunks (``kernels.mfpm.chunks``; the result does not depend on it).
    """
    n = rho.shape[0]
    w1 = 2.0 / (stages * (stages + 1))
    base_r, base_x, base_y = work[9], work[10], work[11]  # Y_0 of the super-step
    prev_r, prev_x, prev_y = work[0], work[1], work[2]  # Y_{j-1}
    old_r, old_x, old_y = work[3], work[4], work[5]  # Y_{j-2}, overwritten by Y_j
    h_r, h_x, h_y = work[6], work[7], work[8]  # H Y_{j-1}
    for i in range(n):
        prev_r[i] = rho[i]
        prev_x[i] = vx[i]
        prev_y[i] = vy[i]
    tau_step = dt / supersteps
    for _ in range(supersteps):
        for i in range(n):
            base_r[i] = prev_r[i]
            base_x[i] = prev_x[i]
            base_y[i] = prev_y[i]
        hyperviscous_flow_operator(base_r, base_x, base_y, start, nbr, sign, count,
                                   lap_b, lap_c, area, consistent_density, consistent_velocity,
                                   n_chunks, operator_work, h_r, h_x, h_y)
        tau = w1 * tau_step
        for i in range(n):
            s = scale[i]
            sv = s * velocity_factor
            prev_r[i] = base_r[i] + tau * (h_r[i] * s + rho_source[i])
            prev_x[i] = vx[i] if pinned_vx[i] else base_x[i] + tau * (h_x[i] * sv)
            prev_y[i] = vy[i] if pinned_vy[i] else base_y[i] + tau * (h_y[i] * sv)
            old_r[i] = base_r[i]
            old_x[i] = base_x[i]
            old_y[i] = base_y[i]
        for j in range(2, stages + 1):
            mu = (2.0 * j - 1.0) / j
            nu = (1.0 - j) / j
            tau = mu * w1 * tau_step
            hyperviscous_flow_operator(prev_r, prev_x, prev_y, start, nbr, sign, count,
                                       lap_b, lap_c, area, consistent_density,
                                       consistent_velocity, n_chunks, operator_work, h_r, h_x,
                                       h_y)
            for i in range(n):
                s = scale[i]
                sv = s * velocity_factor
                old_r[i] = mu * prev_r[i] + nu * old_r[i] + tau * (h_r[i] * s + rho_source[i])
                old_x[i] = (vx[i] if pinned_vx[i]
                            else mu * prev_x[i] + nu * old_x[i] + tau * (h_x[i] * sv))
                old_y[i] = (vy[i] if pinned_vy[i]
                            else mu * prev_y[i] + nu * old_y[i] + tau * (h_y[i] * sv))
            prev_r, old_r = old_r, prev_r
            prev_x, old_x = old_x, prev_x
            prev_y, old_y = old_y, prev_y
    for i in range(n):
        out_rho[i] = prev_r[i] - rho[i] - dt * rho_source[i]
        out_vx[i] = prev_x[i] - vx[i]
        out_vy[i] = prev_y[i] - vy[i]
