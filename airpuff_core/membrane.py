"""The cornea: reference configuration, IOP prestress and the discrete static equilibrium.

The drawn arc (radius R) is the loaded state at IOP p0.  For a spherical membrane under uniform
pressure the equibiaxial tension is p0 R / 2 (Laplace); for an equibiaxial membrane the Cauchy
tension equals the second Piola-Kirchhoff force N, so the prestretch lambda0 solves

    N(lambda0, lambda0) = Ebar exp(Q) (1 + nu) E = p0 R / 2,   E = (lambda0^2 - 1)/2,
    Q = 2 k (1 + nu) E^2,

and the stress-free reference is the concentric arc of radius R_ref = R / lambda0.  The discrete
membrane is in equilibrium with these loads to second order; the exact discrete equilibrium
(found by Newton's method at start-up) differs from the drawn arc by O(dphi^2), and is reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .kernels.membrane import add_pressure_loads, fung_resultants, internal_forces


def equibiaxial_tension(lam, Ebar, nu, k):
    """N(lambda, lambda) [N/m] of the simplified Fung law."""
    E = 0.5 * (lam * lam - 1.0)
    return fung_resultants(E, E, Ebar, nu, k)[0]


def prestretch(p0, R, Ebar, nu, k):
    """lambda0 with N(lambda0, lambda0) = p0 R / 2 (bisection; N is increasing in lambda)."""
    target = 0.5 * p0 * R
    lo, hi = 1.0, 1.0
    while equibiaxial_tension(hi, Ebar, nu, k) < target:
        hi = 1.0 + 2.0 * (hi - 1.0) + 1e-3
        if hi > 10.0:
            raise ValueError("no prestretch below 10 balances the IOP: the cornea is too soft")
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if equibiaxial_tension(mid, Ebar, nu, k) < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclass
class MembraneModel:
    """Discrete membrane: reference geometry, lumped masses and material constants (SI)."""

    phi: np.ndarray  # reference angles of the nodes [rad]
    R_ref: float  # stress-free radius [m]
    lambda0: float  # prestretch
    L0: np.ndarray  # reference chords [m]
    S0: np.ndarray  # reference hoop sums R_ref (sin phi_a + sin phi_b) [m]
    A0: np.ndarray  # reference zone areas [m^2]
    mass: np.ndarray  # lumped nodal masses [kg]
    Ebar: float  # E0 h / (1 - nu^2) [N/m]
    nu: float
    k: float
    rho_h: float  # mass per reference area [kg/m^2]

    @property
    def n(self):
        return self.phi.shape[0]

    def forces(self, X, Y, q):
        """Total nodal forces [N] at positions (X, Y) under net inside pressure q [Pa]."""
        Fx = np.empty_like(X)
        Fy = np.empty_like(Y)
        internal_forces(X, Y, self.L0, self.S0, self.A0, self.Ebar, self.nu, self.k, Fx, Fy)
        add_pressure_loads(X, Y, q, Fx, Fy)
        return Fx, Fy


def build_membrane(phi, R, p0, E0, h, nu, k, rho_c) -> MembraneModel:
    """Membrane on reference angles ``phi`` (apex first), prestressed by p0 on the drawn arc R."""
    Ebar = E0 * h / (1.0 - nu * nu)
    lam0 = prestretch(p0, R, Ebar, nu, k)
    R_ref = R / lam0
    pa, pb = phi[:-1], phi[1:]
    L0 = 2.0 * R_ref * np.sin(0.5 * (pb - pa))
    S0 = R_ref * (np.sin(pa) + np.sin(pb))
    A0 = 2.0 * math.pi * R_ref ** 2 * (np.cos(pa) - np.cos(pb))
    # lumped masses: reference tributary zone of each node (half of each adjacent segment)
    edges = np.concatenate(([phi[0]], 0.5 * (pa + pb), [phi[-1]]))
    trib = 2.0 * math.pi * R_ref ** 2 * (np.cos(edges[:-1]) - np.cos(edges[1:]))
    mass = rho_c * h * trib
    return MembraneModel(phi, R_ref, lam0, L0, S0, A0, mass, Ebar, nu, k, rho_c * h)


def static_equilibrium(model: MembraneModel, X, Y, q, tol=1e-12, max_iter=50):
    """Newton's method for the discrete equilibrium under the net pressure q [Pa].

    Unknowns: y of the apex and (x, y) of the free nodes (the apex stays on the axis, the limbus
    is fixed).  Returns (X, Y, residual norm relative to the pressure force scale).
    """
    n = model.n
    X = X.copy()
    Y = Y.copy()
    free = [("y", 0)] + [(c, i) for i in range(1, n - 1) for c in ("x", "y")]

    def residual(Xc, Yc):
        Fx, Fy = model.forces(Xc, Yc, q)
        return np.array([Fy[i] if c == "y" else Fx[i] for c, i in free])

    scale = np.max(np.abs(q)) * np.max(model.A0) + 1e-300
    res = residual(X, Y)
    for _ in range(max_iter):
        if np.max(np.abs(res)) / scale < tol:
            break
        J = np.empty((len(free), len(free)))
        eps = 1e-9 * model.R_ref
        for col, (c, i) in enumerate(free):
            Xp, Yp, Xm, Ym = X.copy(), Y.copy(), X.copy(), Y.copy()
            if c == "x":
                Xp[i] += eps
                Xm[i] -= eps
            else:
                Yp[i] += eps
                Ym[i] -= eps
            J[:, col] = (residual(Xp, Yp) - residual(Xm, Ym)) / (2 * eps)
        delta = np.linalg.solve(J, -res)
        for (c, i), d in zip(free, delta):
            if c == "x":
                X[i] += d
            else:
                Y[i] += d
        res = residual(X, Y)
    return X, Y, float(np.max(np.abs(res)) / scale)


def jet_pressure(t, phi, pmax, a, b, T, t0):
    """Eq. (11): p_a = pmax exp(-a sin^2 phi) exp(-b (t - t0)^2 / T^2)  [Pa], for arrays of times
    t [s] or reference angles phi [rad] (numpy broadcasting; the kernels use ``air_jet``)."""
    return pmax * np.exp(-a * np.sin(phi) ** 2) * np.exp(-b * (np.asarray(t) - t0) ** 2 / T ** 2)


# m: apex curvature is fitted over the nodes with x <= this radius.  It must be small against the
# width of the jet (exp(-a sin^2 phi) falls to 1/e at 1.5 mm, by 35 % already at 1 mm): the net
# pressure, and with it the curvature of a membrane, varies across the jet, and a wide fit measures
# an average that is not the apex (a 1 mm fit put P1, P2 0.1-0.5 mmHg off the apex balance).
APEX_FIT_RADIUS = 0.3e-3


def apex_fit_nodes(X_ref, fit_radius=APEX_FIT_RADIUS):
    """Number of cornea nodes (apex first) whose reference x lies within ``fit_radius``, at least
    two.  Chosen once per run, so the fit follows the same material points throughout."""
    return max(2, int(np.searchsorted(X_ref, fit_radius * (1 + 1e-9), side="right")))


def apex_curvature(X, Y, n_fit):
    """Apical curvature [1/m], positive convex, from an even least-squares fit over the first
    ``n_fit`` nodes (those within APEX_FIT_RADIUS of the axis in the reference state):

        y = c0 + c2 x^2 (+ c4 x^4 when n_fit >= 4),   kappa = -2 c2

    A fixed physical radius, not a node count, so the measure converges to the curvature at the
    apex as the resolution grows.  With two nodes it is 2 (y0 - y1) / x1^2, the curvature the
    discrete apex balance 2 N kappa = q actually sees.
    """
    x = X[:n_fit]
    y = Y[:n_fit]
    if n_fit >= 4:
        G = np.stack([np.ones(n_fit), x * x, x ** 4], axis=1)
    else:
        G = np.stack([np.ones(n_fit), x * x], axis=1)
    coef = np.linalg.lstsq(G, y, rcond=None)[0]
    return -2.0 * coef[1]
