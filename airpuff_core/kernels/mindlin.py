"""Axisymmetric shear-deformable (Reissner-Mindlin) shell, large rotations, discrete energy (SI).

The Kirchhoff-Love shell (``kernels/shell.py``) ties the normal of the shell to the meridian: it
is rigid in transverse shear.  The corneal stroma is a stack of lamellae whose transverse shear
modulus G_t is two to three orders of magnitude below the in-plane modulus (Petsche et al., IOVS
53 (2012) 873: 9.48 +- 2.92 kPa for the full thickness), so here the director carries its own
rotation beta_i [rad] at every node (0 at the apex, beta_ref on the stress-free reference), and
bending and transverse shear are separate strains.  Per segment s (nodes s, s+1, reference
chord L0_s, zone area A0_s, reference mid-point distance x_mid_s from the axis), all evaluated at
the segment's mid-point (one-point, "reduced" integration, the usual cure of shear locking):

    K_s     = ((beta_{s+1} - beta_s) - (beta_ref_{s+1} - beta_ref_s)) / L0_s
    K_theta = (sin betabar_s - sin betabar_ref_s) / x_mid_s,   betabar_s = (beta_s + beta_{s+1})/2
    gamma_s = (psi_s - psi_ref_s) - (betabar_s - betabar_ref_s)      (transverse shear strain)

with psi_s the segment's meridian angle (``segment_angles``).  The energy is

    Pi = sum_s A0_s [ W_membrane(E1, E2) + D/2 (K_s^2 + K_theta^2 + 2 nu K_s K_theta)
                      + S/2 gamma^2 ],          S = kappa G_t h,  kappa = 5/6,

so the resultants are the Fung N1, N2, the bending moments M = D (K + nu K') and the transverse
shear force Q = S gamma [N/m].  For a wavenumber k the bending response D k^4 becomes
D k^4 / (1 + D k^2 / S): a stiffness bounded by S k^2 instead of growing like k^4.  As S -> inf,
gamma -> 0 and the Kirchhoff-Love shell is recovered (one-point integration of gamma leaves the
thin limit free of locking; tests/core/test_mindlin.py).

Forces on the nodes are -dPi/dX (membrane as in ``kernels/membrane.py``; shear through
dPi/dpsi_s = A0_s Q_s and dpsi_s/d(dx, dy) = (dy, -dx) / L^2, ``add_angle_forces``); the moments
on the directors are T_i = -dPi/dbeta_i.  Apex: beta_0 = 0 (symmetry).  Limbus: clamped (beta
fixed at its reference) or pinned (free).  Time integration: velocity Verlet for positions and
directors alike, with the rotary inertia rho h^3 / 12 per reference area (``advance_mindlin``).
"""

import numpy as np
from numba import njit

from .membrane import add_pressure_loads, add_segment_forces, fung_resultants, segment_strains
from .shell import (LIMBUS_CLAMPED, add_angle_forces, bending_energy_density, bending_moments,
                    fung_energy_density, net_inside_pressure, segment_angles)
from .viscoelastic import relax_in_place

SHEAR_CORRECTION = 5.0 / 6.0  # kappa of the first-order shear-deformable shell (Reissner)
MINDLIN_ROWS = 12  # rows of the work space (``mindlin_work``)


def mindlin_work(n):
    """Scratch space for n nodes: rows E1, E2, psi, N1, N2, G, K_s, K_theta, gamma, M_s, M_theta,
    Q per segment (the first n - 1 entries)."""
    return np.zeros((MINDLIN_ROWS, n))


@njit(cache=True)
def mindlin_rows(work, n):
    m = n - 1
    return (work[0, :m], work[1, :m], work[2, :m], work[3, :m], work[4, :m], work[5, :m],
            work[6, :m], work[7, :m], work[8, :m], work[9, :m], work[10, :m], work[11, :m])


@njit(cache=True)
def mindlin_strains(X, Y, beta, L0, S0, psi_ref, beta_ref, x_mid, E1, E2, psi, Ks, Kt, gamma):
    """Membrane E1, E2, segment angles psi, bending K_s, K_theta [1/m] and transverse shear
    gamma [1] of every segment (overwritten); the module docstring has the formulas."""
    n = X.shape[0]
    segment_angles(X, Y, psi)
    for s in range(n - 1):
        E1[s], E2[s] = segment_strains(X, Y, L0, S0, s)
        Ks[s] = ((beta[s + 1] - beta[s]) - (beta_ref[s + 1] - beta_ref[s])) / L0[s]
        mean = 0.5 * (beta[s] + beta[s + 1])
        mean_ref = 0.5 * (beta_ref[s] + beta_ref[s + 1])
        Kt[s] = (np.sin(mean) - np.sin(mean_ref)) / x_mid[s]
        gamma[s] = (psi[s] - psi_ref[s]) - (mean - mean_ref)


@njit(cache=True)
def mindlin_resultants(E1, E2, Ks, Kt, gamma, Ebar, nu, k, D, S, N1, N2, Ms, Mt, Q):
    """Fung N1, N2 [N/m], linear bending M_s, M_theta [N] and shear Q = S gamma [N/m]."""
    for s in range(E1.shape[0]):
        N1[s], N2[s] = fung_resultants(E1[s], E2[s], Ebar, nu, k)
        Q[s] = S * gamma[s]
    bending_moments(Ks, Kt, D, nu, Ms, Mt)


@njit(cache=True)
def add_director_forces(X, Y, beta, L0, A0, x_mid, Ms, Mt, Q, G, Fx, Fy, T):
    """Add the shear's -dPi/dX [N] to Fx, Fy and set the moments T = -dPi/dbeta [N m] of bending
    and shear on the directors.  G (n - 1) is work space for dPi/dpsi_s = A0_s Q_s."""
    n = X.shape[0]
    for i in range(n):
        T[i] = 0.0
    for s in range(n - 1):
        G[s] = A0[s] * Q[s]
        tangent = np.cos(0.5 * (beta[s] + beta[s + 1])) / (2.0 * x_mid[s])
        common = A0[s] * (Mt[s] * tangent - 0.5 * Q[s])
        bend = A0[s] * Ms[s] / L0[s]
        T[s] -= common - bend
        T[s + 1] -= common + bend
    add_angle_forces(X, Y, G, Fx, Fy)


@njit(cache=True)
def mindlin_internal_forces(X, Y, beta, L0, S0, A0, psi_ref, beta_ref, x_mid, Ebar, nu, k, D, S,
                            work, Fx, Fy, T, ve_mode, ve_previous, ve_overstress, ve_decay,
                            ve_weight):
    """Fx, Fy = -dPi/dX [N] and T = -dPi/dbeta [N m] (overwritten); ``work`` from
    ``mindlin_work``.  Viscoelasticity as in ``kernels/shell.shell_internal_forces``, on the five
    resultants N1, N2, M_s, M_theta, Q (rows 0-4 of ve_previous, ve_overstress, per segment)."""
    n = X.shape[0]
    E1, E2, psi, N1, N2, G, Ks, Kt, gamma, Ms, Mt, Q = mindlin_rows(work, n)
    mindlin_strains(X, Y, beta, L0, S0, psi_ref, beta_ref, x_mid, E1, E2, psi, Ks, Kt, gamma)
    mindlin_resultants(E1, E2, Ks, Kt, gamma, Ebar, nu, k, D, S, N1, N2, Ms, Mt, Q)
    if ve_mode != 0:
        step = ve_mode == 2
        m = n - 1
        relax_in_place(N1, ve_previous[0, :m], ve_decay, ve_weight, ve_overstress[:, 0, :m], step)
        relax_in_place(N2, ve_previous[1, :m], ve_decay, ve_weight, ve_overstress[:, 1, :m], step)
        relax_in_place(Ms, ve_previous[2, :m], ve_decay, ve_weight, ve_overstress[:, 2, :m], step)
        relax_in_place(Mt, ve_previous[3, :m], ve_decay, ve_weight, ve_overstress[:, 3, :m], step)
        relax_in_place(Q, ve_previous[4, :m], ve_decay, ve_weight, ve_overstress[:, 4, :m], step)
    for i in range(n):
        Fx[i] = 0.0
        Fy[i] = 0.0
    for s in range(n - 1):
        add_segment_forces(X, Y, L0, S0, A0, s, N1[s], N2[s], Fx, Fy)
    add_director_forces(X, Y, beta, L0, A0, x_mid, Ms, Mt, Q, G, Fx, Fy, T)


@njit(cache=True)
def mindlin_energy(X, Y, beta, L0, S0, A0, psi_ref, beta_ref, x_mid, Ebar, nu, k, D, S, work):
    """(Pi_membrane, Pi_bending, Pi_shear) [J] of the state (module docstring)."""
    n = X.shape[0]
    E1, E2, psi, N1, N2, G, Ks, Kt, gamma, Ms, Mt, Q = mindlin_rows(work, n)
    mindlin_strains(X, Y, beta, L0, S0, psi_ref, beta_ref, x_mid, E1, E2, psi, Ks, Kt, gamma)
    membrane = 0.0
    bending = 0.0
    shear = 0.0
    for s in range(n - 1):
        membrane += A0[s] * fung_energy_density(E1[s], E2[s], Ebar, nu, k)
        bending += A0[s] * bending_energy_density(Ks[s], Kt[s], D, nu)
        shear += A0[s] * 0.5 * S * gamma[s] * gamma[s]
    return membrane, bending, shear


@njit(cache=True)
def _mindlin_total_forces(X, Y, beta, jet_space, L0, S0, A0, psi_ref, beta_ref, x_mid, Ebar, nu, k, D,
                          S, p_start, p_end, frac, t, jet, work, Fx, Fy, T, q, ve_mode,
                          ve_previous, ve_overstress, ve_decay, ve_weight):
    net_inside_pressure(jet_space, p_start, p_end, frac, t, jet, q)
    mindlin_internal_forces(X, Y, beta, L0, S0, A0, psi_ref, beta_ref, x_mid, Ebar, nu, k, D, S,
                            work, Fx, Fy, T, ve_mode, ve_previous, ve_overstress, ve_decay,
                            ve_weight)
    add_pressure_loads(X, Y, q, Fx, Fy)


@njit(cache=True)
def advance_mindlin(X, Y, VX, VY, beta, omega, mass, inertia, jet_space, L0, S0, A0, psi_ref, beta_ref,
                    x_mid, limbus, Ebar, nu, k, D, S, p_start, p_end, t_start, dt, n_sub, jet,
                    work, Fx, Fy, T, q, viscoelastic, ve_previous, ve_overstress, ve_decay,
                    ve_weight):
    """Velocity-Verlet sub-steps of positions (X, Y, VX, VY) and directors (beta [rad], omega
    [rad/s]) from t_start to t_start + dt [s], in place; loads (the fluid pressure and the air
    pulse ``jet`` with its space factor ``jet_space``, ``kernels/air_jet.py``) and
    viscoelasticity as in ``kernels/shell.advance_shell``.  ``inertia``: rotary inertia rho h^3 / 12 A_i [kg m^2] of
    each node.  Apex: x = 0, beta = 0; limbus: fixed position, beta fixed when clamped."""
    n = X.shape[0]
    h = dt / n_sub
    last_free = n - 1 if limbus == LIMBUS_CLAMPED else n  # directors 1 .. last_free - 1 move
    ve_start = 1 if viscoelastic else 0
    ve_step = 2 if viscoelastic else 0
    _mindlin_total_forces(X, Y, beta, jet_space, L0, S0, A0, psi_ref, beta_ref, x_mid, Ebar, nu, k,
                          D, S, p_start, p_end, 0.0, t_start, jet, work, Fx, Fy, T, q, ve_start,
                          ve_previous, ve_overstress, ve_decay, ve_weight)
    for m in range(n_sub):
        for i in range(n - 1):
            VX[i] += 0.5 * h * Fx[i] / mass[i]
            VY[i] += 0.5 * h * Fy[i] / mass[i]
        VX[0] = 0.0
        for i in range(1, last_free):
            omega[i] += 0.5 * h * T[i] / inertia[i]
        for i in range(n - 1):
            X[i] += h * VX[i]
            Y[i] += h * VY[i]
        for i in range(1, last_free):
            beta[i] += h * omega[i]
        frac = (m + 1.0) / n_sub
        _mindlin_total_forces(X, Y, beta, jet_space, L0, S0, A0, psi_ref, beta_ref, x_mid, Ebar, nu, k,
                              D, S, p_start, p_end, frac, t_start + (m + 1) * h, jet, work, Fx,
                              Fy, T, q, ve_step, ve_previous, ve_overstress, ve_decay, ve_weight)
        for i in range(n - 1):
            VX[i] += 0.5 * h * Fx[i] / mass[i]
            VY[i] += 0.5 * h * Fy[i] / mass[i]
        VX[0] = 0.0
        X[0] = 0.0
        for i in range(1, last_free):
            omega[i] += 0.5 * h * T[i] / inertia[i]


@njit(cache=True)
def balance_directors(X, Y, beta, L0, S0, A0, psi_ref, beta_ref, x_mid, Ebar, nu, k, D, S, limbus,
                      work, Fx, Fy, T, ve_previous, ve_overstress, ve_decay, ve_weight, tol,
                      max_iter):
    """Directors beta [rad] (in place, from the given start) at which the moments T vanish for
    the positions (X, Y): Newton's method with the exact tridiagonal Hessian of the bending and
    shear energy, per segment

        d^2 Pi_s / d(beta_a, beta_b)^2 = A0 [D (gK gK + gT gT + nu (gK gT + gT gK))
                                         + M_theta d^2 K_theta + S gG gG],
        gK = (-1, 1) / L0,  gT = (c, c),  c = cos(betabar) / (2 x_mid),  gG = (-1/2, -1/2),

    solved by the Thomas algorithm on the free directors (1 .. n - 2, and n - 1 when pinned), until
    a correction is below ``tol`` [rad].  Returns the iterations used."""
    n = X.shape[0]
    last_free = n - 1 if limbus == LIMBUS_CLAMPED else n
    diag = np.zeros(n)
    off = np.zeros(n)  # off[i] couples i and i + 1
    rhs = np.zeros(n)
    it = 0
    while it < max_iter:
        it += 1
        mindlin_internal_forces(X, Y, beta, L0, S0, A0, psi_ref, beta_ref, x_mid, Ebar, nu, k, D,
                                S, work, Fx, Fy, T, 0, ve_previous, ve_overstress, ve_decay,
                                ve_weight)
        Mt = work[10]
        for i in range(n):
            diag[i] = 0.0
            off[i] = 0.0
        for s in range(n - 1):
            mean = 0.5 * (beta[s] + beta[s + 1])
            c = np.cos(mean) / (2.0 * x_mid[s])
            common = Mt[s] * (-np.sin(mean) / (4.0 * x_mid[s])) + 0.25 * S
            gK = 1.0 / L0[s]
            diag[s] += A0[s] * (D * (gK * gK + c * c - 2.0 * nu * gK * c) + common)
            diag[s + 1] += A0[s] * (D * (gK * gK + c * c + 2.0 * nu * gK * c) + common)
            off[s] = A0[s] * (D * (c * c - gK * gK) + common)
        # Thomas algorithm on rows 1 .. last_free - 1 (the others are fixed)
        for i in range(1, last_free):
            rhs[i] = T[i]
        for i in range(2, last_free):
            w = off[i - 1] / diag[i - 1]
            diag[i] -= w * off[i - 1]
            rhs[i] -= w * rhs[i - 1]
        largest = 0.0
        delta = 0.0
        for i in range(last_free - 1, 0, -1):
            upper = off[i] * delta if i + 1 < last_free else 0.0
            delta = (rhs[i] - upper) / diag[i]
            beta[i] += delta
            largest = max(largest, abs(delta))
        if largest < tol:
            break
    return it


@njit(cache=True)
def max_director_frequency(L0, A0, x_mid, mass, inertia, limbus, D, nu, S):
    """Upper estimate [rad/s] of the highest frequency that bending and transverse shear add:
    Gershgorin's bound on the linearised stiffness of the directors (bending and shear, per unit
    rotary inertia) and on the shear stiffness of the positions (per unit mass), added in squares.
    Per segment the director rows sum to at most A0 (D (2/L0^2 + 1/(2 x^2) + 2 |nu| / (x L0))
    + S / 2), the position rows to 2 A0 S / L0^2 per coordinate."""
    n = mass.shape[0]
    rot = np.zeros(n)
    pos = np.zeros(n)
    for s in range(n - 1):
        x = x_mid[s]
        L = L0[s]
        r = A0[s] * (D * (2.0 / (L * L) + 0.5 / (x * x) + 2.0 * abs(nu) / (x * L)) + 0.5 * S)
        rot[s] += r
        rot[s + 1] += r
        p = 2.0 * A0[s] * S / (L * L)
        pos[s] += p
        pos[s + 1] += p
    last_free = n - 1 if limbus == LIMBUS_CLAMPED else n
    omega_rot2 = 0.0
    for i in range(1, last_free):
        omega_rot2 = max(omega_rot2, rot[i] / inertia[i])
    omega_pos2 = 0.0
    for i in range(n - 1):
        omega_pos2 = max(omega_pos2, pos[i] / mass[i])
    return np.sqrt(omega_rot2 + omega_pos2)
