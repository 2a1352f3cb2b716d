"""The divergence damping's rate and its forward-Euler sub-steps (``divergence_damping.py``,
docs/model.md section 4), on the divergence matrix D stored in compressed sparse rows.

D is (n, 2n): row i is the divergence at node i of the velocity (v_x, v_y) stacked, column c < n
is v_x at node c, column n + c is v_y at node c (``indptr``, ``indices``, ``data``: the
canonical CSR arrays of ``scipy.sparse.csr_matrix``, every row's columns sorted and unique; the
offsets ``indptr`` as uint64 and the columns as uint32, so that no index is checked for being
negative).
D^T r is formed by scattering row i's entries times r_i into the columns, rows in increasing
order: each column then receives its terms in the order of D^T's own compressed rows, so both
products give the sums of ``scipy.sparse``'s matrix-vector product bit for bit (no fused
multiply-adds here, as in its compiled loops).
"""

from numba import njit


@njit(inline="always")
def _row_sum(indptr, indices, data, v, i, k_from, acc):
    """acc plus row i's entries from k_from on times the stacked velocity v, in their order."""
    for k in range(k_from, indptr[i + 1]):
        acc += data[k] * v[indices[k]]
    return acc


@njit(inline="always")
def _scatter_row(indptr, indices, data, i, r, scatter):
    """scatter[c] += D_ic r for row i's entries, in their order."""
    for k in range(indptr[i], indptr[i + 1]):
        scatter[indices[k]] += data[k] * r


@njit(cache=True)
def damping_rate(indptr, indices, data, vx, vy, scale, weight, free_x, free_y, work, out_x,
                 out_y):
    """out = -W_f^-1 D_f^T S W D v [m/s^2]: r = (S W)(D v) with S = ``scale`` (gamma_div c_d h per
    node [m/s]) and W = ``weight`` (node areas, halved on the axis [m^2]), g = D^T r, and
    out_x,i = -g_i / W_i where ``free_x`` (else 0), out_y,i = -g_{n+i} / W_i where ``free_y``.
    ``work``: scratch (2, 2n).

    Rows are taken two at a time: their first entries, as many as the shorter row has, in one
    loop (two independent sums, where one row's waits on the latency of each addition), then
    each row's remaining entries; every sum runs in its row's order."""
    n = vx.shape[0]
    v = work[0]  # (v_x, v_y) stacked, as D's columns
    scatter = work[1]
    for c in range(n):
        v[c] = vx[c]
        v[n + c] = vy[c]
    for c in range(2 * n):
        scatter[c] = 0.0
    i = 0
    while i + 1 < n:
        k0 = indptr[i]
        k1 = indptr[i + 1]
        common = min(k1 - k0, indptr[i + 2] - k1)
        acc0 = 0.0
        acc1 = 0.0
        for t in range(common):
            acc0 += data[k0 + t] * v[indices[k0 + t]]
            acc1 += data[k1 + t] * v[indices[k1 + t]]
        acc0 = _row_sum(indptr, indices, data, v, i, k0 + common, acc0)
        acc1 = _row_sum(indptr, indices, data, v, i + 1, k1 + common, acc1)
        _scatter_row(indptr, indices, data, i, (scale[i] * weight[i]) * acc0, scatter)
        _scatter_row(indptr, indices, data, i + 1, (scale[i + 1] * weight[i + 1]) * acc1,
                     scatter)
        i += 2
    if i < n:
        acc = _row_sum(indptr, indices, data, v, i, indptr[i], 0.0)
        _scatter_row(indptr, indices, data, i, (scale[i] * weight[i]) * acc, scatter)
    for i in range(n):
        out_x[i] = -scatter[i] / weight[i] if free_x[i] else 0.0
        out_y[i] = -scatter[n + i] / weight[i] if free_y[i] else 0.0


@njit(cache=True)
def damping_increments(indptr, indices, data, vx, vy, scale, weight, free_x, free_y, tau, steps,
                       work, rate_work, out_x, out_y):
    """The change of v_x, v_y [m/s] over ``steps`` forward-Euler sub-steps of tau [s] of
    dv/dt = ``damping_rate``: u = v, then u += tau rate(u) ``steps`` times; out = u - v.
    ``work``: scratch (4, n), ``rate_work``: ``damping_rate``'s."""
    n = vx.shape[0]
    ux, uy, rx, ry = work[0], work[1], work[2], work[3]
    for i in range(n):
        ux[i] = vx[i]
        uy[i] = vy[i]
    for _ in range(steps):
        damping_rate(indptr, indices, data, ux, uy, scale, weight, free_x, free_y, rate_work, rx,
                     ry)
        for i in range(n):
            ux[i] += tau * rx[i]
            uy[i] += tau * ry[i]
    for i in range(n):
        out_x[i] = ux[i] - vx[i]
        out_y[i] = uy[i] - vy[i]
