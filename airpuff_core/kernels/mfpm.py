"""Modified Finite Particle Method (MFPM) operators and the SPH (Brookshaw) Laplacian.

MFPM.  At node i the derivative vector D f = (f_x, f_y, f_xx, f_xy, f_yy) solves

    sum_j (f_j - f_i) W_alpha,ij = sum_beta A_alpha,beta D_beta f,
    A_alpha,beta = sum_j P_beta(x_j - x_i) W_alpha,ij,

with P = (dx, dy, dx^2/2, dx dy, dy^2/2) and projection functions W_alpha,ij = P_alpha(x_j - x_i) W(r_ij)
(monomial-weighted Wendland C2 kernel; the monomials are scaled by s_i = kappa h_i so that A is
well conditioned).  A is symmetric positive definite when the neighbours span the quadratics; it
depends on positions only and is inverted once per node and evaluation (written-out LDL^T):

    D f_i = S_i A_i^-1 b_i(f),   b_i(f) = sum_j P(x_j - x_i) W_ij (f_j - f_i).

Several fields share one build (one A^-1 per node).  The operator reproduces the
derivatives of any quadratic field to round-off, on irregular clouds and one-sided boundary
stencils alike.  A moment matrix whose 1-norm condition number exceeds ``cond_max`` is an error.

Brookshaw Laplacian (used only for the stabilising hyperviscosity, a sign-definite operator):

    (L f)_i = sum_j b_ij (f_j - f_i),   b_ij = 2 A_j (-dW/dr)(r_ij) / r_ij >= 0,

with A_j the node's area in the meridian plane and W the 2-D normalised Wendland C2 kernel of
support H_ij = kappa max(h_i, h_j).  A_i b_ij is symmetric, so L is self-adjoint and negative
semi-definite in the A-weighted inner product: its powers damp and never amplify.
"""

import numpy as np
from numba import njit, prange


@njit(cache=True)
def chunk_bounds(n_items, n_chunks, c):
    """[lo, hi): the items of chunk c of n_chunks nearly equal contiguous chunks."""
    return c * n_items // n_chunks, (c + 1) * n_items // n_chunks


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


# The one floating-point liberty the kernels take: a * b + c may be one fused multiply-add (one
# rounding instead of two), which cuts the pair loops' instruction count (docs/performance.md,
# "Fused multiply-adds, and two fields per pass").
# The choice is made per expression, so every compiled copy of a loop rounds alike.  No
# reassociation: that let the compiler vectorise sums in an order that differed between compiled
# copies (bits then differed between a Dask worker and its client); no 'nnan': the
# singular-matrix checks test for NaN.
FUSED_MULTIPLY_ADD = {"contract"}

LAPLACIAN_SCALE = 2.0 * 140.0 / np.pi  # 2 x (7 / pi) x 20: b_ij = LAPLACIAN_SCALE A_j (1-q)^3 / H^4


@njit(cache=True, parallel=True, fastmath=FUSED_MULTIPLY_ADD)
def mfpm_derivatives(x, y, h, inv_h, area, kappa, start, nbr, mirrored, nodes, fields, parity,
                     cond_max, out, cond, lap_count, lap_nbr, lap_sign, lap_b, lap_c, lap_w,
                     store_laplacian, store_consistent, n_chunks):
    """Build the MFPM operator of each node in ``nodes`` at the positions (x, y) [m] and apply it
    to every field: out[f, i, :] = D fields[f] at node i, with D f = (f_x, f_y, f_xx, f_xy, f_yy),
    or only (f_x, f_y) when ``out`` has two columns.

    The candidate pairs come from the neighbour table, stored flat: node i's are
    p = start[i] ... start[i + 1] - 1, with neighbour ``nbr[p]`` and ``mirrored[p]`` = 1 for the
    image (-x_j, y_j).  h [m] is the node spacing (``inv_h`` = 1/h), ``area`` [m^2] the node area
    in the meridian plane.  Per node i:
      1. the distances r_ij to the candidates, then the list of those inside the support
         r_ij < H_ij = kappa max(h_i, h_j): a pair outside has W = 0 and contributes exactly
         nothing;
      2. the scaled moment matrix A = sum_j W_ij P_j P_j^T, P_j = (u, v, u^2/2, u v, v^2/2),
         (u, v) = (x_j - x_i, y_j - y_i) / s_i, s_i = kappa h_i, with the Wendland C2 shape
         W = (1-q)^4 (4q+1), q = r_ij / H_ij.  Its 15 entries are 12 distinct monomial sums
         S_ab = sum_j W_ij u^a v^b;
      3. A^-1 by the written-out LDL^T (``spd_inverse5``), and the 1-norm condition number of A
         into ``cond[i]``;
      4. for each field, b = sum_j W_ij P_j (f_j - f_i) (f_j times the field's ``parity``, +1
         even or -1 odd in x, for a mirror image: the image's sign for an odd field, 1 for an
         even one, so that one loop without a branch serves both) and D f_i = S A^-1 b,
         S = diag(1/s, 1/s, 1/s^2, 1/s^2, 1/s^2).

    No pair weight is stored across calls: in the solver each operator is applied once, right
    after its build.  Within a node the weighted monomials W_ij P_j are kept in scratch rows,
    for the moment sums and every field; two fields share a pass over them.  For speed
    (docs/performance.md): each
    node's x, y, h, 1/h are packed side by side, so a neighbour costs one cache line; the
    support's pairs are written into contiguous scratch rows in the distance pass itself (a
    branch-free compaction); the scratch rows are one block.

    The nodes are built in ``n_chunks`` contiguous chunks (``threads.chunks``) by a parallel
    loop (one chunk without it); a node's results depend on its own support only.  The
    arithmetic is IEEE with fused multiply-adds only (``FUSED_MULTIPLY_ADD``): reassociated sums
    would let the compiler vectorise the reductions differently in each compiled copy of the
    loop (serial or parallel, fresh or from the Numba cache), and a run in a Dask worker could
    then differ in its last bits from the same run in its client (docs/performance.md,
    "Threads").  Every sum runs in the order of the pairs, so the results are the same bit for
    bit for any chunks, threads, process or cache (tests/core/test_threads.py).

    With ``store_laplacian`` (all nodes) the support's pairs and the Brookshaw coefficients
    b_ij = 2 A_j (-dW/dr) / r_ij = LAPLACIAN_SCALE A_j (1-q)^3 / H_ij^4 are also kept, node i's in
    lap_*[start[i] ... start[i] + lap_count[i] - 1] (``lap_sign`` = -1.0 for a mirror image,
    else 1.0: x_j's factor, which the three-field pass multiplies by rather than branching),
    for ``brookshaw_laplacian`` and the hyperviscosity, and with them (``store_consistent``
    too) the coefficients of the linearly consistent Laplacian
    c_ij = b_ij - m_i . g_ij (see ``consistent_laplacian``): m_i = sum_j b_ij (x_j - x_i) is the
    first moment of the Brookshaw weights (zero on a full symmetric support, not at a wall) and
    g_ij the MFPM gradient weights, (grad f)_i = sum_j g_ij (f_j - f_i).  With
    ``store_laplacian`` and a ``lap_w`` of 5 rows (not 0) the operator itself is kept too: its
    pair weights d_ij = S A^-1 P_j W_ij, (D f)_i = sum_j d_ij (f_j - f_i), in
    lap_w[:, start[i] ... start[i] + lap_count[i] - 1], for ``mapped_derivatives``.

    Returns 0, or i+1 for the first node whose matrix is singular or worse than ``cond_max``.
    """
    n = x.shape[0]
    node = np.empty((n, 4))
    for i in range(n):
        node[i, 0] = x[i]
        node[i, 1] = y[i]
        node[i, 2] = h[i]
        node[i, 3] = inv_h[i]
    n_chunks = max(1, min(n_chunks, nodes.shape[0]))
    if n_chunks == 1:  # no parallel loop to launch
        return _build_nodes(nodes, node, area, kappa, start, nbr, mirrored, fields, parity,
                            cond_max, out, cond, lap_count, lap_nbr, lap_sign, lap_b,
                            lap_c, lap_w, store_laplacian, store_consistent)
    status = np.zeros(n_chunks, np.int64)
    for c in prange(n_chunks):
        lo, hi = chunk_bounds(nodes.shape[0], n_chunks, c)
        status[c] = _build_nodes(nodes[lo:hi], node, area, kappa, start, nbr, mirrored, fields,
                                 parity, cond_max, out, cond, lap_count, lap_nbr,
                                 lap_sign, lap_b, lap_c, lap_w, store_laplacian,
                                 store_consistent)
    for c in range(n_chunks):  # the first failing node in the order of ``nodes``
        if status[c]:
            return status[c]
    return 0


@njit(inline="always")
def _store_derivatives(out, f, i, n_rows, inv_s, inverse, b0, b1, b2, b3, b4):
    """out[f, i, :] = S A^-1 b for the moment vector b of field f at node i, with A^-1's lower
    triangle ``inverse`` and S = diag(1/s, 1/s, 1/s^2, 1/s^2, 1/s^2), 1/s = ``inv_s``: the first
    ``n_rows`` (2 or 5) of (f_x, f_y, f_xx, f_xy, f_yy)."""
    i00, i10, i11, i20, i21, i22, i30, i31, i32, i33, i40, i41, i42, i43, i44 = inverse
    s1 = inv_s
    s2 = inv_s * inv_s
    out[f, i, 0] = s1 * (i00 * b0 + i10 * b1 + i20 * b2 + i30 * b3 + i40 * b4)
    out[f, i, 1] = s1 * (i10 * b0 + i11 * b1 + i21 * b2 + i31 * b3 + i41 * b4)
    if n_rows == 5:
        out[f, i, 2] = s2 * (i20 * b0 + i21 * b1 + i22 * b2 + i32 * b3 + i42 * b4)
        out[f, i, 3] = s2 * (i30 * b0 + i31 * b1 + i32 * b2 + i33 * b3 + i43 * b4)
        out[f, i, 4] = s2 * (i40 * b0 + i41 * b1 + i42 * b2 + i43 * b3 + i44 * b4)


@njit(inline="always")
def _build_nodes(nodes, node, area, kappa, start, nbr, mirrored, fields, parity, cond_max, out,
                 cond, lap_count, lap_nbr, lap_sign, lap_b, lap_c, lap_w, store_laplacian,
                 store_consistent):
    """The loop of ``mfpm_derivatives`` over ``nodes`` (one chunk), with its own scratch rows;
    ``node`` holds each node's (x, y, h, 1/h) side by side.  Inlined into ``mfpm_derivatives``."""
    n_fields = fields.shape[0]
    n_rows = out.shape[2]  # 5, or 2 for the gradient only
    width = 1
    for i in nodes:
        width = max(width, start[i + 1] - start[i])
    # scratch rows in one block: separate small allocations may land 4 KiB apart, where the
    # loads of one row wait on stores to another (4K aliasing)
    scratch = np.empty((13, width))
    u_k, v_k, r2_k, inv_support_k, sign_k, w_k, t3_k, ones_k = (
        scratch[0], scratch[1], scratch[2], scratch[3], scratch[4], scratch[5], scratch[6],
        scratch[7])
    pw0, pw1, pw2, pw3, pw4 = scratch[8], scratch[9], scratch[10], scratch[11], scratch[12]
    for k in range(width):  # a loop, not ones_k[:] = 1.0: in a parallel function an array
        ones_k[k] = 1.0  # expression becomes a parallel loop, and wakes every thread
    nbr_k = np.empty(width, np.uint32)
    inv_kappa = 1.0 / kappa
    status = 0
    for i in nodes:
        xi = node[i, 0]
        yi = node[i, 1]
        hi = node[i, 2]
        inv_hi = node[i, 3]
        inv_s = inv_kappa * inv_hi
        p0 = start[i]
        n_cand = start[i + 1] - p0
        # 1. distances to the candidates; those inside the support are written contiguous
        # (every candidate is written at slot m, and m advances only for one inside: no branch)
        m = np.uint64(0)  # unsigned: no negative-index wrap-around check on the scratch rows
        for c in range(n_cand):
            p = p0 + c
            j = nbr[p]
            sign = 1.0 - 2.0 * mirrored[p]  # x_j's factor: -1 for a mirror image
            dx = sign * node[j, 0] - xi
            dy = node[j, 1] - yi
            H = kappa * max(hi, node[j, 2])
            r2 = dx * dx + dy * dy
            nbr_k[m] = j
            u_k[m] = dx * inv_s
            v_k[m] = dy * inv_s
            r2_k[m] = r2
            inv_support_k[m] = inv_kappa * min(inv_hi, node[j, 3])
            sign_k[m] = sign
            m += np.uint64(r2 < H * H)
        # 2. kernel values and the weighted monomials W P_k, then the moment sums
        for k in range(m):
            q = np.sqrt(r2_k[k]) * inv_support_k[k]
            tq = max(1.0 - q, 0.0)  # rounding may put q at 1 for r just below H: W = 0 there
            t3 = tq * tq * tq
            w = t3 * tq * (4.0 * q + 1.0)
            u = u_k[k]
            v = v_k[k]
            w_k[k] = w
            t3_k[k] = t3
            wu = w * u
            wv = w * v
            pw0[k] = wu
            pw1[k] = wv
            pw2[k] = 0.5 * wu * u
            pw3[k] = wu * v
            pw4[k] = 0.5 * wv * v
        s20 = s11 = s02 = s30 = s21 = s12 = s03 = s40 = s31 = s22 = s13 = s04 = 0.0
        for k in range(m):
            u = u_k[k]
            v = v_k[k]
            wuu = pw0[k] * u
            wuv = pw0[k] * v
            wvv = pw1[k] * v
            s20 += wuu
            s11 += wuv
            s02 += wvv
            s30 += wuu * u
            s21 += wuu * v
            s12 += wuv * v
            s03 += wvv * v
            s40 += wuu * u * u
            s31 += wuu * u * v
            s22 += wuu * v * v
            s13 += wuv * v * v
            s04 += wvv * v * v
        # A's lower triangle in the order P = (u, v, u^2/2, u v, v^2/2)
        a00 = s20
        a10 = s11
        a11 = s02
        a20 = 0.5 * s30
        a21 = 0.5 * s21
        a22 = 0.25 * s40
        a30 = s21
        a31 = s12
        a32 = 0.5 * s31
        a33 = s22
        a40 = 0.5 * s12
        a41 = 0.5 * s03
        a42 = 0.25 * s22
        a43 = 0.5 * s13
        a44 = 0.25 * s04
        if store_laplacian:
            for k in range(m):
                j = nbr_k[k]
                ih2 = inv_support_k[k] * inv_support_k[k]
                lap_nbr[p0 + k] = j
                lap_sign[p0 + k] = sign_k[k]
                lap_b[p0 + k] = area[j] * LAPLACIAN_SCALE * ih2 * ih2 * t3_k[k]
            lap_count[i] = m
        # 3. inverse and condition number
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
        if store_consistent:
            # c_k = b_k - m . g_k with the first moment m = s sum_k b_k (u_k, v_k) and the
            # gradient weights g_k = (1/s) (A^-1 P_k)[0:2] W_k: the spacing scale s cancels
            mx = 0.0
            my = 0.0
            for k in range(m):
                mx += lap_b[p0 + k] * u_k[k]
                my += lap_b[p0 + k] * v_k[k]
            for k in range(m):
                u = u_k[k]
                v = v_k[k]
                q2 = 0.5 * u * u
                q3 = u * v
                q4 = 0.5 * v * v
                gx = (i00 * u + i10 * v + i20 * q2 + i30 * q3 + i40 * q4) * w_k[k]
                gy = (i10 * u + i11 * v + i21 * q2 + i31 * q3 + i41 * q4) * w_k[k]
                lap_c[p0 + k] = lap_b[p0 + k] - (mx * gx + my * gy)
        if store_laplacian and lap_w.shape[0] == 5:
            # the operator's pair weights d_k = S A^-1 W_k P_k
            s2 = inv_s * inv_s
            for k in range(m):
                q0 = pw0[k]
                q1 = pw1[k]
                q2 = pw2[k]
                q3 = pw3[k]
                q4 = pw4[k]
                p = p0 + k
                lap_w[0, p] = inv_s * (i00 * q0 + i10 * q1 + i20 * q2 + i30 * q3 + i40 * q4)
                lap_w[1, p] = inv_s * (i10 * q0 + i11 * q1 + i21 * q2 + i31 * q3 + i41 * q4)
                lap_w[2, p] = s2 * (i20 * q0 + i21 * q1 + i22 * q2 + i32 * q3 + i42 * q4)
                lap_w[3, p] = s2 * (i30 * q0 + i31 * q1 + i32 * q2 + i33 * q3 + i43 * q4)
                lap_w[4, p] = s2 * (i40 * q0 + i41 * q1 + i42 * q2 + i43 * q3 + i44 * q4)
        # 4. each field's moment vector b, then D f = S A^-1 b; two fields share one pass over
        # the pairs: each sum b_a is a chain of dependent additions, and ten chains instead of
        # five keep the floating-point units busy (docs/performance.md)
        inverse = (i00, i10, i11, i20, i21, i22, i30, i31, i32, i33, i40, i41, i42, i43, i44)
        for f in range(0, n_fields - 1, 2):
            g = f + 1
            fi = fields[f, i]
            gi = fields[g, i]
            # an image of an odd field carries -f_j: the factor of f_j is the image's sign
            factor_f = sign_k if parity[f] < 0.0 else ones_k
            factor_g = sign_k if parity[g] < 0.0 else ones_k
            b0 = b1 = b2 = b3 = b4 = 0.0
            c0 = c1 = c2 = c3 = c4 = 0.0
            for k in range(m):
                j = nbr_k[k]
                df = factor_f[k] * fields[f, j] - fi
                dg = factor_g[k] * fields[g, j] - gi
                b0 += pw0[k] * df
                b1 += pw1[k] * df
                b2 += pw2[k] * df
                b3 += pw3[k] * df
                b4 += pw4[k] * df
                c0 += pw0[k] * dg
                c1 += pw1[k] * dg
                c2 += pw2[k] * dg
                c3 += pw3[k] * dg
                c4 += pw4[k] * dg
            _store_derivatives(out, f, i, n_rows, inv_s, inverse, b0, b1, b2, b3, b4)
            _store_derivatives(out, g, i, n_rows, inv_s, inverse, c0, c1, c2, c3, c4)
        # an odd last field: the pass above for one field, cheaper than pairing it with itself
        # (docs/performance.md, "What the code's comments used to carry")
        if n_fields % 2 == 1:
            f = n_fields - 1
            fi = fields[f, i]
            factor_f = sign_k if parity[f] < 0.0 else ones_k
            b0 = b1 = b2 = b3 = b4 = 0.0
            for k in range(m):
                df = factor_f[k] * fields[f, nbr_k[k]] - fi
                b0 += pw0[k] * df
                b1 += pw1[k] * df
                b2 += pw2[k] * df
                b3 += pw3[k] * df
                b4 += pw4[k] * df
            _store_derivatives(out, f, i, n_rows, inv_s, inverse, b0, b1, b2, b3, b4)
    return status


@njit(cache=True, parallel=True)
def mapped_derivatives(x, y, nodes, fields, parity, start, nbr, sign, count, weights, out,
                       strain, n_chunks):
    """out[f, i, :] = (f_x, f_y, f_xx, f_xy, f_yy) of fields[f] at node i, or (f_x, f_y) when
    ``out`` has two columns, at the positions (x, y) [m], from the MFPM operator D kept at
    earlier positions X (``mfpm_derivatives`` with ``lap_w``: its pair lists start, nbr, sign,
    count and pair weights ``weights`` (5, pairs)), mapped by the deformation since (the total
    Lagrangian form of the operator).

    D gives the derivatives with respect to the reference positions X.  Applied to the positions
    themselves (x odd in x, y even) it gives the deformation gradient F = dx/dX and the map's
    second derivatives; by the chain rule, with g = grad_x f and H_x f the Hessian in x,

        D_X f = F^T g,     H_X f = F^T (H_x f) F + g_x H_X x + g_y H_X y,

    so g = F^-T D_X f and H_x f = F^-T (H_X f - g_x H_X x - g_y H_X y) F^-1.  D is exact on
    quadratics in X, so the mapped operator is exact on quadratic fields for any affine
    deformation (F the same at every neighbour); for a curved one its error grows with the
    deformation's curvature over the support (``FluidStepper``'s ``strain_limit`` bounds it).
    strain[i] = max |F - I| (largest entry) at node i.  The nodes are done in ``n_chunks``
    contiguous chunks in parallel; a node's result depends on its own pairs only, summed in
    their order, so it is the same for any chunks or threads.  Returns 0, or i+1 for the first
    node (in the order of ``nodes``) whose F is not invertible with a positive determinant."""
    n_chunks = max(1, min(n_chunks, nodes.shape[0]))
    gradient_only = out.shape[2] == 2
    if n_chunks == 1:
        if gradient_only:
            return _mapped_gradient_nodes(nodes, x, y, fields, parity, start, nbr, sign, count,
                                          weights, out, strain)
        return _mapped_nodes(nodes, x, y, fields, parity, start, nbr, sign, count, weights,
                             out, strain)
    status = np.zeros(n_chunks, np.int64)
    for c in prange(n_chunks):
        lo, hi = chunk_bounds(nodes.shape[0], n_chunks, c)
        if gradient_only:
            status[c] = _mapped_gradient_nodes(nodes[lo:hi], x, y, fields, parity, start, nbr,
                                               sign, count, weights, out, strain)
        else:
            status[c] = _mapped_nodes(nodes[lo:hi], x, y, fields, parity, start, nbr, sign,
                                      count, weights, out, strain)
    for c in range(n_chunks):
        if status[c]:
            return status[c]
    return 0


@njit(cache=True, fastmath=FUSED_MULTIPLY_ADD)
def _mapped_nodes(nodes, x, y, fields, parity, start, nbr, sign, count, weights, out, strain):
    """The loop of ``mapped_derivatives`` over ``nodes`` (one chunk).  One pass over a node's
    pairs forms D_X of the positions and of one or two fields (a single field is carried twice):
    each of the sums is a chain of dependent additions, and 20 chains in one pass keep the
    floating-point units busy where separate passes would wait on each chain's latency."""
    n_rows = out.shape[2]
    n_fields = fields.shape[0]
    w0, w1, w2, w3, w4 = weights[0], weights[1], weights[2], weights[3], weights[4]
    status = 0
    for f0 in range(0, n_fields, 2):
        f1 = min(f0 + 1, n_fields - 1)
        # x_j's factor for an image is sign[p]; a field's is sign[p] if odd, else 1
        odd0 = 1.0 if parity[f0] < 0.0 else 0.0
        odd1 = 1.0 if parity[f1] < 0.0 else 0.0
        for i in nodes:
            p0 = start[i]
            p1 = p0 + count[i]
            xi = x[i]
            yi = y[i]
            u0 = fields[f0, i]
            u1 = fields[f1, i]
            # D_X x = (a, b, xxx, xxy, xyy), D_X y = (c, d, yxx, yxy, yyy); F = [[a, b], [c, d]]
            a = b = c = d = 0.0
            xxx = xxy = xyy = yxx = yxy = yyy = 0.0
            e0 = e1 = e2 = e3 = e4 = 0.0  # D_X of field f0
            k0 = k1 = k2 = k3 = k4 = 0.0  # D_X of field f1
            for p in range(p0, p1):
                j = nbr[p]
                sp = sign[p]
                dx = sp * x[j] - xi
                dy = y[j] - yi
                d0 = (1.0 + odd0 * (sp - 1.0)) * fields[f0, j] - u0
                d1 = (1.0 + odd1 * (sp - 1.0)) * fields[f1, j] - u1
                q0 = w0[p]
                q1 = w1[p]
                q2 = w2[p]
                q3 = w3[p]
                q4 = w4[p]
                a += q0 * dx
                b += q1 * dx
                c += q0 * dy
                d += q1 * dy
                xxx += q2 * dx
                xxy += q3 * dx
                xyy += q4 * dx
                yxx += q2 * dy
                yxy += q3 * dy
                yyy += q4 * dy
                e0 += q0 * d0
                e1 += q1 * d0
                e2 += q2 * d0
                e3 += q3 * d0
                e4 += q4 * d0
                k0 += q0 * d1
                k1 += q1 * d1
                k2 += q2 * d1
                k3 += q3 * d1
                k4 += q4 * d1
            strain[i] = max(abs(a - 1.0), abs(b), abs(c), abs(d - 1.0))
            tangled, g00, g01, g10, g11 = _inverse_gradient(a, b, c, d)
            if tangled:
                if status == 0:
                    status = i + 1
                continue
            _chain_rule(out, f0, i, n_rows, g00, g01, g10, g11, xxx, xxy, xyy, yxx, yxy, yyy,
                        e0, e1, e2, e3, e4)
            if f1 != f0:
                _chain_rule(out, f1, i, n_rows, g00, g01, g10, g11, xxx, xxy, xyy, yxx, yxy,
                            yyy, k0, k1, k2, k3, k4)
    return status


@njit(cache=True, fastmath=FUSED_MULTIPLY_ADD)
def _mapped_gradient_nodes(nodes, x, y, fields, parity, start, nbr, sign, count, weights, out,
                           strain):
    """``_mapped_nodes`` when only the gradients are asked for (``out`` of two columns): one
    pass over a node's pairs per field forms F and the first two rows of D_X of the field, the
    sums of ``_mapped_nodes`` that the gradient and the strain need, in the same order (so the
    same bits), without the second derivatives' (6 sums per pair for one field instead of
    20)."""
    w0, w1 = weights[0], weights[1]
    status = 0
    for f in range(fields.shape[0]):
        odd = 1.0 if parity[f] < 0.0 else 0.0
        for i in nodes:
            p0 = start[i]
            p1 = p0 + count[i]
            xi = x[i]
            yi = y[i]
            u0 = fields[f, i]
            a = b = c = d = 0.0
            e0 = e1 = 0.0
            for p in range(p0, p1):
                j = nbr[p]
                sp = sign[p]
                dx = sp * x[j] - xi
                dy = y[j] - yi
                d0 = (1.0 + odd * (sp - 1.0)) * fields[f, j] - u0
                q0 = w0[p]
                q1 = w1[p]
                a += q0 * dx
                b += q1 * dx
                c += q0 * dy
                d += q1 * dy
                e0 += q0 * d0
                e1 += q1 * d0
            strain[i] = max(abs(a - 1.0), abs(b), abs(c), abs(d - 1.0))
            tangled, g00, g01, g10, g11 = _inverse_gradient(a, b, c, d)
            if tangled:
                if status == 0:
                    status = i + 1
                continue
            # the gradient rows of ``_chain_rule`` with its row count read from ``out`` as there
            # (a constant 2 lets the compiler fuse the multiply-adds otherwise, and the last
            # bits of g_y differ from the full evaluation's)
            _chain_rule(out, f, i, out.shape[2], g00, g01, g10, g11, 0.0, 0.0, 0.0, 0.0, 0.0,
                        0.0, e0, e1, 0.0, 0.0, 0.0)
    return status


@njit(inline="always")
def _inverse_gradient(a, b, c, d):
    """(tangled, G = F^-1 as g00, g01, g10, g11) of the deformation gradient F = [[a, b], [c, d]]:
    G = [[d, -b], [-c, a]] / det F; ``tangled`` when det F is not positive (also NaN), and G is
    then not computed (zeros)."""
    det = a * d - b * c
    if not det > 0.0:
        return True, 0.0, 0.0, 0.0, 0.0
    inv_det = 1.0 / det
    return False, d * inv_det, -b * inv_det, -c * inv_det, a * inv_det


@njit(inline="always")
def _chain_rule(out, f, i, n_rows, g00, g01, g10, g11, xxx, xxy, xyy, yxx, yxy, yyy, e0, e1, e2,
                e3, e4):
    """out[f, i] = the derivatives in x of a field from its derivatives e = D_X f in X, with
    G = F^-1 and the map's second derivatives (``mapped_derivatives``):
    g = G^T (e0, e1), H_x = G^T M G, M = H_X f - g_x H_X x - g_y H_X y."""
    gx = g00 * e0 + g10 * e1
    gy = g01 * e0 + g11 * e1
    out[f, i, 0] = gx
    out[f, i, 1] = gy
    if n_rows == 5:
        m00 = e2 - gx * xxx - gy * yxx
        m01 = e3 - gx * xxy - gy * yxy
        m11 = e4 - gx * xyy - gy * yyy
        t00 = m00 * g00 + m01 * g10  # M G
        t01 = m00 * g01 + m01 * g11
        t10 = m01 * g00 + m11 * g10
        t11 = m01 * g01 + m11 * g11
        out[f, i, 2] = g00 * t00 + g10 * t10
        out[f, i, 3] = g00 * t01 + g10 * t11
        out[f, i, 4] = g01 * t01 + g11 * t11


@njit(cache=True, fastmath=FUSED_MULTIPLY_ADD)
def brookshaw_laplacian(f, parity, start, nbr, sign, count, lap_b, out):
    """out_i = sum_j b_ij (f_j - f_i): the sign-definite SPH Laplacian (or, with the coefficients
    c_ij, the consistent Laplacian K of ``hyperviscous_term``)."""
    n = f.shape[0]
    for i in range(n):
        acc = 0.0
        fi = f[i]
        for k in range(start[i], start[i] + count[i]):
            j = nbr[k]
            fj = parity * f[j] if sign[k] < 0.0 else f[j]
            acc += lap_b[k] * (fj - fi)
        out[i] = acc


@njit(cache=True, fastmath=FUSED_MULTIPLY_ADD)
def pair_operator_adjoint(f, parity, start, nbr, sign, count, coef, area, out):
    """out = A^-1 K^T A f: the adjoint, in the weighted inner product <f, g> = sum_i A_i f_i g_i
    (``area`` = A: the node areas, halved on the axis, where the Brookshaw Laplacian is
    self-adjoint), of the pair operator (K f)_i = sum_j c_ij (f_j - f_i) that
    ``brookshaw_laplacian`` applies with the coefficients c (an image j carries parity f_j)."""
    n = f.shape[0]
    for i in range(n):
        out[i] = 0.0
    for i in range(n):
        af = area[i] * f[i]
        diagonal = 0.0
        for k in range(start[i], start[i] + count[i]):
            c = coef[k]
            diagonal += c
            out[nbr[k]] += (parity * c if sign[k] < 0.0 else c) * af
        out[i] -= diagonal * af
    for i in range(n):
        out[i] /= area[i]


@njit(cache=True)
def hyperviscous_term(f, parity, start, nbr, sign, count, lap_b, lap_c, area, consistent,
                      scale, work1, work2, out):
    """out_i = scale_i (H f)_i (scale_i = gamma c h_i^5), with H = L^3 (``consistent`` False: the
    paper-reproduction operator) or H = K^* L K (``consistent`` True): L the Brookshaw Laplacian,
    K the linearly consistent Laplacian (coefficients ``lap_c``), K^* its adjoint.

    L^3 is negative semi-definite, but a truncated support at a wall or the cornea makes L f != 0
    for a linear f there.  K f = 0 for every linear f, at boundary nodes too, so K^* L K
    annihilates linear fields.  With the weight A of ``pair_operator_adjoint`` (node areas,
    halved on the axis), A L is symmetric and negative semi-definite (for an odd field on the
    subspace where it vanishes on the axis), so A K^* L K = K^T (A L) K is too.  Either H damps
    and never amplifies, and acts mostly on grid-scale modes (eigenvalues grow like k^6).
    """
    if consistent:
        brookshaw_laplacian(f, parity, start, nbr, sign, count, lap_c, work1)
        brookshaw_laplacian(work1, parity, start, nbr, sign, count, lap_b, work2)
        pair_operator_adjoint(work2, parity, start, nbr, sign, count, lap_c, area, out)
    else:
        brookshaw_laplacian(f, parity, start, nbr, sign, count, lap_b, work1)
        brookshaw_laplacian(work1, parity, start, nbr, sign, count, lap_b, work2)
        brookshaw_laplacian(work2, parity, start, nbr, sign, count, lap_b, out)
    for i in range(f.shape[0]):
        out[i] *= scale[i]


@njit(cache=True, fastmath=FUSED_MULTIPLY_ADD)
def _pair_flow_rows(lo, hi, rho, vx, vy, start, nbr, sign, count, coef, coef_density, out_rho,
                    out_vx, out_vy):
    """Rows lo ... hi - 1 of ``pair_flow``."""
    for i in range(lo, hi):
        acc_r = 0.0
        acc_x = 0.0
        acc_y = 0.0
        ri = rho[i]
        xi = vx[i]
        yi = vy[i]
        for k in range(start[i], start[i] + count[i]):
            j = nbr[k]
            c = coef[k]
            if coef_density is None:
                acc_r += c * (rho[j] - ri)
            else:
                acc_r += coef_density[k] * (rho[j] - ri)
            acc_x += c * (sign[k] * vx[j] - xi)
            acc_y += c * (vy[j] - yi)
        out_rho[i] = acc_r
        out_vx[i] = acc_x
        out_vy[i] = acc_y


@njit(cache=True, parallel=True)
def pair_flow(rho, vx, vy, start, nbr, sign, count, coef, coef_density, n_chunks, out_rho,
              out_vx, out_vy):
    """The pair operator (K f)_i = sum_j c_ij (f_j - f_i) on the three flow fields in one pass
    over the pairs (rho and v_y even in x, v_x odd: an image carries sign * v_x, ``sign`` = -1.0
    for an image), with the coefficients ``coef`` (Brookshaw's ``lap_b`` or the consistent
    ``lap_c``) on the velocity and ``coef_density`` on rho, or ``coef`` on rho too when
    ``coef_density`` is None: each field's sum is the one ``brookshaw_laplacian`` forms.  A
    separate density coefficient is the first pass of K^* L K on the velocity with L^3 on the
    density (one pass instead of two); Numba compiles the None case apart, without the second
    array, and multiplies by the sign instead of branching on it, both for speed
    (docs/performance.md, "What the code's comments used to carry").
    Each node's sums are its own, so the ``n_chunks`` contiguous chunks of nodes
    (``threads.chunks``) run in parallel and give the same result for any number."""
    n = rho.shape[0]
    if n_chunks <= 1:
        _pair_flow_rows(0, n, rho, vx, vy, start, nbr, sign, count, coef, coef_density, out_rho,
                        out_vx, out_vy)
        return
    for c in prange(n_chunks):
        lo, hi = chunk_bounds(n, n_chunks, c)
        _pair_flow_rows(lo, hi, rho, vx, vy, start, nbr, sign, count, coef, coef_density,
                        out_rho, out_vx, out_vy)


ADJOINT_CHUNKS = 2  # fixed, so that the adjoint's sums do not depend on the number of threads


@njit(cache=True, fastmath=FUSED_MULTIPLY_ADD)
def _adjoint_rows(lo, hi, rho, vx, vy, start, nbr, sign, count, coef, coef_density, area,
                  with_density, acc_rho, acc_vx, acc_vy, out_rho):
    """Nodes lo ... hi - 1 of ``adjoint_flow``: their pairs scattered into ``acc_*`` (zeroed
    here), and without ``with_density`` rho's gathered pair sums into ``out_rho``."""
    for i in range(acc_vx.shape[0]):
        acc_vx[i] = 0.0
        acc_vy[i] = 0.0
    if with_density:
        for i in range(acc_rho.shape[0]):
            acc_rho[i] = 0.0
    for i in range(lo, hi):
        a = area[i]
        ri = rho[i]
        ar = a * ri
        ax = a * vx[i]
        ay = a * vy[i]
        diagonal = 0.0
        gather_rho = 0.0
        for k in range(start[i], start[i] + count[i]):
            j = nbr[k]
            b = coef[k]
            diagonal += b
            if with_density:
                acc_rho[j] += b * ar
            else:
                gather_rho += coef_density[k] * (rho[j] - ri)
            acc_vx[j] += sign[k] * b * ax
            acc_vy[j] += b * ay
        if with_density:
            acc_rho[i] -= diagonal * ar
        else:
            out_rho[i] = gather_rho
        acc_vx[i] -= diagonal * ax
        acc_vy[i] -= diagonal * ay


@njit(cache=True, parallel=True)
def adjoint_flow(rho, vx, vy, start, nbr, sign, count, coef, coef_density, area, with_density,
                 n_chunks, scatter, out_rho, out_vx, out_vy):
    """``pair_operator_adjoint`` of v_x (odd in x) and v_y (even), in one pass over the pairs;
    with ``with_density`` also that of rho (even), otherwise rho's pair operator of coefficients
    ``coef_density`` (a gather, as ``pair_flow``), in the same pass.

    The adjoint scatters node i's pairs into its neighbours' sums.  The nodes are split into
    ADJOINT_CHUNKS contiguous chunks, each scattering into its own rows of ``scatter``
    (ADJOINT_CHUNKS, 3, n), which are then added in chunk order: threads never write the same
    sum, and the order of every addition is fixed, so the result is the same for any number of
    threads (``n_chunks`` > 1 runs the chunks in parallel)."""
    n = rho.shape[0]
    if n_chunks <= 1:
        for c in range(ADJOINT_CHUNKS):
            lo, hi = chunk_bounds(n, ADJOINT_CHUNKS, c)
            _adjoint_rows(lo, hi, rho, vx, vy, start, nbr, sign, count, coef, coef_density, area,
                          with_density, scatter[c, 0], scatter[c, 1], scatter[c, 2], out_rho)
    else:
        for c in prange(ADJOINT_CHUNKS):
            lo, hi = chunk_bounds(n, ADJOINT_CHUNKS, c)
            _adjoint_rows(lo, hi, rho, vx, vy, start, nbr, sign, count, coef, coef_density, area,
                          with_density, scatter[c, 0], scatter[c, 1], scatter[c, 2], out_rho)
    for i in range(n):
        inv_a = 1.0 / area[i]
        total_vx = scatter[0, 1, i]
        total_vy = scatter[0, 2, i]
        for c in range(1, ADJOINT_CHUNKS):
            total_vx += scatter[c, 1, i]
            total_vy += scatter[c, 2, i]
        out_vx[i] = total_vx * inv_a
        out_vy[i] = total_vy * inv_a
        if with_density:  # otherwise out_rho holds the gathered density sums already
            total_rho = scatter[0, 0, i]
            for c in range(1, ADJOINT_CHUNKS):
                total_rho += scatter[c, 0, i]
            out_rho[i] = total_rho * inv_a


def flow_operator_work(n):
    """Scratch array of ``hyperviscous_flow_operator`` for n nodes."""
    return np.empty((1 + ADJOINT_CHUNKS, 3, n))


@njit(cache=True)
def hyperviscous_flow_operator(rho, vx, vy, start, nbr, sign, count, lap_b, lap_c, area,
                               consistent_density, consistent_velocity, n_chunks, work, out_rho,
                               out_vx, out_vy):
    """out_f = H f for the three flow fields (rho and v_y even in x, v_x odd): H = K^* L K on the
    density with ``consistent_density`` and on the velocity with ``consistent_velocity``, L^3
    otherwise (see ``hyperviscous_term``; ``consistent_density`` requires
    ``consistent_velocity``, the operators ``consistent`` and ``consistent_velocity`` of
    docs/model.md section 4).  The pair lists are ``Operators.hyperviscosity_args``; one pass
    over the pairs serves the three fields, and an application of H takes three passes (L^3 on
    rho with K^* L K on the velocity included: its passes ride along); ``work`` is the scratch
    array of ``flow_operator_work``.  This is the
    only place where the time integration of the hyperviscosity (``kernels/hyperviscosity.py``)
    meets the operator."""
    b_r, b_x, b_y = work[0, 0], work[0, 1], work[0, 2]
    scatter = work[1:]
    if not consistent_velocity:
        pair_flow(rho, vx, vy, start, nbr, sign, count, lap_b, None, n_chunks, out_rho, out_vx,
                  out_vy)
        pair_flow(out_rho, out_vx, out_vy, start, nbr, sign, count, lap_b, None, n_chunks, b_r,
                  b_x, b_y)
        pair_flow(b_r, b_x, b_y, start, nbr, sign, count, lap_b, None, n_chunks, out_rho, out_vx,
                  out_vy)
        return
    if consistent_density:
        pair_flow(rho, vx, vy, start, nbr, sign, count, lap_c, None, n_chunks, out_rho, out_vx,
                  out_vy)
    else:
        pair_flow(rho, vx, vy, start, nbr, sign, count, lap_c, lap_b, n_chunks, out_rho, out_vx,
                  out_vy)
    pair_flow(out_rho, out_vx, out_vy, start, nbr, sign, count, lap_b, None, n_chunks, b_r, b_x,
              b_y)
    adjoint_flow(b_r, b_x, b_y, start, nbr, sign, count, lap_c, lap_b, area, consistent_density,
                 n_chunks, scatter, out_rho, out_vx, out_vy)
