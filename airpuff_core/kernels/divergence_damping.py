"""The divergence damping's rate and its forward-Euler sub-steps (``divergence_damping.py``,
docs/model.md section 4), on the divergence matrix D stored in compressed sparse rows.

D is (n, 2n): row i is the divergence at node i of the velocity (v_x, v_y) stacked, column c < n
is v_x at node c, column n + c is v_y at node c (``indptr``, ``indices``, ``data``: the
canonical CSR arrays of ``scipy.sparse.csr_matrix``, every row's columns sorted and unique).
D^T r is formed by scattering row i's entries times r_i into the columns, rows in increasing
order: each column then receives its terms in the order of D^T's own compressed rows, so both
products give the sums of ``scipy.sparse``'s matrix-vector product bit for bit (no fused
multiply-adds here, as in its compiled loops).
"""

import numpy as np
from numba import njit


@njit(cache=True)
def damping_rate(indptr, indices, data, vx, vy, scale, weight, free_x, free_y, scatter, out_x,
                 out_y):
    """out = -W_f^-1 D_f^T S W D v [m/s^2]: r = (S W)(D v) with S = ``scale`` (gamma_div c h per
    node [m/s]) and W = ``weight`` (node areas, halved on the axis [m^2]), g = D^T r, and
    out_x,i = -g_i / W_i where ``free_x`` (else 0), out_y,i = -g_{n+i} / W_i where ``free_y``.
    ``scatter``: scratch of 2n values."""
    n = vx.shape[0]
    for c in range(2 * n):
        scatter[c] = 0.0
    for i in range(n):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            c = indices[k]
            acc += data[k] * (vx[c] if c < n else vy[c - n])
        r = (scale[i] * weight[i]) * acc
        for k in range(indptr[i], indptr[i + 1]):
            scatter[indices[k]] += data[k] * r
    for i in range(n):
        out_x[i] = -scatter[i] / weight[i] if free_x[i] else 0.0
        out_y[i] = -scatter[n + i] / weight[i] if free_y[i] else 0.0


@njit(cache=True)
def damping_increments(indptr, indices, data, vx, vy, scale, weight, free_x, free_y, tau, steps,
                       work, scatter, out_x, out_y):
    """The change of v_x, v_y [m/s] over ``steps`` forward-Euler sub-steps of tau [s] of
    dv/dt = ``damping_rate``: u = v, then u += tau rate(u) ``steps`` times; out = u - v.
    ``work``: scratch (4, n), ``scatter``: scratch of 2n values."""
    n = vx.shape[0]
    ux, uy, rx, ry = work[0], work[1], work[2], work[3]
    for i in range(n):
        ux[i] = vx[i]
        uy[i] = vy[i]
    for _ in range(steps):
        damping_rate(indptr, indices, data, ux, uy, scale, weight, free_x, free_y, scatter, rx,
                     ry)
        for i in range(n):
            ux[i] += tau * rx[i]
            uy[i] += tau * ry[i]
    for i in range(n):
        out_x[i] = ux[i] - vx[i]
        out_y[i] = uy[i] - vy[i]
