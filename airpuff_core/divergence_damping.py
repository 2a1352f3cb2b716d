"""Damping of the velocity's divergence: a stabilisation of the weakly compressible fluid that
acts only on its compressive part (docs/model.md section 4, "A stabilisation whose effect does
not grow with c").

    dv/dt += -W^-1 D^T S W D v,   S = diag(gamma_div c_d h),

with D the discrete axisymmetric divergence of the solver, (D v)_i = (v_x)_x + (v_y)_y + v_x/x
at node i (MFPM derivatives, the axis limit 2 (v_x)_x + (v_y)_y), W = diag(W_i) the weights of
the inner product in which the Brookshaw Laplacian is self-adjoint (node area, halved on the
axis), and D^T its transpose: -W^-1 D^T W is the adjoint of D, a gradient.  The rate is applied
to the velocity components that are not Dirichlet values (walls, cornea, v_x on the axis), so on
them it is -W_f^-1 D_f^T S W D v with D_f the free columns of D: its linear part is symmetric
and negative semi-definite in the W-inner product, <v, W dv/dt> = -(D v)^T S W (D v) <= 0, and
it annihilates every velocity field whose discrete divergence vanishes.  It is a bulk viscosity
gamma_div c_d h on the divergence, with c_d the sound speed c or a fixed speed
(``hyperviscosity_divergence_speed``).  With c_d = c it damps an acoustic mode of wavenumber k
at a rate of about gamma_div c h k^2, the same fraction gamma_div h k of the mode's frequency
c k at every c.  The smooth flow's discrete divergence, though, is not only its compressible
part, which falls like 1/c^2 (D rho / Dt = -rho div v, rho - rho0 ~ p / c^2): the operator's
truncation error on the cloud, largest at the cornea's one-sided stencils, gives it a part that
does not depend on c, on which a bulk viscosity growing with c exerts a force growing with c.
A fixed c_d keeps that force independent of c; the acoustic modes are then damped at a fraction
gamma_div h k c_d / c of their frequency, which the velocity's hyperviscosity supplements.

D is assembled as a sparse matrix from the pair weights of the solver's own derivative operator
at each operator build, and used until the next (as the hyperviscosity's Brookshaw lists are).
The term is stiff (its rate grows like c / h); it is integrated over the fluid step by
forward-Euler sub-steps within HV_SAFETY / HV_MARGIN of its spectral radius, which a power
iteration gives at each build (from the last build's vector after the first).  The products with D and D^T are compiled
(``kernels/divergence_damping.py``, the same sums as ``scipy.sparse``'s).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from .kernels.divergence_damping import damping_increments, damping_rate
from .kernels.nodes import AXIS_EPS

SAFETY = 1.0  # forward-Euler sub-steps of at most SAFETY / spectral radius (limit 2)
POWER_ITERATIONS = 40  # from a random start, at the first build
WARM_ITERATIONS = 8  # from the last build's vector, at the later builds


class DivergenceDamping:
    """The divergence damping of one run (module docstring) with strength ``gamma_div`` [1] and
    speed ``speed`` c_d [m/s] (0: the sound speed c)."""

    def __init__(self, gamma_div, speed, h, pinned_vx, pinned_vy):
        self.gamma_div = gamma_div
        self.speed = speed
        self.h = h
        self.free_x = ~pinned_vx
        self.free_y = ~pinned_vy
        self.D = None  # sparse (n, 2n): the divergence of (v_x, v_y)
        self.weight = None
        self.radius_unit = 0.0  # spectral radius of W^-1 D_f^T diag(h) W D_f [1/(m s) per c]
        self.built_for = -1
        self._vector = None  # the power iteration's last vector (the next build's start)
        n = h.shape[0]
        self._work = np.empty((4, n))  # scratch of the kernels
        self._rate_work = np.empty((2, 2 * n))

    def assemble(self, ops, x, weight):
        """D from the pair weights of the MFPM operator ``ops`` kept at its last build (at the
        node positions x [m] of that build, where the deformation gradient is the identity),
        the weights W, and the spectral radius.

        (D v)_i = a_i sum_j d^x_ij (s_ij v_x,j - v_x,i) + sum_j d^y_ij (v_y,j - v_y,i)
                  + v_x,i / x_i,
        with s_ij = -1 for a mirror image (v_x is odd in x), and on the axis a_i = 2 and no
        v_x / x term (its limit)."""
        start, nbr, sign, count, weights = ops.start, ops.nbr, ops.sign, ops.count, ops.lap_w
        n = x.shape[0]
        if weights.shape[0] != 5:
            raise ValueError("the divergence damping needs the kept operator (strain_limit > 0)")
        rows = np.repeat(np.arange(n), count)
        # node i's pairs start[i] ... start[i] + count[i] - 1, in node order
        first = np.cumsum(count) - count  # node i's first entry in ``pairs``
        pairs = np.arange(rows.shape[0]) + (start[:n] - first)[rows]
        cols = nbr[pairs].astype(np.int64)
        on_axis = x < AXIS_EPS
        factor = np.where(on_axis, 2.0, 1.0)[rows]
        wx = factor * weights[0, pairs]
        wy = weights[1, pairs]
        diag_x = -np.bincount(rows, wx, n) + np.where(on_axis, 0.0, 1.0 / np.where(on_axis, 1.0, x))
        diag_y = -np.bincount(rows, wy, n)
        i_all = np.arange(n)
        self.D = sp.csr_matrix(
            (np.concatenate([wx * sign[pairs], diag_x, wy, diag_y]),
             (np.concatenate([rows, i_all, rows, i_all]),
              np.concatenate([cols, i_all, n + cols, n + i_all]))), shape=(n, 2 * n))
        # D's compressed rows for the kernels, with unsigned offsets and columns: Numba then
        # emits no negative-index check in their loops (docs/performance.md)
        self._rows = (self.D.indptr.astype(np.uint64), self.D.indices.astype(np.uint32),
                      self.D.data)
        self.weight = weight.copy()
        self.radius_unit = self._spectral_radius()

    def rate(self, vx, vy, scale, out_x, out_y):
        """out = -W_f^-1 D_f^T S W D v [m/s^2] with S = ``scale`` (gamma_div c h per node)."""
        damping_rate(*self._rows, vx, vy, scale, self.weight, self.free_x, self.free_y,
                     self._rate_work, out_x, out_y)

    def _spectral_radius(self):
        """The spectral radius of W^-1 D_f^T diag(h) W D_f by power iterations: POWER_ITERATIONS
        from a fixed random start at the first build, WARM_ITERATIONS from the last build's
        vector at the later ones (D changes little between builds, so its dominant mode too)."""
        n = self.h.shape[0]
        if self._vector is None:
            f = np.random.default_rng(0).standard_normal(2 * n)
            iterations = POWER_ITERATIONS
        else:
            f = self._vector
            iterations = WARM_ITERATIONS
        ox, oy = np.empty(n), np.empty(n)
        lam = 0.0
        for _ in range(iterations):
            f[:n] *= self.free_x
            f[n:] *= self.free_y
            f /= np.linalg.norm(f)
            self.rate(f[:n], f[n:], self.h, ox, oy)
            g = np.concatenate([ox, oy])
            lam = float(np.linalg.norm(g))
            f = g
        self._vector = f
        return lam

    def increments(self, vx, vy, c, dt, out_x, out_y):
        """The change of v_x, v_y [m/s] over dt [s] under the damping alone at sound speed c
        [m/s], by forward-Euler sub-steps (module docstring), into out_x, out_y."""
        speed = self.speed if self.speed > 0 else c
        scale = self.gamma_div * speed * self.h
        steps = max(1, math.ceil(dt * self.gamma_div * speed * self.radius_unit / SAFETY))
        damping_increments(*self._rows, vx, vy, scale, self.weight, self.free_x, self.free_y,
                           dt / steps, steps, self._work, self._rate_work, out_x, out_y)
        return steps
