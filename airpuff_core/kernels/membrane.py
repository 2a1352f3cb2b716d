"""Axisymmetric Fung membrane in discrete-energy form, lumped pressure loads (SI).

Nodes k = 0..N-1 at reference angles phi_k = k dphi on the stress-free arc of radius R_ref;
node 0 is the apex (on the axis), node N-1 the limbus (fixed).  Segment s joins nodes s and s+1:

    lambda1 = |X_{s+1} - X_s| / L0_s,            L0_s = 2 R_ref sin(dphi/2)  (reference chord)
    lambda2 = (x_s + x_{s+1}) / S0_s,            S0_s = R_ref (sin phi_s + sin phi_{s+1})
    E_i = (lambda_i^2 - 1) / 2
    W = C/2 [exp(Q) - 1],  Q = k (E1^2 + E2^2 + 2 nu E1 E2),  C k = E0 h / (1 - nu^2) = Ebar
    N1 = dW/dE1 = Ebar e^Q (E1 + nu E2),  N2 = Ebar e^Q (E2 + nu E1)
    Pi = sum_s A0_s W(E1, E2),          A0_s = 2 pi R_ref^2 (cos phi_s - cos phi_{s+1})

A uniformly scaled arc has lambda1 = lambda2 exactly in every segment.  The internal nodal force
is -dPi/dX.  The net pressure q = p_fluid - p_air acts on the tributary area of each node (half of
each adjacent segment, as a surface of revolution) along the segment normal: these lumped loads
balance the apex to second order (2 N kappa = q), which consistent linear-element loads do not.
With k = 0 the law is exactly the Saint Venant-Kirchhoff membrane.  The time integration (Verlet
sub-steps) is ``kernels/shell.py``'s, for the membrane (bending rigidity 0) and the shell alike.
"""

import math

import numpy as np
from numba import njit

from .sums import numpy_sum, pairwise_sum


@njit(cache=True)
def fung_resultants(E1, E2, Ebar, nu, k):
    """Second Piola-Kirchhoff membrane forces (N1, N2) [N/m] of the simplified Fung law."""
    eQ = np.exp(k * (E1 * E1 + E2 * E2 + 2.0 * nu * E1 * E2))
    return Ebar * eQ * (E1 + nu * E2), Ebar * eQ * (E2 + nu * E1)


@njit(cache=True)
def segment_strains(X, Y, L0, S0, s):
    """Green-Lagrange strains (E1 meridional, E2 hoop) of segment s:
    E1 = (|X_{s+1} - X_s|^2 / L0_s^2 - 1) / 2,  E2 = (((x_s + x_{s+1}) / S0_s)^2 - 1) / 2."""
    dx = X[s + 1] - X[s]
    dy = Y[s + 1] - Y[s]
    E1 = 0.5 * ((dx * dx + dy * dy) / (L0[s] * L0[s]) - 1.0)
    lam2 = (X[s] + X[s + 1]) / S0[s]
    return E1, 0.5 * (lam2 * lam2 - 1.0)


@njit(cache=True)
def add_segment_forces(X, Y, L0, S0, A0, s, N1, N2, Fx, Fy):
    """Add -d(A0_s W_s)/dX [N] of segment s carrying the resultants N1, N2 [N/m] to Fx, Fy:
    dW = N1 dE1 + N2 dE2 with dE1/dX = (X_{s+1} - X_s) . d/L0^2 and dE2/dx = lambda2 / S0."""
    dx = X[s + 1] - X[s]
    dy = Y[s + 1] - Y[s]
    lam2 = (X[s] + X[s + 1]) / S0[s]
    g1 = A0[s] * N1 / (L0[s] * L0[s])
    Fx[s] += g1 * dx
    Fy[s] += g1 * dy
    Fx[s + 1] -= g1 * dx
    Fy[s + 1] -= g1 * dy
    g2 = A0[s] * N2 * lam2 / S0[s]
    Fx[s] -= g2
    Fx[s + 1] -= g2


@njit(cache=True)
def internal_forces(X, Y, L0, S0, A0, Ebar, nu, k, Fx, Fy):
    """Fx, Fy = -dPi/dX [N] (overwritten)."""
    n = X.shape[0]
    for i in range(n):
        Fx[i] = 0.0
        Fy[i] = 0.0
    for s in range(n - 1):
        E1, E2 = segment_strains(X, Y, L0, S0, s)
        N1, N2 = fung_resultants(E1, E2, Ebar, nu, k)
        add_segment_forces(X, Y, L0, S0, A0, s, N1, N2, Fx, Fy)


@njit(cache=True)
def add_pressure_loads(X, Y, q, Fx, Fy):
    """Add the lumped loads of the net inside pressure q [Pa] to Fx, Fy [N].

    Half-segment from node s to the mid-point m: area 2 pi (x_s + x_m)/2 * L/2, outward normal
    n = (-dy, dx)/L for a segment running from the apex towards the limbus.
    """
    n = X.shape[0]
    for s in range(n - 1):
        dx = X[s + 1] - X[s]
        dy = Y[s + 1] - Y[s]
        xm = 0.5 * (X[s] + X[s + 1])
        # area * normal = 2 pi (x_a + x_m)/2 * (L/2) * (-dy, dx)/L
        wa = 0.5 * np.pi * (X[s] + xm)
        wb = 0.5 * np.pi * (xm + X[s + 1])
        Fx[s] += q[s] * wa * (-dy)
        Fy[s] += q[s] * wa * dx
        Fx[s + 1] += q[s + 1] * wb * (-dy)
        Fy[s + 1] += q[s + 1] * wb * dx


@njit(cache=True)
def region_pressure_loads(X, Y, q_fluid, q_jet, n_region):
    """The y components [N] of the lumped loads (``add_pressure_loads``) summed over the nodes
    i < n_region: (a, F_fluid, F_jet) of a unit net inside pressure (a = sum a_p,i, the lumped
    area), of q_fluid and of q_jet [Pa].  Each sum is numpy's ``np.sum`` of the loads, formed in
    its order (``sums.pairwise_sum``), so the apex budget keeps its bits."""
    n = X.shape[0]
    Fx, Fy = np.zeros(n), np.zeros(n)
    add_pressure_loads(X, Y, np.ones(n), Fx, Fy)
    area = pairwise_sum(Fy, 0, n_region)
    Fx[:] = 0.0
    Fy[:] = 0.0
    add_pressure_loads(X, Y, q_fluid, Fx, Fy)
    fluid = pairwise_sum(Fy, 0, n_region)
    Fx[:] = 0.0
    Fy[:] = 0.0
    add_pressure_loads(X, Y, q_jet, Fx, Fy)
    jet = pairwise_sum(Fy, 0, n_region)
    return area, fluid, jet


@njit(cache=True)
def max_wave_speed(X, Y, L0, S0, Ebar, nu, k, rho_h):
    """Largest in-plane wave speed [m/s] from the tangent stiffness of the current state:
    c^2 = (N + lambda^2 dN/dE) / (rho_c h), maximised over segments and both directions."""
    n = X.shape[0]
    cmax2 = 0.0
    for s in range(n - 1):
        dx = X[s + 1] - X[s]
        dy = Y[s + 1] - Y[s]
        lam1sq = (dx * dx + dy * dy) / (L0[s] * L0[s])
        lam2 = (X[s] + X[s + 1]) / S0[s]
        E1 = 0.5 * (lam1sq - 1.0)
        E2 = 0.5 * (lam2 * lam2 - 1.0)
        eQ = np.exp(k * (E1 * E1 + E2 * E2 + 2.0 * nu * E1 * E2))
        N1 = Ebar * eQ * (E1 + nu * E2)
        N2 = Ebar * eQ * (E2 + nu * E1)
        dN1 = Ebar * eQ * (1.0 + 2.0 * k * (E1 + nu * E2) ** 2)
        dN2 = Ebar * eQ * (1.0 + 2.0 * k * (E2 + nu * E1) ** 2)
        c1 = (abs(N1) + lam1sq * dN1) / rho_h
        c2 = (abs(N2) + lam2 * lam2 * dN2) / rho_h
        cmax2 = max(cmax2, c1, c2)
    return np.sqrt(cmax2)


@njit(cache=True)
def even_fit_curvature(X, Y, n_fit):
    """Curvature kappa = -2 c2 [1/m] of the least-squares fit y = c0 + c2 x^2 + c4 x^4 through the
    first ``n_fit`` nodes (n_fit >= 3; with three nodes the interpolating even quartic), or of
    y = c0 + c2 x^2 through two.

    The normal equations are formed in xi = x / x_max, where the basis 1, xi^2, xi^4 is well
    conditioned on [0, 1], and solved by Gaussian elimination with partial pivoting.
    """
    m = 3 if n_fit >= 3 else 2
    x_max = 0.0
    for k in range(n_fit):
        x_max = max(x_max, abs(X[k]))
    G = np.zeros((m, m + 1))  # augmented normal equations [G^T G | G^T y]
    basis = np.empty(m)
    for k in range(n_fit):
        xi2 = (X[k] / x_max) ** 2
        basis[0] = 1.0
        basis[1] = xi2
        if m == 3:
            basis[2] = xi2 * xi2
        for a in range(m):
            for b in range(m):
                G[a, b] += basis[a] * basis[b]
            G[a, m] += basis[a] * Y[k]
    for col in range(m):
        piv = col
        for r in range(col + 1, m):
            if abs(G[r, col]) > abs(G[piv, col]):
                piv = r
        for c in range(m + 1):
            G[col, c], G[piv, c] = G[piv, c], G[col, c]
        for r in range(col + 1, m):
            f = G[r, col] / G[col, col]
            for c in range(col, m + 1):
                G[r, c] -= f * G[col, c]
    coef = np.empty(m)
    for r in range(m - 1, -1, -1):
        s = G[r, m]
        for c in range(r + 1, m):
            s -= G[r, c] * coef[c]
        coef[r] = s / G[r, r]
    return -2.0 * coef[1] / (x_max * x_max)


@njit(cache=True)
def cornea_polygon_volume(xc, yc, y_axis):
    """Volume [m^3] swept about the axis by the meridian polygon (0, y_axis) - cornea polyline
    (xc, yc) - (0, y_axis): the sum of cone frusta (Pappus),
    |pi/3 sum (x_a^2 + x_a x_b + x_b^2)(y_a - y_b)| over its edges."""
    n = xc.shape[0]
    v = 0.0
    xa = 0.0
    ya = y_axis
    for k in range(n + 1):
        xb = xc[k] if k < n else 0.0
        yb = yc[k] if k < n else y_axis
        v += (xa * xa + xa * xb + xb * xb) * (ya - yb)
        xa = xb
        ya = yb
    return abs(np.pi / 3.0 * v)


@njit(cache=True)
def enclosed_volume_rate(xc, yc, vxc, vyc, y_axis):
    """d/dt [m^3/s] of the volume swept about the axis by the meridian polygon (0, y_axis) -
    cornea polyline (xc, yc) - (0, y_axis), whose volume |S| is ``cornea_polygon_volume``'s:
    S = pi/3 sum (x_a^2 + x_a x_b + x_b^2)(y_a - y_b) over its edges a -> b, differentiated
    exactly for the node velocities (vxc, vyc) [m/s] (the closing points do not move):

        dS/dt = pi/3 sum ((2 x_a + x_b) u_a + (x_a + 2 x_b) u_b)(y_a - y_b)
                         + (x_a^2 + x_a x_b + x_b^2)(w_a - w_b).

    Each sum is numpy's of its terms (``sums.numpy_sum``)."""
    n = xc.shape[0]
    volume_terms = np.empty(n + 1)
    rate_terms = np.empty(n + 1)
    xa, ya, ua, wa = 0.0, y_axis, 0.0, 0.0
    for k in range(n + 1):
        if k < n:
            xb, yb, ub, wb = xc[k], yc[k], vxc[k], vyc[k]
        else:
            xb, yb, ub, wb = 0.0, y_axis, 0.0, 0.0
        square = xa * xa + xa * xb + xb * xb
        volume_terms[k] = square * (ya - yb)
        rate_terms[k] = (((2.0 * xa + xb) * ua + (xa + 2.0 * xb) * ub) * (ya - yb)
                         + square * (wa - wb))
        xa, ya, ua, wa = xb, yb, ub, wb
    return math.copysign(1.0, numpy_sum(volume_terms)) * np.pi / 3.0 * numpy_sum(rate_terms)
