"""The fluid's discrete operators at one set of node positions (MFPM weights + Brookshaw Laplacian).

``Operators.build(x, y)`` runs the cell-list search and factors every node's moment matrix once;
the derivative of any field is then a dot product with stored weights.  Arrays are allocated once
per run and reused, so a time step allocates nothing per particle.
"""

from __future__ import annotations

import numpy as np

from .errors import SimulationError
from .kernels.mfpm import compute_weights, hyperviscous_term, near_nodes
from .kernels.neighbours import build_neighbours, max_squared_move

MAX_NEIGHBOURS = 128
COND_MAX = 1e8  # largest accepted 1-norm condition number of a scaled moment matrix
SKIN = 0.15  # neighbour lists search (1 + SKIN) times the support, and are reused until a node
# has moved by half the margin: a pair beyond the support has a Wendland weight of exactly 0, so
# the extra pairs change nothing and the operators stay exact


class NeighbourTable:
    """Verlet neighbour lists with a skin, shared by the operators at t^n, t^{n+1/2}, t^{n+1}."""

    def __init__(self, h, kappa, skin=SKIN):
        n = h.shape[0]
        self.h = h
        self.kappa = kappa
        self.skin = skin
        # unsigned indices: numba then emits no negative-index wrap-around check in the pair loops
        # (about 30 % faster, measured)
        self.nbr = np.zeros((n, MAX_NEIGHBOURS), np.uint32)
        self.mirrored = np.zeros((n, MAX_NEIGHBOURS), np.int8)
        self.count = np.zeros(n, np.int64)
        self.x_ref = None
        self.y_ref = None
        self.max_move = 0.5 * skin * kappa * float(h.min())
        self.searches = 0

    def update(self, x, y, time_ms=None):
        """Search again if some node moved more than half the skin since the last search."""
        if self.x_ref is not None:
            move2 = max_squared_move(x, y, self.x_ref, self.y_ref)
            if move2 < self.max_move ** 2:  # False for NaN: a blown-up state is searched, and fails
                return
        status = build_neighbours(x, y, self.h, self.kappa * (1.0 + self.skin), self.nbr,
                                  self.mirrored, self.count)
        if status < 0:
            raise SimulationError(
                "fluid blew up: node positions are not finite"
                + (f" at t = {time_ms:.4f} ms" if time_ms is not None else ""), time_ms, "blow-up")
        if status:
            raise SimulationError(
                f"node {status - 1} has more than {MAX_NEIGHBOURS} neighbours"
                + (f" at t = {time_ms:.4f} ms" if time_ms is not None else ""), time_ms,
                "neighbours")
        if self.x_ref is None:
            self.x_ref = x.copy()
            self.y_ref = y.copy()
        else:
            self.x_ref[:] = x
            self.y_ref[:] = y
        self.searches += 1


class Operators:
    """MFPM weights and Brookshaw coefficients for one configuration, on a shared neighbour table."""

    def __init__(self, h, area, kappa, table: NeighbourTable | None = None, rows: int = 5):
        """``rows``: 5 for every derivative (f_x, f_y, f_xx, f_xy, f_yy), 2 for an operator that
        serves gradients only (``kernels.mfpm.derivatives`` into two columns): it skips the
        other three rows."""
        n = h.shape[0]
        self.h = h
        self.area = area
        self.kappa = kappa
        self.table = table if table is not None else NeighbourTable(h, kappa)
        # this configuration's own pairs (those of the table inside the support), stored flat:
        # node i owns pairs start[i] ... start[i] + count[i] - 1.  The arrays are sized for the
        # fullest table; only the pages in use are touched.
        self.start = np.zeros(n + 1, np.int64)
        self.count = np.zeros(n, np.int64)
        self.nbr = np.zeros(n * MAX_NEIGHBOURS, np.uint32)
        self.mirrored = np.zeros(n * MAX_NEIGHBOURS, np.int8)
        self.weights = np.zeros((rows, n * MAX_NEIGHBOURS))  # one row per derivative
        self.lap_b = np.zeros(n * MAX_NEIGHBOURS)
        self.cond = np.zeros(n)
        self.all_nodes = np.arange(n)
        self._table_search = -1  # the table search the pair layout was made for

    def build(self, x, y, time_ms=None, active=None):
        """Factor the moment matrices at positions (x, y) [m] (updating the neighbour table first).

        With ``active`` (node indices) only those nodes' weights are recomputed: used within one
        time step, when only the cornea has moved.  If the neighbour table was searched again since
        the last full build, every node is rebuilt.
        """
        t = self.table
        t.update(x, y, time_ms)
        if t.searches != self._table_search:
            active = None
            np.cumsum(t.count, out=self.start[1:])
            self._table_search = t.searches
        if active is None:
            active = self.all_nodes
        status = compute_weights(x, y, self.h, self.area, self.kappa, t.nbr, t.mirrored, t.count,
                                 COND_MAX, active, self.start, self.nbr, self.mirrored, self.count,
                                 self.weights, self.lap_b, self.cond)
        if status:
            i = status - 1
            raise SimulationError(
                f"MFPM moment matrix of node {i} is ill-conditioned (condition {self.cond[i]:.3g} "
                f"> {COND_MAX:.0e}, {self.count[i]} neighbours)"
                + (f" at t = {time_ms:.4f} ms" if time_ms is not None else ""), time_ms, "conditioning")
        return self

    def nodes_near(self, targets_mask):
        """Indices of the nodes that are in ``targets_mask`` or have a neighbour in it.

        Searched in the neighbour table, whose skin adds a margin: a node just outside the support
        whose weights a small move of the targets would change is included.
        """
        return near_nodes(targets_mask, self.table.nbr, self.table.count)

    def args(self):
        """(start, nbr, mirrored, count, weights) for the derivative kernels."""
        return self.start, self.nbr, self.mirrored, self.count, self.weights

    def laplacian_args(self):
        """(start, nbr, mirrored, count, lap_b) for the Brookshaw-Laplacian kernels."""
        return self.start, self.nbr, self.mirrored, self.count, self.lap_b

    def hyperviscous(self, f, parity, scale, work1, work2, out):
        hyperviscous_term(f, parity, *self.laplacian_args(), scale, work1, work2, out)
        return out

    def hyperviscous_spectral_radius(self, scale, start=None, iterations=60):
        """Largest |eigenvalue| of f -> scale * L^3 f by power iteration, and its eigenvector.

        L has real non-positive eigenvalues, so this converges to the stiffest grid mode.  Nodes
        that the flow pushes together raise it, so the solver re-runs a few iterations every step
        from the previous eigenvector (``start``).
        """
        if start is None:
            start = np.random.default_rng(0).standard_normal(self.h.shape[0])
        f = start / np.linalg.norm(start)
        w1, w2, out = np.empty_like(f), np.empty_like(f), np.empty_like(f)
        lam = 0.0
        for _ in range(iterations):
            self.hyperviscous(f, 1.0, scale, w1, w2, out)
            lam = np.linalg.norm(out)
            f = out / lam
        return lam, f
