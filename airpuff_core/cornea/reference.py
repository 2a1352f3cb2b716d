"""The cornea's reference: the stress-free configuration under the IOP prestress, the discrete
membrane that every cornea model builds on (``MembraneModel``), and the discrete static
equilibrium.  The models and their advance in time are ``membrane.py``, ``kirchhoff.py`` and
``mindlin.py``.

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

from ..kernels.membrane import (add_pressure_loads, fung_resultants, internal_forces,
                                max_wave_speed)
from ..params import PRESTRETCH_MAX

# Verlet sub-step <= MEMBRANE_SAFETY * 2 / omega_max, the Verlet limit being 2 / omega_max; for the
# membrane, whose highest frequency is 2 c / L_min, that is MEMBRANE_SAFETY * min chord / c
MEMBRANE_SAFETY = 0.4


def equibiaxial_tension(lam, Ebar, nu, k):
    """N(lambda, lambda) [N/m] of the simplified Fung law."""
    E = 0.5 * (lam * lam - 1.0)
    return fung_resultants(E, E, Ebar, nu, k)[0]


def prestretch(p0, R, Ebar, nu, k):
    """lambda0 with N(lambda0, lambda0) = p0 R / 2 (bisection; N is increasing in lambda).

    ``RunParams.validate`` rejects the parameters that need lambda0 > PRESTRETCH_MAX (E0 below
    ``params.softest_E0``), so the error here is reached only by direct calls."""
    target = 0.5 * p0 * R
    lo, hi = 1.0, 1.0
    while equibiaxial_tension(hi, Ebar, nu, k) < target:
        if hi >= PRESTRETCH_MAX:
            raise ValueError(f"no prestretch up to {PRESTRETCH_MAX:g} balances the pressure "
                             f"{p0:g} Pa: the membrane (Ebar = {Ebar:g} N/m) is too soft")
        hi = min(1.0 + 2.0 * (hi - 1.0) + 1e-3, PRESTRETCH_MAX)
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

    stencil = 1  # the force on a node depends on the nodes up to this many away

    @property
    def n(self):
        return self.phi.shape[0]

    @property
    def length_scale(self):
        """A length of the reference [m] (the radius R_ref, or the meridian's length when it is
        not an arc), the scale of the finite-difference steps of ``static_equilibrium``."""
        return self.R_ref if math.isfinite(self.R_ref) else float(self.L0.sum())

    def substeps(self, X, Y, dt):
        """Verlet sub-steps that resolve the fastest membrane wave of the state (X, Y) [m] in a
        step of dt [s]: dt / n <= MEMBRANE_SAFETY * min chord / wave speed."""
        c_wave = max_wave_speed(X, Y, self.L0, self.S0, self.Ebar, self.nu, self.k, self.rho_h)
        return max(1, int(math.ceil(dt / (MEMBRANE_SAFETY * self.L0.min() / c_wave))))

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
    is fixed).  Returns (X [m], Y [m], residual norm relative to the pressure force scale).

    The Jacobian is taken by central differences, but column groups at a time: the force on a
    node depends only on that node and its two neighbours, so nodes three apart never act on the
    same force component.  Perturbing all of them together therefore gives, in each row, exactly
    the numbers of perturbing them one by one, and six patterns (node index mod 3, x or y) give
    the whole Jacobian from 12 force evaluations instead of 4 per node (these evaluations would
    otherwise dominate the start-up of a run).

    Newton reaches the rounding level of the residual in about three iterations; that level
    (~1e-12 of the pressure scale, from the nearly cancelling tension forces) can lie above
    ``tol``.  Once the residual is small (below sqrt(tol)) and an iteration no longer halves it,
    further iterations only reshuffle rounding errors, so the iteration stops there and the best
    iterate is returned.
    """
    n = model.n
    X = X.copy()
    Y = Y.copy()
    # unknown k <-> (coordinate, node): the apex's y, then x and y of nodes 1 .. n-2
    node = np.concatenate(([0], np.repeat(np.arange(1, n - 1), 2)))
    is_x = np.concatenate(([False], np.tile([True, False], n - 2)))
    ix, iy = node[is_x], node[~is_x]
    # rows touched by each unknown: the force components of the nodes within the stencil
    reach = model.stencil
    colours = 2 * reach + 1
    rows_of_node = {i: np.flatnonzero(np.abs(node - i) <= reach) for i in range(n - 1)}

    def residual(Xc, Yc):
        Fx, Fy = model.forces(Xc, Yc, q)
        r = np.empty(node.size)
        r[is_x] = Fx[ix]
        r[~is_x] = Fy[iy]
        return r

    scale = np.max(np.abs(q)) * np.max(model.A0) + 1e-300
    eps = 1e-9 * model.length_scale
    res = residual(X, Y)
    rel = float(np.max(np.abs(res)) / scale)
    best = (rel, X.copy(), Y.copy())
    for _ in range(max_iter):
        if rel < tol:
            break
        J = np.zeros((node.size, node.size))
        for coord in (True, False):
            for colour in range(colours):
                cols = np.flatnonzero((is_x == coord) & (node % colours == colour))
                if cols.size == 0:
                    continue
                step = np.zeros(n)
                step[node[cols]] = eps
                if coord:
                    diff = residual(X + step, Y) - residual(X - step, Y)
                else:
                    diff = residual(X, Y + step) - residual(X, Y - step)
                for col in cols:  # rows of nodes `colours` apart do not overlap (see above)
                    rows = rows_of_node[node[col]]
                    J[rows, col] = diff[rows] / (2 * eps)
        delta = np.linalg.solve(J, -res)
        X[ix] += delta[is_x]
        Y[iy] += delta[~is_x]
        res = residual(X, Y)
        rel_new = float(np.max(np.abs(res)) / scale)
        if rel_new < best[0]:
            best = (rel_new, X.copy(), Y.copy())
        stalled = rel < math.sqrt(tol) and rel_new > 0.5 * rel
        rel = rel_new
        if stalled:
            break
    rel, X, Y = best
    return X, Y, rel
