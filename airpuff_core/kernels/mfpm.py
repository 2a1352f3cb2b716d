"""Modified Finite Particle Method (MFPM) operators and the SPH (Brookshaw) Laplacian.

MFPM.  At node i the derivative vector D f = (f_x, f_y, f_xx, f_xy, f_yy) solves

    sum_j (f_j - f_i) W_alpha,ij = sum_beta A_alpha,beta D_beta f,
    A_alpha,beta = sum_j P_beta(x_j - x_i) W_alpha,ij,

with P = (dx, dy, dx^2/2, dx dy, dy^2/2) and projection functions W_alpha,ij = P_alpha(x_j - x_i) W(r_ij)
(monomial-weighted Wendland C2 kernel; the monomials are scaled by s_i = kappa h_i so that A is
well conditioned).  A is symmetric positive definite when the neighbours span the quadratics; it
depends on positions only, so it is inverted once per evaluation (written-out LDL^T) and the
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
def spd_inverse5(a00, a10, a11, a20, a21, a22, a30, a31, a32, a33, a40, a41, a42, a43, a44):
    """Inverse of a symmetric positive definite 5 x 5 matrix given by its lower triangle.

    A = L D L^T (unit lower triangular L, diagonal D > 0), N = L^-1, A^-1 = N^T D^-1 N.  Written
    out in scalars so that the factorisation stays in registers; the only long-latency operations
    are the five reciprocals 1/d_k (no square roots).  Returns the lower triangle of A^-1 in the
    argument order, or all NaN when a pivot d_k is not positive (A is not positive definite: the
    support does not span the quadratics).
    """
    nan = np.nan
    if not a00 > 0.0:
        return nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan
    e0 = 1.0 / a00
    # column k: g_ik = a_ik - sum_{m<k} l_im g_km, l_ik = g_ik / d_k, d_k = a_kk - sum_m l_km g_km
    l10 = a10 * e0
    l20 = a20 * e0
    l30 = a30 * e0
    l40 = a40 * e0
    d1 = a11 - l10 * a10
    if not d1 > 0.0:
        return nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan
    e1 = 1.0 / d1
    g21 = a21 - l20 * a10
    g31 = a31 - l30 * a10
    g41 = a41 - l40 * a10
    l21 = g21 * e1
    l31 = g31 * e1
    l41 = g41 * e1
    d2 = a22 - l20 * a20 - l21 * g21
    if not d2 > 0.0:
        return nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan
    e2 = 1.0 / d2
    g32 = a32 - l30 * a20 - l31 * g21
    g42 = a42 - l40 * a20 - l41 * g21
    l32 = g32 * e2
    l42 = g42 * e2
    d3 = a33 - l30 * a30 - l31 * g31 - l32 * g32
    if not d3 > 0.0:
        return nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan
    e3 = 1.0 / d3
    g43 = a43 - l40 * a30 - l41 * g31 - l42 * g32
    l43 = g43 * e3
    d4 = a44 - l40 * a40 - l41 * g41 - l42 * g42 - l43 * g43
    if not d4 > 0.0:
        return nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan
    e4 = 1.0 / d4
    # N = L^-1 (unit lower triangular): n_ij = -(l_ij + sum_{j<k<i} l_ik n_kj)
    n10 = -l10
    n21 = -l21
    n20 = -(l20 + l21 * n10)
    n32 = -l32
    n31 = -(l31 + l32 * n21)
    n30 = -(l30 + l31 * n10 + l32 * n20)
    n43 = -l43
    n42 = -(l42 + l43 * n32)
    n41 = -(l41 + l42 * n21 + l43 * n31)
    n40 = -(l40 + l41 * n10 + l42 * n20 + l43 * n30)
    # (A^-1)_ab = sum_{k >= max(a, b)} n_ka n_kb / d_k, with n_kk = 1
    return (e0 + n10 * n10 * e1 + n20 * n20 * e2 + n30 * n30 * e3 + n40 * n40 * e4,
            n10 * e1 + n21 * n20 * e2 + n31 * n30 * e3 + n41 * n40 * e4,
            e1 + n21 * n21 * e2 + n31 * n31 * e3 + n41 * n41 * e4,
            n20 * e2 + n32 * n30 * e3 + n42 * n40 * e4,
            n21 * e2 + n32 * n31 * e3 + n42 * n41 * e4,
            e2 + n32 * n32 * e3 + n42 * n42 * e4,
            n30 * e3 + n43 * n40 * e4,
            n31 * e3 + n43 * n41 * e4,
            n32 * e3 + n43 * n42 * e4,
            e3 + n43 * n43 * e4,
            n40 * e4,
            n41 * e4,
            n42 * e4,
            n43 * e4,
            e4)


@njit(cache=True)
def _norm1_sym5(a00, a10, a11, a20, a21, a22, a30, a31, a32, a33, a40, a41, a42, a43, a44):
    """1-norm (largest absolute column sum) of a symmetric 5 x 5 matrix from its lower triangle."""
    c0 = abs(a00) + abs(a10) + abs(a20) + abs(a30) + abs(a40)
    c1 = abs(a10) + abs(a11) + abs(a21) + abs(a31) + abs(a41)
    c2 = abs(a20) + abs(a21) + abs(a22) + abs(a32) + abs(a42)
    c3 = abs(a30) + abs(a31) + abs(a32) + abs(a33) + abs(a43)
    c4 = abs(a40) + abs(a41) + abs(a42) + abs(a43) + abs(a44)
    return max(c0, c1, c2, c3, c4)


@njit(cache=True, fastmath={"reassoc", "contract", "nsz"})
def compute_weights(x, y, h, area, kappa, table_nbr, table_mirrored, table_count, cond_max,
                    active, start, nbr, mirrored, count, weights, lap_b, cond):
    """MFPM pair weights and Brookshaw coefficients for the nodes listed in ``active`` (all nodes,
    or those near the moving cornea).

    The candidate pairs come from the neighbour table (``table_*``, searched with a skin); only the
    pairs inside the support (r < kappa max(h_i, h_j)) are kept, in the table's order, as node i's
    pairs p = start[i] ... start[i] + count[i] - 1 of the flat arrays ``nbr[p]``, ``mirrored[p]``,
    ``weights[beta, p]`` and ``lap_b[p]`` (start[i + 1] - start[i] >= the table's count for i).
    ``weights`` has 5 rows (beta = 0..4), or 2 when only gradients are wanted (``derivatives``
    into two columns).
    Contiguous pair data keep the derivative loops in cache.  A pair outside the support has W = 0
    and contributes exactly nothing, so dropping it changes no result.

    The moment matrix is accumulated in registers (a branch-free loop over the gathered pairs,
    which LLVM vectorises: the fastmath flags allow only reassociation and fused multiply-adds, so
    NaN and infinity keep their meaning) and inverted once per node (``spd_inverse5``); the pair
    weights are then A^-1 (P_j W_j) with no division in the pair loop.  ``cond[i]``
    receives the 1-norm condition number of the scaled moment matrix.  Returns 0, or i+1 for the
    first node whose matrix is singular or worse than ``cond_max``.
    """
    maxn = table_nbr.shape[1]
    n_rows = weights.shape[0]  # 5, or 2 for an operator that serves gradients only
    rk = np.empty(maxn)
    uk = np.empty(maxn)
    vk = np.empty(maxn)
    ik = np.empty(maxn)
    ck = np.empty(maxn)
    wk = np.empty(maxn)
    inv_h = np.empty(h.shape[0])
    for j in range(h.shape[0]):
        inv_h[j] = 1.0 / h[j]
    inv_kappa = 1.0 / kappa
    lap_scale = 2.0 * 140.0 / np.pi
    status = 0
    for i in active:
        xi = x[i]
        yi = y[i]
        hi = h[i]
        inv_hi = inv_h[i]
        inv_s = inv_kappa * inv_hi
        base = start[i]
        # 1. the table's pairs inside the support, gathered into contiguous scratch arrays
        m = 0
        for kk in range(table_count[i]):
            j = table_nbr[i, kk]
            mir = table_mirrored[i, kk]
            xj = -x[j] if mir else x[j]
            dx = xj - xi
            dy = y[j] - yi
            H = kappa * max(hi, h[j])
            r2 = dx * dx + dy * dy
            # written unconditionally and kept by advancing m only inside the support: no branch
            # to mispredict (slot m is free: start[i + 1] - start[i] >= the table's count)
            nbr[base + m] = j
            mirrored[base + m] = mir
            rk[m] = r2
            uk[m] = dx * inv_s
            vk[m] = dy * inv_s
            inv_H = inv_kappa * min(inv_hi, inv_h[j])
            ik[m] = inv_H
            ih2 = inv_H * inv_H
            ck[m] = area[j] * lap_scale * ih2 * ih2
            m += np.int64(r2 < H * H)
        count[i] = m
        # 2. kernel values, Brookshaw coefficients and the moment matrix (a branch-free loop)
        a00 = a10 = a11 = a20 = a21 = a22 = a30 = a31 = a32 = a33 = 0.0
        a40 = a41 = a42 = a43 = a44 = 0.0
        for k in range(m):
            q = np.sqrt(rk[k]) * ik[k]
            u = uk[k]
            v = vk[k]
            tq = max(1.0 - q, 0.0)  # rounding may put q at 1 for r just below H: W = 0 there
            t3 = tq * tq * tq
            w = t3 * tq * (4.0 * q + 1.0)  # Wendland C2 shape (1-q)^4 (4q+1)
            wk[k] = w
            # Brookshaw coefficient: 2 A_j (-dW/dr)/r with W = 7/(pi H^2) (1-q)^4 (4q+1)
            lap_b[base + k] = ck[k] * t3
            p2 = 0.5 * u * u
            p3 = u * v
            p4 = 0.5 * v * v
            a00 += w * u * u
            a10 += w * v * u
            a11 += w * v * v
            a20 += w * p2 * u
            a21 += w * p2 * v
            a22 += w * p2 * p2
            a30 += w * p3 * u
            a31 += w * p3 * v
            a32 += w * p3 * p2
            a33 += w * p3 * p3
            a40 += w * p4 * u
            a41 += w * p4 * v
            a42 += w * p4 * p2
            a43 += w * p4 * p3
            a44 += w * p4 * p4
        (i00, i10, i11, i20, i21, i22, i30, i31, i32, i33,
         i40, i41, i42, i43, i44) = spd_inverse5(a00, a10, a11, a20, a21, a22, a30, a31, a32, a33,
                                                 a40, a41, a42, a43, a44)
        if np.isnan(i00):
            cond[i] = np.inf
            if status == 0:
                status = i + 1
            continue
        cond[i] = (_norm1_sym5(a00, a10, a11, a20, a21, a22, a30, a31, a32, a33, a40, a41, a42,
                               a43, a44)
                   * _norm1_sym5(i00, i10, i11, i20, i21, i22, i30, i31, i32, i33, i40, i41, i42,
                                 i43, i44))
        if not (cond[i] < cond_max) and status == 0:
            status = i + 1
        s1 = inv_s
        s2 = inv_s * inv_s
        c00 = s1 * i00; c01 = s1 * i10; c02 = s1 * i20; c03 = s1 * i30; c04 = s1 * i40
        c10 = s1 * i10; c11 = s1 * i11; c12 = s1 * i21; c13 = s1 * i31; c14 = s1 * i41
        c20 = s2 * i20; c21 = s2 * i21; c22 = s2 * i22; c23 = s2 * i32; c24 = s2 * i42
        c30 = s2 * i30; c31 = s2 * i31; c32 = s2 * i32; c33 = s2 * i33; c34 = s2 * i43
        c40 = s2 * i40; c41 = s2 * i41; c42 = s2 * i42; c43 = s2 * i43; c44 = s2 * i44
        # 3. pair weights A^-1 P_j W_j, one row per derivative (the first two rows only for a
        # gradient-only operator)
        for k in range(m):
            w = wk[k]
            u = uk[k]
            v = vk[k]
            p0 = u * w
            p1 = v * w
            p2 = 0.5 * u * u * w
            p3 = u * v * w
            p4 = 0.5 * v * v * w
            weights[0, base + k] = c00 * p0 + c01 * p1 + c02 * p2 + c03 * p3 + c04 * p4
            weights[1, base + k] = c10 * p0 + c11 * p1 + c12 * p2 + c13 * p3 + c14 * p4
            if n_rows == 5:
                weights[2, base + k] = c20 * p0 + c21 * p1 + c22 * p2 + c23 * p3 + c24 * p4
                weights[3, base + k] = c30 * p0 + c31 * p1 + c32 * p2 + c33 * p3 + c34 * p4
                weights[4, base + k] = c40 * p0 + c41 * p1 + c42 * p2 + c43 * p3 + c44 * p4
    return status


@njit(cache=True)
def derivatives(f, parity, start, nbr, mirrored, count, weights, out):
    """out[i, :] = (f_x, f_y, f_xx, f_xy, f_yy) at every node, or only the gradient (f_x, f_y)
    when ``out`` has two columns (all an operator built with two weight rows can give).

    ``parity`` is +1 for a field even in x (density, pressure, v_y), -1 for an odd one (v_x).
    """
    full = out.shape[1] == 5
    for i in range(f.shape[0]):
        d0 = 0.0
        d1 = 0.0
        d2 = 0.0
        d3 = 0.0
        d4 = 0.0
        fi = f[i]
        for k in range(start[i], start[i] + count[i]):
            j = nbr[k]
            fj = parity * f[j] if mirrored[k] else f[j]
            df = fj - fi
            d0 += weights[0, k] * df
            d1 += weights[1, k] * df
            if full:  # loop-invariant: the compiler splits the loop in two
                d2 += weights[2, k] * df
                d3 += weights[3, k] * df
                d4 += weights[4, k] * df
        out[i, 0] = d0
        out[i, 1] = d1
        if full:
            out[i, 2] = d2
            out[i, 3] = d3
            out[i, 4] = d4


@njit(cache=True)
def derivatives_pair(f, parity_f, g, parity_g, start, nbr, mirrored, count, weights, out_f,
                     out_g):
    """``derivatives`` of two fields in one pass over the pairs (each weight is loaded once):
    out_f[i, :] = D f_i, out_g[i, :] = D g_i, the same sums as two ``derivatives`` calls."""
    n = f.shape[0]
    for i in range(n):
        a0 = a1 = a2 = a3 = a4 = 0.0
        b0 = b1 = b2 = b3 = b4 = 0.0
        fi = f[i]
        gi = g[i]
        for k in range(start[i], start[i] + count[i]):
            j = nbr[k]
            if mirrored[k]:
                df = parity_f * f[j] - fi
                dg = parity_g * g[j] - gi
            else:
                df = f[j] - fi
                dg = g[j] - gi
            w0 = weights[0, k]
            w1 = weights[1, k]
            w2 = weights[2, k]
            w3 = weights[3, k]
            w4 = weights[4, k]
            a0 += w0 * df
            a1 += w1 * df
            a2 += w2 * df
            a3 += w3 * df
            a4 += w4 * df
            b0 += w0 * dg
            b1 += w1 * dg
            b2 += w2 * dg
            b3 += w3 * dg
            b4 += w4 * dg
        out_f[i, 0] = a0
        out_f[i, 1] = a1
        out_f[i, 2] = a2
        out_f[i, 3] = a3
        out_f[i, 4] = a4
        out_g[i, 0] = b0
        out_g[i, 1] = b1
        out_g[i, 2] = b2
        out_g[i, 3] = b3
        out_g[i, 4] = b4


@njit(cache=True)
def brookshaw_laplacian(f, parity, start, nbr, mirrored, count, lap_b, out):
    """out_i = sum_j b_ij (f_j - f_i): the sign-definite SPH Laplacian."""
    n = f.shape[0]
    for i in range(n):
        acc = 0.0
        fi = f[i]
        for k in range(start[i], start[i] + count[i]):
            j = nbr[k]
            fj = parity * f[j] if mirrored[k] else f[j]
            acc += lap_b[k] * (fj - fi)
        out[i] = acc


@njit(cache=True)
def hyperviscous_term(f, parity, start, nbr, mirrored, count, lap_b, scale, work1, work2, out):
    """out_i = scale_i (L^3 f)_i, with L the Brookshaw Laplacian (scale_i = gamma c h_i^5).

    L^3 is negative semi-definite, so adding ``out`` to df/dt damps the grid-scale modes most
    (eigenvalues of L^3 grow like k^6) and the resolved flow very little.
    """
    brookshaw_laplacian(f, parity, start, nbr, mirrored, count, lap_b, work1)
    brookshaw_laplacian(work1, parity, start, nbr, mirrored, count, lap_b, work2)
    brookshaw_laplacian(work2, parity, start, nbr, mirrored, count, lap_b, out)
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
def _brookshaw_flow(rho, vx, vy, start, nbr, mirrored, count, lap_b, out_rho, out_vx, out_vy):
    """The Brookshaw Laplacian of the three flow fields in one pass over the pairs (rho and v_y
    even in x, v_x odd): each field's sum is the one ``brookshaw_laplacian`` forms."""
    for i in range(rho.shape[0]):
        acc_r = 0.0
        acc_x = 0.0
        acc_y = 0.0
        ri = rho[i]
        xi = vx[i]
        yi = vy[i]
        for k in range(start[i], start[i] + count[i]):
            j = nbr[k]
            b = lap_b[k]
            xj = -vx[j] if mirrored[k] else vx[j]
            acc_r += b * (rho[j] - ri)
            acc_x += b * (xj - xi)
            acc_y += b * (vy[j] - yi)
        out_rho[i] = acc_r
        out_vx[i] = acc_x
        out_vy[i] = acc_y


@njit(cache=True)
def hyperviscous_flow_increments(rho, vx, vy, pinned_vx, pinned_vy, start, nbr, mirrored, count,
                                 lap_b,
                                 scale, dt, n_sub, work, out_rho, out_vx, out_vy):
    """Change of rho, v_x and v_y over dt under d f/dt = scale L^3 f, by n_sub explicit Euler
    sub-steps: out_f = g(dt) - f with g(0) = f.

    Nodes with ``pinned_vx`` / ``pinned_vy`` keep their velocity component (Dirichlet nodes: walls,
    the cornea, v_x on the axis); no density is pinned.  Sub-cycling keeps dt/n_sub within the
    stability limit of this stiff term without shrinking the step of the whole solver.  One pass
    over the pairs serves the three fields.  ``work`` is a (9, n) scratch array.
    """
    n = rho.shape[0]
    h = dt / n_sub
    g_r, g_x, g_y = work[0], work[1], work[2]
    a_r, a_x, a_y = work[3], work[4], work[5]
    b_r, b_x, b_y = work[6], work[7], work[8]
    for i in range(n):
        g_r[i] = rho[i]
        g_x[i] = vx[i]
        g_y[i] = vy[i]
    for _ in range(n_sub):
        _brookshaw_flow(g_r, g_x, g_y, start, nbr, mirrored, count, lap_b, a_r, a_x, a_y)
        _brookshaw_flow(a_r, a_x, a_y, start, nbr, mirrored, count, lap_b, b_r, b_x, b_y)
        _brookshaw_flow(b_r, b_x, b_y, start, nbr, mirrored, count, lap_b, a_r, a_x, a_y)
        for i in range(n):
            s = scale[i]
            g_r[i] += h * (a_r[i] * s)
            if not pinned_vx[i]:
                g_x[i] += h * (a_x[i] * s)
            if not pinned_vy[i]:
                g_y[i] += h * (a_y[i] * s)
    for i in range(n):
        out_rho[i] = g_r[i] - rho[i]
        out_vx[i] = g_x[i] - vx[i]
        out_vy[i] = g_y[i] - vy[i]
