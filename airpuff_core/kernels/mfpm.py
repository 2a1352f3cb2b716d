"""Modified Finite Particle Method (MFPM) operators and the SPH (Brookshaw) Laplacian.

MFPM.  At node i the derivative vector D f = (f_x, f_y, f_xx, f_xy, f_yy) solves

    sum_j (f_j - f_i) W_alpha,ij = sum_beta A_alpha,beta D_beta f,
    A_alpha,beta = sum_j P_beta(x_j - x_i) W_alpha,ij,

with P = (dx, dy, dx^2/2, dx dy, dy^2/2) and projection functions W_alpha,ij = P_alpha(x_j - x_i) W(r_ij)
(monomial-weighted Wendland C2 kernel; the monomials are scaled by s_i = kappa h_i so that A is
well conditioned).  A is symmetric positive definite when the neighbours span the quadratics; it
depends on positions only, so it is factored once per evaluation (hand-written Cholesky) and the
result is stored as five weights per pair:

    D_beta f_i = sum_j c_ij,beta (f_j - f_i).

Every field's derivatives are then dot products over the neighbours.  The operator reproduces the
derivatives of any quadratic field to round-off, on irregular clouds and one-sided boundary
stencils alike.  A moment matrix whose 1-norm condition number exceeds ``cond_max`` is an error.

Brookshaw Laplacian (used only for the stabilising hyperviscosity, a sign-definite operator):

    (L f)_i = sum_j b_ij (f_j - f_i),   b_ij = 2 A_j (-dW/dr)(r_ij) / r_ij >= 0,

with A_j the node's area in the meridian plane and W the 2-D normalised Wendland C2 kernel of
support H_ij = kappa max(h_i, h_j).  A_i b_ij is symmetric, so L is self-adjoint and negative
semi-definite in the A-weighted inner product: its powers damp and never amplify.
"""

import numpy as np
from numba import njit


@njit(cache=True)
def _cholesky5(A, L):
    """A = L L^T for a 5 x 5 SPD matrix.  Returns False when a pivot is not positive."""
    for i in range(5):
        for j in range(i + 1):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if s <= 0.0:
                    return False
                L[i, i] = np.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    return True


@njit(cache=True)
def _solve5(L, b, out, z):
    """Solve L L^T out = b (forward and back substitution); z is a work vector of length 5."""
    for i in range(5):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * z[k]
        z[i] = s / L[i, i]
    for i in range(4, -1, -1):
        s = z[i]
        for k in range(i + 1, 5):
            s -= L[k, i] * out[k]
        out[i] = s / L[i, i]


@njit(cache=True)
def _wendland(q):
    """Wendland C2 shape (1-q)^4 (4q+1) on q = r/H in [0, 1] (unnormalised)."""
    if q >= 1.0:
        return 0.0
    t = 1.0 - q
    return t * t * t * t * (4.0 * q + 1.0)


@njit(cache=True)
def compute_weights(x, y, h, area, kappa, nbr, mirrored, count, cond_max, active, weights, lap_b,
                    cond):
    """MFPM pair weights ``weights[i, k, beta]`` and Brookshaw coefficients ``lap_b[i, k]`` for the
    nodes listed in ``active`` (all nodes, or those near the moving cornea).

    The moment matrix is factored (Cholesky) and inverted once per node; the pair weights are then
    A^-1 (P_j W_j) with no division in the pair loop.  ``cond[i]`` receives the 1-norm condition
    number of the scaled moment matrix.  Returns 0, or i+1 for the first node whose matrix is
    singular or worse than ``cond_max``.
    """
    maxn = nbr.shape[1]
    A = np.empty((5, 5))
    L = np.zeros((5, 5))
    Ainv = np.empty((5, 5))
    e = np.empty(5)
    col = np.empty(5)
    z = np.empty(5)
    wk = np.empty(maxn)
    uk = np.empty(maxn)
    vk = np.empty(maxn)
    status = 0
    for i in active:
        s = kappa * h[i]
        inv_s = 1.0 / s
        for a in range(5):
            for b in range(5):
                A[a, b] = 0.0
        for k in range(count[i]):
            j = nbr[i, k]
            xj = -x[j] if mirrored[i, k] else x[j]
            dx = xj - x[i]
            dy = y[j] - y[i]
            r = np.sqrt(dx * dx + dy * dy)
            inv_H = 1.0 / (kappa * max(h[i], h[j]))
            q = r * inv_H
            w = _wendland(q)
            u = dx * inv_s
            v = dy * inv_s
            wk[k] = w
            uk[k] = u
            vk[k] = v
            p2 = 0.5 * u * u
            p3 = u * v
            p4 = 0.5 * v * v
            # lower triangle of sum_j w p p^T
            A[0, 0] += w * u * u
            A[1, 0] += w * v * u
            A[1, 1] += w * v * v
            A[2, 0] += w * p2 * u
            A[2, 1] += w * p2 * v
            A[2, 2] += w * p2 * p2
            A[3, 0] += w * p3 * u
            A[3, 1] += w * p3 * v
            A[3, 2] += w * p3 * p2
            A[3, 3] += w * p3 * p3
            A[4, 0] += w * p4 * u
            A[4, 1] += w * p4 * v
            A[4, 2] += w * p4 * p2
            A[4, 3] += w * p4 * p3
            A[4, 4] += w * p4 * p4
            # Brookshaw coefficient: 2 A_j (-dW/dr)/r with W = 7/(pi H^2) (1-q)^4 (4q+1)
            t = 1.0 - q if q < 1.0 else 0.0
            ih2 = inv_H * inv_H
            lap_b[i, k] = 2.0 * area[j] * (140.0 / np.pi) * t * t * t * ih2 * ih2
        for a in range(5):
            for b in range(a + 1, 5):
                A[a, b] = A[b, a]
        ok = _cholesky5(A, L)
        if not ok:
            cond[i] = np.inf
            if status == 0:
                status = i + 1
            continue
        # explicit inverse (five solves) for the weights and the condition number
        anorm = 0.0
        for b in range(5):
            sacc = 0.0
            for a in range(5):
                sacc += abs(A[a, b])
            anorm = max(anorm, sacc)
        inorm = 0.0
        for b in range(5):
            for a in range(5):
                e[a] = 0.0
            e[b] = 1.0
            _solve5(L, e, col, z)
            sacc = 0.0
            for a in range(5):
                Ainv[a, b] = col[a]
                sacc += abs(col[a])
            inorm = max(inorm, sacc)
        cond[i] = anorm * inorm
        if not (cond[i] < cond_max) and status == 0:
            status = i + 1
        s1 = inv_s
        s2 = inv_s * inv_s
        for k in range(count[i]):
            w = wk[k]
            u = uk[k]
            v = vk[k]
            p0 = u * w
            p1 = v * w
            p2 = 0.5 * u * u * w
            p3 = u * v * w
            p4 = 0.5 * v * v * w
            weights[i, k, 0] = s1 * (Ainv[0, 0] * p0 + Ainv[0, 1] * p1 + Ainv[0, 2] * p2
                                     + Ainv[0, 3] * p3 + Ainv[0, 4] * p4)
            weights[i, k, 1] = s1 * (Ainv[1, 0] * p0 + Ainv[1, 1] * p1 + Ainv[1, 2] * p2
                                     + Ainv[1, 3] * p3 + Ainv[1, 4] * p4)
            weights[i, k, 2] = s2 * (Ainv[2, 0] * p0 + Ainv[2, 1] * p1 + Ainv[2, 2] * p2
                                     + Ainv[2, 3] * p3 + Ainv[2, 4] * p4)
            weights[i, k, 3] = s2 * (Ainv[3, 0] * p0 + Ainv[3, 1] * p1 + Ainv[3, 2] * p2
                                     + Ainv[3, 3] * p3 + Ainv[3, 4] * p4)
            weights[i, k, 4] = s2 * (Ainv[4, 0] * p0 + Ainv[4, 1] * p1 + Ainv[4, 2] * p2
                                     + Ainv[4, 3] * p3 + Ainv[4, 4] * p4)
    return status


@njit(cache=True)
def derivatives(f, parity, nbr, mirrored, count, weights, out):
    """out[i, :] = (f_x, f_y, f_xx, f_xy, f_yy) at every node.

    ``parity`` is +1 for a field even in x (density, pressure, v_y), -1 for an odd one (v_x).
    """
    n = f.shape[0]
    for i in range(n):
        d0 = 0.0
        d1 = 0.0
        d2 = 0.0
        d3 = 0.0
        d4 = 0.0
        fi = f[i]
        for k in range(count[i]):
            j = nbr[i, k]
            fj = parity * f[j] if mirrored[i, k] else f[j]
            df = fj - fi
            d0 += weights[i, k, 0] * df
            d1 += weights[i, k, 1] * df
            d2 += weights[i, k, 2] * df
            d3 += weights[i, k, 3] * df
            d4 += weights[i, k, 4] * df
        out[i, 0] = d0
        out[i, 1] = d1
        out[i, 2] = d2
        out[i, 3] = d3
        out[i, 4] = d4


@njit(cache=True)
def brookshaw_laplacian(f, parity, nbr, mirrored, count, lap_b, out):
    """out_i = sum_j b_ij (f_j - f_i): the sign-definite SPH Laplacian."""
    n = f.shape[0]
    for i in range(n):
        acc = 0.0
        fi = f[i]
        for k in range(count[i]):
            j = nbr[i, k]
            fj = parity * f[j] if mirrored[i, k] else f[j]
            acc += lap_b[i, k] * (fj - fi)
        out[i] = acc


@njit(cache=True)
def hyperviscous_term(f, parity, nbr, mirrored, count, lap_b, scale, work1, work2, out):
    """out_i = scale_i (L^3 f)_i, with L the Brookshaw Laplacian (scale_i = gamma c h_i^5).

    L^3 is negative semi-definite, so adding ``out`` to df/dt damps the grid-scale modes most
    (eigenvalues of L^3 grow like k^6) and the resolved flow very little.
    """
    brookshaw_laplacian(f, parity, nbr, mirrored, count, lap_b, work1)
    brookshaw_laplacian(work1, parity, nbr, mirrored, count, lap_b, work2)
    brookshaw_laplacian(work2, parity, nbr, mirrored, count, lap_b, out)
    for i in range(f.shape[0]):
        out[i] *= scale[i]


@njit(cache=True)
def near_nodes(mask, nbr, count):
    """Indices of the nodes i with mask[i] or with a neighbour j with mask[j]."""
    n = count.shape[0]
    out = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        hit = mask[i]
        if not hit:
            for k in range(count[i]):
                if mask[nbr[i, k]]:
                    hit = True
                    break
        if hit:
            out[m] = i
            m += 1
    return out[:m]


@njit(cache=True)
def hyperviscous_increment(f, parity, pinned, nbr, mirrored, count, lap_b, scale, dt, n_sub,
                           work1, work2, work3, g, out):
    """Change of f over dt under df/dt = scale L^3 f, by n_sub explicit Euler sub-steps.

    ``out = g(dt) - f`` with g(0) = f.  Nodes with ``pinned`` keep their value (Dirichlet nodes:
    walls, the cornea, v_x on the axis).  Sub-cycling keeps dt/n_sub within the stability limit of
    this stiff term without shrinking the step of the whole solver.
    """
    n = f.shape[0]
    h = dt / n_sub
    for i in range(n):
        g[i] = f[i]
    for _ in range(n_sub):
        hyperviscous_term(g, parity, nbr, mirrored, count, lap_b, scale, work1, work2, work3)
        for i in range(n):
            if not pinned[i]:
                g[i] += h * work3[i]
    for i in range(n):
        out[i] = g[i] - f[i]
