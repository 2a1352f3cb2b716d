"""Cell-list neighbour search in the meridian half-plane, with mirror images across the axis.

Node i sees node j when |x_i - x_j| < kappa * max(h_i, h_j) (a symmetric criterion, so the pair
sets of i and j agree).  Nodes near the symmetry axis also see the mirror images (-x_j, y_j) of
nodes off the axis: the axisymmetric fields are even (density, pressure, v_y) or odd (v_x) in x,
so a mirror image carries the node's value times the field's parity.  This makes the axis an
interior line for the MFPM operators instead of a one-sided boundary.

Output is a flat table: node i's neighbours are p = start[i] ... start[i + 1] - 1, with
``nbr[p]`` (neighbour index) and ``mirrored[p]`` (1 for an image), at most ``max_neighbours`` per
node.  The search is O(n) (counting sort into square cells of side
kappa * max h).  The same cell sort serves ``nearest_node_sums``, which gives each node the area
and volume of the part of the chamber nearest to it.
"""

import numpy as np
from numba import njit

from .nodes import AXIS_EPS


@njit(cache=True)
def sort_into_cells(x, y, xmin, ymin, cell, ncx, ncy):
    """Counting sort of the nodes into square cells of side ``cell`` [m] on an ncx x ncy grid
    whose corner is (xmin, ymin); cell c = cx * ncy + cy.  Returns (cell_start, order): the nodes
    of cell c are order[cell_start[c]] ... order[cell_start[c + 1] - 1], in increasing index."""
    n = x.shape[0]
    cell_start = np.zeros(ncx * ncy + 1, dtype=np.int64)
    cell_of = np.empty(n, dtype=np.int64)
    for i in range(n):
        cx = min(int((x[i] - xmin) / cell), ncx - 1)
        cy = min(int((y[i] - ymin) / cell), ncy - 1)
        c = cx * ncy + cy
        cell_of[i] = c
        cell_start[c + 1] += 1
    for c in range(ncx * ncy):
        cell_start[c + 1] += cell_start[c]
    fill = cell_start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = cell_of[i]
        order[fill[c]] = i
        fill[c] += 1
    return cell_start, order


@njit(cache=True)
def build_neighbours(x, y, h, kappa, max_neighbours, start, nbr, mirrored):
    """Fill the neighbour table.  Returns 0, i+1 for the first node whose table overflows, or -1
    when a position is not finite (a blown-up state must not index cells out of range)."""
    n = x.shape[0]
    for i in range(n):
        if not (np.isfinite(x[i]) and np.isfinite(y[i])):
            return -1
    hmax = 0.0
    xmin = x[0]
    xmax = x[0]
    ymin = y[0]
    ymax = y[0]
    for i in range(n):
        hmax = max(hmax, h[i])
        xmin = min(xmin, x[i])
        xmax = max(xmax, x[i])
        ymin = min(ymin, y[i])
        ymax = max(ymax, y[i])
    cell = kappa * hmax
    ncx = int((xmax - xmin) / cell) + 1
    ncy = int((ymax - ymin) / cell) + 1
    cell_start, order = sort_into_cells(x, y, xmin, ymin, cell, ncx, ncy)

    status = 0
    p0 = 0
    for i in range(n):
        start[i] = p0
        k = 0
        for image in range(2):
            if image == 1:
                qx = -x[i]
                if x[i] - kappa * hmax > 0.0:
                    break  # too far from the axis to see any image
            else:
                qx = x[i]
            qy = y[i]
            cx = int(np.floor((qx - xmin) / cell))
            cy = int(np.floor((qy - ymin) / cell))
            for ix in range(max(cx - 1, 0), min(cx + 2, ncx)):
                for iy in range(max(cy - 1, 0), min(cy + 2, ncy)):
                    c = ix * ncy + iy
                    for s in range(cell_start[c], cell_start[c + 1]):
                        j = order[s]
                        if image == 0 and j == i:
                            continue
                        if image == 1 and x[j] < AXIS_EPS:
                            continue  # an axis node is its own image
                        dx = x[j] - qx
                        dy = y[j] - qy
                        r2 = dx * dx + dy * dy
                        hij = kappa * max(h[i], h[j])
                        if r2 < hij * hij:
                            if k >= max_neighbours:
                                if status == 0:
                                    status = i + 1
                                continue
                            nbr[p0 + k] = j
                            mirrored[p0 + k] = image
                            k += 1
        p0 += k
    start[n] = p0
    return status


@njit(cache=True)
def max_squared_move(x, y, x_ref, y_ref):
    """max_i |x_i - x_ref_i|^2 [m^2]; NaN if a position is not finite."""
    m = 0.0
    for i in range(x.shape[0]):
        d2 = (x[i] - x_ref[i]) ** 2 + (y[i] - y_ref[i]) ** 2
        if not d2 <= m:  # also catches NaN, which must trigger a search (and its error)
            if np.isnan(d2):
                return np.nan
            m = d2
    return m


@njit(cache=True)
def nearest_node_sums(x, y, sx, sy, cell, area_out, vol_out, dA):
    """Assign each sample point (sx, sy) [m] to its nearest node and
    add dA [m^2] to that node's ``area_out`` and 2 pi sx dA [m^3] to its ``vol_out``.

    ``cell`` [m] must be at least the largest distance from a sample to its nearest node (the
    search looks two cells around the sample's cell)."""
    xmin = x.min() - cell
    ymin = y.min() - cell
    ncx = int((x.max() - xmin) / cell) + 2
    ncy = int((y.max() - ymin) / cell) + 2
    start, order = sort_into_cells(x, y, xmin, ymin, cell, ncx, ncy)
    for s in range(sx.shape[0]):
        cx = int((sx[s] - xmin) / cell)
        cy = int((sy[s] - ymin) / cell)
        best = -1
        bd = 1e300
        for ix in range(max(cx - 2, 0), min(cx + 3, ncx)):
            for iy in range(max(cy - 2, 0), min(cy + 3, ncy)):
                c = ix * ncy + iy
                for t in range(start[c], start[c + 1]):
                    j = order[t]
                    d = (x[j] - sx[s]) ** 2 + (y[j] - sy[s]) ** 2
                    if d < bd:
                        bd = d
                        best = j
        if best >= 0:
            area_out[best] += dA
            vol_out[best] += 2.0 * np.pi * sx[s] * dA
