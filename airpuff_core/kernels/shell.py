"""Axisymmetric Kirchhoff-Love shell with large rotations in discrete-energy form (SI).

The membrane of ``kernels/membrane.py`` plus a bending energy at the nodes:

    Pi = sum_s A0_s W_membrane(E1_s, E2_s)  +  sum_i A_i W_bending(K_s,i, K_theta,i)

psi_s is the angle of segment s (psi = atan2(-dy, dx): 0 at the apex, phi on a sphere), measured
from the reference psi_ref_s.  Reissner's bending strains, per reference length, at node i:

    K_s     = (psi_i - psi_{i-1} - (psi_ref_i - psi_ref_{i-1})) / l_i,  l_i = (L0_{i-1} + L0_i)/2
    K_theta = (sin psibar_i - sin psibar_ref_i) / x_ref_i,          psibar_i = (psi_{i-1} + psi_i)/2

Apex (symmetry, psi = 0 on the axis): the mirror segment has angle -psi_0, so
K_s = K_theta = 2 (psi_0 - psi_ref_0) / L0_0.  Limbus: clamped (the tangent keeps its reference
angle: K_s = -(psi_{n-2} - psi_ref_{n-2}) / (L0_{n-2} / 2), K_theta = 0), or pinned (no moment, the
node carries no bending energy).  A homothetic deformation keeps every angle, so it has no bending
strain: the drawn arc and the stress-free reference differ only by the membrane prestretch.

Linear bending law (``bending_moments``): W_bending = D/2 (K_s^2 + K_theta^2 + 2 nu K_s K_theta),
M_s = D (K_s + nu K_theta), M_theta = D (K_theta + nu K_s), D = E0 h^3 / (12 (1 - nu^2)).

Forces are -dPi/dX, exact: with G_s = dPi_b/dpsi_s (a sum of A_i M dK/dpsi over the nodes that
see segment s) and dpsi_s/d(dx, dy) = (dy, -dx) / L^2.  The kernel computes all strains first,
then all resultants (N from the Fung law, M from the bending law, ``shell_resultants``), then the
forces from the resultants, so a history of N and M (viscoelasticity) can act between the two.
"""

import numpy as np
from numba import njit

from .air_jet import pulse_time_factor
from .membrane import add_pressure_loads, add_segment_forces, fung_resultants, segment_strains
from .viscoelastic import relax_in_place

LIMBUS_PINNED = 0
LIMBUS_CLAMPED = 1


@njit(cache=True)
def segment_angles(X, Y, psi):
    """psi_s = atan2(-(y_{s+1} - y_s), x_{s+1} - x_s) [rad] of every segment (overwritten)."""
    for s in range(X.shape[0] - 1):
        psi[s] = np.arctan2(Y[s] - Y[s + 1], X[s + 1] - X[s])


@njit(cache=True)
def bending_strains(psi, psi_ref, dual_length, x_ref, limbus, Ks, Kt):
    """Reissner bending strains K_s, K_theta [1/m] at the nodes (overwritten); see the module
    docstring for the apex and limbus rows."""
    n = psi.shape[0] + 1
    Ks[0] = 2.0 * (psi[0] - psi_ref[0]) / dual_length[0]
    Kt[0] = Ks[0]
    for i in range(1, n - 1):
        Ks[i] = ((psi[i] - psi[i - 1]) - (psi_ref[i] - psi_ref[i - 1])) / dual_length[i]
        Kt[i] = (np.sin(0.5 * (psi[i - 1] + psi[i]))
                 - np.sin(0.5 * (psi_ref[i - 1] + psi_ref[i]))) / x_ref[i]
    if limbus == LIMBUS_CLAMPED:
        Ks[n - 1] = -(psi[n - 2] - psi_ref[n - 2]) / dual_length[n - 1]
    else:
        Ks[n - 1] = 0.0
    Kt[n - 1] = 0.0


@njit(cache=True)
def bending_moments(Ks, Kt, D, nu, Ms, Mt):
    """Linear bending law: M_s = D (K_s + nu K_theta), M_theta = D (K_theta + nu K_s) [N]
    (per reference length), the derivatives of W = D/2 (K_s^2 + K_theta^2 + 2 nu K_s K_theta)."""
    for i in range(Ks.shape[0]):
        Ms[i] = D * (Ks[i] + nu * Kt[i])
        Mt[i] = D * (Kt[i] + nu * Ks[i])


@njit(cache=True)
def bending_energy_density(Ks, Kt, D, nu):
    """W_bending = D/2 (K_s^2 + K_theta^2 + 2 nu K_s K_theta) [J/m^2]."""
    return 0.5 * D * (Ks * Ks + Kt * Kt + 2.0 * nu * Ks * Kt)


@njit(cache=True)
def shell_strains(X, Y, L0, S0, psi_ref, dual_length, x_ref, limbus, D, E1, E2, psi, Ks, Kt):
    """All strains of the current state: membrane E1, E2 per segment, and, when D != 0, the
    segment angles psi [rad] and the bending strains K_s, K_theta [1/m] per node (overwritten)."""
    for s in range(X.shape[0] - 1):
        E1[s], E2[s] = segment_strains(X, Y, L0, S0, s)
    if D != 0.0:
        segment_angles(X, Y, psi)
        bending_strains(psi, psi_ref, dual_length, x_ref, limbus, Ks, Kt)


@njit(cache=True)
def shell_resultants(E1, E2, Ks, Kt, Ebar, nu, k, D, N1, N2, Ms, Mt):
    """The constitutive laws in one place: Fung membrane forces N1, N2 [N/m] per segment (second
    Piola-Kirchhoff) and, when D != 0, the linear bending moments M_s, M_theta [N] per node."""
    for s in range(E1.shape[0]):
        N1[s], N2[s] = fung_resultants(E1[s], E2[s], Ebar, nu, k)
    if D != 0.0:
        bending_moments(Ks, Kt, D, nu, Ms, Mt)


@njit(cache=True)
def add_bending_forces(X, Y, psi, psi_ref, dual_length, x_ref, node_area, limbus, Ms, Mt, G,
                       Fx, Fy):
    """Add -dPi_b/dX [N] for nodal moments Ms, Mt to Fx, Fy.  G (n - 1) is work space: it
    receives G_s = dPi_b/dpsi_s = sum_i A_i (M_s dK_s/dpsi_s + M_theta dK_theta/dpsi_s)."""
    n = X.shape[0]
    for s in range(n - 1):
        G[s] = 0.0
    G[0] += node_area[0] * (Ms[0] + Mt[0]) * 2.0 / dual_length[0]
    for i in range(1, n - 1):
        gs = node_area[i] * Ms[i] / dual_length[i]
        G[i] += gs
        G[i - 1] -= gs
        gt = 0.5 * node_area[i] * Mt[i] * np.cos(0.5 * (psi[i - 1] + psi[i])) / x_ref[i]
        G[i] += gt
        G[i - 1] += gt
    if limbus == LIMBUS_CLAMPED:
        G[n - 2] -= node_area[n - 1] * Ms[n - 1] / dual_length[n - 1]
    add_angle_forces(X, Y, G, Fx, Fy)


@njit(cache=True)
def add_angle_forces(X, Y, G, Fx, Fy):
    """Add -dPi/dX [N] to Fx, Fy for G_s = dPi/dpsi_s given per segment, through
    dpsi_s/d(dx, dy) = (dy, -dx) / L^2 (psi_s = atan2(-dy, dx))."""
    for s in range(X.shape[0] - 1):
        dx = X[s + 1] - X[s]
        dy = Y[s + 1] - Y[s]
        g = G[s] / (dx * dx + dy * dy)
        Fx[s] += g * dy
        Fy[s] -= g * dx
        Fx[s + 1] -= g * dy
        Fy[s + 1] += g * dx


def shell_work(n):
    """Scratch space of the shell kernels for n nodes: rows E1, E2, psi, N1, N2, G (per segment,
    the first n - 1 entries) and K_s, K_theta, M_s, M_theta (per node)."""
    return np.zeros((10, n))


@njit(cache=True)
def work_rows(work, n):
    return (work[0, :n - 1], work[1, :n - 1], work[2, :n - 1], work[3, :n - 1], work[4, :n - 1],
            work[5, :n - 1], work[6], work[7], work[8], work[9])


@njit(cache=True)
def shell_internal_forces(X, Y, L0, S0, A0, psi_ref, dual_length, x_ref, node_area, limbus,
                          Ebar, nu, k, D, work, Fx, Fy, ve_mode, ve_previous, ve_overstress,
                          ve_decay, ve_weight):
    """Fx, Fy = -dPi/dX [N] of membrane plus bending (overwritten).  ``work`` is (10, n) scratch
    (``shell_work``).  With D = 0 the bending part is skipped and the forces are the membrane's,
    bit for bit.

    Viscoelasticity (``kernels/viscoelastic.py``) acts between the resultants and the forces:
    ve_mode 0 = none (the elastic law; the ve_ arrays are not read), 1 = the stored overstresses
    are added, 2 = one Simo step with the factors ve_decay, ve_weight.  ve_previous (4, n) holds
    the equilibrium N1, N2 (per segment) and M_s, M_theta (per node) of the last evaluation,
    ve_overstress (terms, 4, n) the overstresses; both are updated in mode 2.  With
    viscoelasticity the forces are those of the total resultants, no longer -dPi/dX."""
    n = X.shape[0]
    E1, E2, psi, N1, N2, G, Ks, Kt, Ms, Mt = work_rows(work, n)
    shell_strains(X, Y, L0, S0, psi_ref, dual_length, x_ref, limbus, D, E1, E2, psi, Ks, Kt)
    shell_resultants(E1, E2, Ks, Kt, Ebar, nu, k, D, N1, N2, Ms, Mt)
    if ve_mode != 0:
        step = ve_mode == 2
        relax_in_place(N1, ve_previous[0, :n - 1], ve_decay, ve_weight,
                       ve_overstress[:, 0, :n - 1], step)
        relax_in_place(N2, ve_previous[1, :n - 1], ve_decay, ve_weight,
                       ve_overstress[:, 1, :n - 1], step)
        if D != 0.0:
            relax_in_place(Ms, ve_previous[2], ve_decay, ve_weight, ve_overstress[:, 2], step)
            relax_in_place(Mt, ve_previous[3], ve_decay, ve_weight, ve_overstress[:, 3], step)
    for i in range(n):
        Fx[i] = 0.0
        Fy[i] = 0.0
    for s in range(n - 1):
        add_segment_forces(X, Y, L0, S0, A0, s, N1[s], N2[s], Fx, Fy)
    if D != 0.0:
        add_bending_forces(X, Y, psi, psi_ref, dual_length, x_ref, node_area, limbus, Ms, Mt, G,
                           Fx, Fy)


@njit(cache=True)
def fung_energy_density(E1, E2, Ebar, nu, k):
    """W_membrane = C/2 (exp(Q) - 1), C k = Ebar, Q = k (E1^2 + E2^2 + 2 nu E1 E2) [J/m^2];
    Saint Venant-Kirchhoff, Ebar/2 (E1^2 + E2^2 + 2 nu E1 E2), when k = 0."""
    quad = E1 * E1 + E2 * E2 + 2.0 * nu * E1 * E2
    if k == 0.0:
        return 0.5 * Ebar * quad
    return 0.5 * Ebar / k * np.expm1(k * quad)


@njit(cache=True)
def shell_energy(X, Y, L0, S0, A0, psi_ref, dual_length, x_ref, node_area, limbus, Ebar, nu, k,
                 D, work):
    """Elastic energy (Pi_membrane, Pi_bending) [J] of the current state:
    sum_s A0_s W_membrane and sum_i A_i W_bending (``work`` as in ``shell_internal_forces``)."""
    n = X.shape[0]
    E1, E2, psi, N1, N2, G, Ks, Kt, Ms, Mt = work_rows(work, n)
    shell_strains(X, Y, L0, S0, psi_ref, dual_length, x_ref, limbus, 1.0, E1, E2, psi, Ks, Kt)
    membrane = 0.0
    for s in range(n - 1):
        membrane += A0[s] * fung_energy_density(E1[s], E2[s], Ebar, nu, k)
    bending = 0.0
    for i in range(n):
        bending += node_area[i] * bending_energy_density(Ks[i], Kt[i], D, nu)
    return membrane, bending


@njit(cache=True)
def net_inside_pressure(jet_space, p_start, p_end, frac, t, jet, q):
    """q = p_start + frac (p_end - p_start) - p_jet [Pa] on the cornea nodes: the fluid
    pressure interpolated within the step (frac in [0, 1]) less the air pulse, its space factor
    ``jet_space`` on the nodes times its time factor at t (``kernels/air_jet.py``)."""
    time_factor = pulse_time_factor(t, jet)
    for i in range(jet_space.shape[0]):
        q[i] = p_start[i] + frac * (p_end[i] - p_start[i]) - jet_space[i] * time_factor


@njit(cache=True)
def _shell_total_forces(X, Y, jet_space, L0, S0, A0, psi_ref, dual_length, x_ref, node_area, limbus,
                        Ebar, nu, k, D, p_start, p_end, frac, t, jet, work, Fx, Fy, q,
                        ve_mode, ve_previous, ve_overstress, ve_decay, ve_weight):
    net_inside_pressure(jet_space, p_start, p_end, frac, t, jet, q)
    shell_internal_forces(X, Y, L0, S0, A0, psi_ref, dual_length, x_ref, node_area, limbus, Ebar,
                          nu, k, D, work, Fx, Fy, ve_mode, ve_previous, ve_overstress, ve_decay,
                          ve_weight)
    add_pressure_loads(X, Y, q, Fx, Fy)


@njit(cache=True)
def advance_shell(X, Y, VX, VY, mass, jet_space, L0, S0, A0, psi_ref, dual_length, x_ref, node_area,
                  limbus, Ebar, nu, k, D, p_start, p_end, t_start, dt, n_sub, jet, work, Fx, Fy,
                  q, viscoelastic, ve_previous, ve_overstress, ve_decay, ve_weight):
    """Velocity-Verlet sub-steps of the shell from t_start to t_start + dt (in place).

    The fluid pressure on the cornea is interpolated linearly from p_start (at t_start) to p_end;
    the air pulse (``kernels/air_jet.py``: ``jet``, its space factor ``jet_space`` on the nodes) is
    evaluated at each sub-step.  Apex: x = 0 (the rotation
    psi = 0 there is built into the bending strains).  Limbus: fixed position (eq. 10); its
    rotation is fixed or free through the bending strains (``limbus``).

    ``viscoelastic``: the resultants relax (``shell_internal_forces``), one Simo step per
    sub-step with ve_decay, ve_weight made for the sub-step dt / n_sub; the history arrays are
    updated in place.
    """
    n = X.shape[0]
    h = dt / n_sub
    ve_start = 1 if viscoelastic else 0  # the state at t_start: its overstresses as stored
    ve_step = 2 if viscoelastic else 0
    _shell_total_forces(X, Y, jet_space, L0, S0, A0, psi_ref, dual_length, x_ref, node_area, limbus,
                        Ebar, nu, k, D, p_start, p_end, 0.0, t_start, jet, work, Fx, Fy, q,
                        ve_start, ve_previous, ve_overstress, ve_decay, ve_weight)
    for m in range(n_sub):
        for i in range(n - 1):
            VX[i] += 0.5 * h * Fx[i] / mass[i]
            VY[i] += 0.5 * h * Fy[i] / mass[i]
        VX[0] = 0.0
        for i in range(n - 1):
            X[i] += h * VX[i]
            Y[i] += h * VY[i]
        frac = (m + 1.0) / n_sub
        _shell_total_forces(X, Y, jet_space, L0, S0, A0, psi_ref, dual_length, x_ref, node_area,
                            limbus, Ebar, nu, k, D, p_start, p_end, frac, t_start + (m + 1) * h,
                            jet, work, Fx, Fy, q, ve_step, ve_previous, ve_overstress, ve_decay,
                            ve_weight)
        for i in range(n - 1):
            VX[i] += 0.5 * h * Fx[i] / mass[i]
            VY[i] += 0.5 * h * Fy[i] / mass[i]
        VX[0] = 0.0
        X[0] = 0.0


# The highest bending mode of the discrete shell sits at the apex, whose cell is light (a disc of
# radius L0_0 / 2): measured 1.20-1.21 times the interior Nyquist mode 4 / l^2 sqrt(D / (rho h)),
# for 26-200 nodes and nu = 0-0.9 (tests/core/test_shell.py checks the bound on the eigenvalues).
APEX_MODE_FACTOR = 1.25


@njit(cache=True)
def max_bending_frequency(dual_length, D, rho_h):
    """Upper estimate of the highest bending frequency [rad/s] of the discrete shell:
    APEX_MODE_FACTOR times the grid-scale bending wave omega = k^2 sqrt(D / (rho h)) with
    k = 2 / l_min (the Nyquist mode of the fourth difference, 16 / l^4), l_min the shortest dual
    length of an interior node."""
    lmin = dual_length[1]
    for i in range(1, dual_length.shape[0] - 1):
        lmin = min(lmin, dual_length[i])
    return APEX_MODE_FACTOR * 4.0 / (lmin * lmin) * np.sqrt(D / rho_h)
