"""The fluid's discrete operators at one set of node positions (MFPM derivatives + Brookshaw
Laplacian).

``Operators.derivatives(x, y, fields, parity, out)`` builds every node's MFPM operator at (x, y)
and applies it to the fields in the same pass; ``Operators.laplacian_args()`` gives the Brookshaw
pair lists kept by the last full build with ``laplacian=True``.  The operators' arrays are
allocated once per run; a kernel call allocates only its scratch (two arrays of n and of the
widest candidate list), so nothing is allocated per particle.
"""

from __future__ import annotations

import numpy as np

from .errors import SimulationError
from .kernels.mfpm import hyperviscous_term, mapped_derivatives, mfpm_derivatives
from .kernels.neighbours import build_neighbours, max_squared_move
from .kernels.nodes import axis_halved_area
from .threads import chunks

KAPPA = 2.7  # MFPM support radius / local spacing (>= 2.2 keeps wall stencils well conditioned)
MAX_NEIGHBOURS = 128
COND_MAX = 1e8  # largest accepted 1-norm condition number of a scaled moment matrix
SKIN = 0.15  # neighbour lists search (1 + SKIN) times the support, and are reused until a node
# has moved by half the margin: a pair beyond the support has a Wendland weight of exactly 0, so
# the extra pairs change nothing and the operators stay exact


class NeighbourTable:
    """Verlet neighbour lists with a skin, shared by the operators at t^n, t^{n+1/2}, t^{n+1}.

    Stored flat: node i's candidates are p = start[i] ... start[i + 1] - 1, with ``nbr[p]`` and
    ``mirrored[p]`` (1 for the mirror image of node nbr[p] across the axis).
    """

    def __init__(self, h, kappa, skin=SKIN):
        """h: node spacing [m]; kappa: support radius / spacing."""
        n = h.shape[0]
        self.h = h
        self.kappa = kappa
        self.skin = skin
        self.start = np.zeros(n + 1, np.int64)
        # unsigned indices: numba then emits no negative-index wrap-around check in the pair loops
        # (docs/performance.md, "What made the difference")
        self.nbr = np.zeros(n * MAX_NEIGHBOURS, np.uint32)
        self.mirrored = np.zeros(n * MAX_NEIGHBOURS, np.int8)
        self.x_ref = None
        self.y_ref = None
        self.max_move = 0.5 * skin * kappa * float(h.min())
        self.searches = 0

    @property
    def count(self):
        """Number of candidates of each node."""
        return np.diff(self.start)

    def update(self, x, y, time_ms=None):
        """Search again if some node moved more than half the skin since the last search."""
        if self.x_ref is not None:
            move2 = max_squared_move(x, y, self.x_ref, self.y_ref)
            if move2 < self.max_move ** 2:  # False for NaN: a blown-up state is searched, and fails
                return
        status = build_neighbours(x, y, self.h, self.kappa * (1.0 + self.skin), MAX_NEIGHBOURS,
                                  self.start, self.nbr, self.mirrored)
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
    """MFPM derivatives at given positions, and the Brookshaw Laplacian of the last full build with
    ``laplacian=True``, on a shared neighbour table."""

    def __init__(self, h, area, kappa, table: NeighbourTable | None = None, consistent=False,
                 keep_operator=False):
        """h: node spacing [m], area: node area in the meridian plane [m^2], kappa: support
        radius / spacing; ``table``: a neighbour table to share (searched with the same h and
        kappa, which the operators then take from it); ``consistent``: also keep the linearly
        consistent Laplacian's coefficients with the Brookshaw lists (for the hyperviscosity
        K^* L K; they cost about a third of the build); ``keep_operator``: also keep the MFPM
        operator's pair weights with them, for ``mapped_derivatives``."""
        if table is None:
            table = NeighbourTable(h, kappa)
        elif table.kappa != kappa or table.h.shape != h.shape or not np.array_equal(table.h, h):
            raise ValueError("the shared neighbour table was made for another h or kappa")
        n = h.shape[0]
        self.table = table
        self.h = table.h
        self.kappa = table.kappa
        self.area = area
        self.inv_h = 1.0 / h
        # the Brookshaw pair lists: node i owns pairs start[i] ... start[i] + count[i] - 1 (the
        # support's pairs, in the table's order).  Sized for the fullest table; only the pages in
        # use are touched.
        self.start = np.zeros(n + 1, np.int64)
        self.count = np.zeros(n, np.int64)
        self.nbr = np.zeros(n * MAX_NEIGHBOURS, np.uint32)
        self.sign = np.zeros(n * MAX_NEIGHBOURS)  # -1.0 for a mirror image, else 1.0
        self.lap_b = np.zeros(n * MAX_NEIGHBOURS)
        self.consistent = consistent
        self.lap_c = np.zeros(n * MAX_NEIGHBOURS if consistent else 0)
        self.lap_w = np.zeros((5, n * MAX_NEIGHBOURS) if keep_operator else (0, 0))
        self.strain = np.zeros(n)  # max |F - I| of the last ``mapped_derivatives`` per node
        # the weight of the inner product in which the Brookshaw Laplacian is self-adjoint: the
        # node area, halved on the axis (an off-axis node stands for itself and its mirror
        # image, a node on the axis only for itself)
        self.adjoint_weight = area.copy()
        self.cond = np.zeros(n)  # 1-norm condition number of each node's scaled moment matrix
        self.all_nodes = np.arange(n)
        self._no_fields = np.zeros((0, n))
        self._no_out = np.zeros((0, n, 2))
        self._no_parity = np.zeros(0)
        self.has_laplacian = False

    def derivatives(self, x, y, fields, parity, out, nodes=None, laplacian=False, time_ms=None):
        """out[f, i, :] = (f_x, f_y, f_xx, f_xy, f_yy) of fields[f] at node i, or (f_x, f_y) when
        ``out`` has 2 columns, with every node's operator built at the positions (x, y) [m].

        fields: (n_fields, n) array; parity: +1 for a field even in x (density, pressure, v_y),
        -1 for an odd one (v_x); out: (n_fields, n, 5 or 2).  ``nodes``: only these nodes (the
        others' rows of ``out`` are left as they are).  ``laplacian=True`` (all nodes only) also
        keeps the Brookshaw pair lists for ``laplacian_args``.  The neighbour table is updated
        first.  An ill-conditioned or singular moment matrix raises ``SimulationError``.
        """
        self._check_shapes(x, y, fields, parity, out)
        t = self.table
        t.update(x, y, time_ms)
        if nodes is None:
            nodes = self.all_nodes
        elif laplacian:
            raise ValueError("laplacian=True needs every node")
        if laplacian:
            self.start[:] = t.start
        status = mfpm_derivatives(x, y, self.h, self.inv_h, self.area, self.kappa, t.start, t.nbr,
                                  t.mirrored, nodes, fields, parity, COND_MAX, out, self.cond,
                                  self.count, self.nbr, self.sign, self.lap_b,
                                  self.lap_c, self.lap_w, laplacian,
                                  laplacian and self.consistent,
                                  chunks(nodes.shape[0]))
        if laplacian:
            self.has_laplacian = True
            axis_halved_area(x, self.area, self.adjoint_weight)
        if status:
            i = status - 1
            raise SimulationError(
                f"MFPM moment matrix of node {i} is ill-conditioned (condition {self.cond[i]:.3g} "
                f"> {COND_MAX:.0e}, {t.start[i + 1] - t.start[i]} candidate neighbours)"
                + (f" at t = {time_ms:.4f} ms" if time_ms is not None else ""), time_ms,
                "conditioning")
        return out

    def _check_shapes(self, x, y, fields, parity, out):
        """The kernels do not check bounds: a wrong shape would read or write out of range."""
        n = self.h.shape[0]
        n_fields = fields.shape[0]
        if (fields.ndim != 2 or fields.shape[1] != n or parity.shape != (n_fields,)
                or out.ndim != 3 or out.shape[:2] != (n_fields, n) or out.shape[2] not in (2, 5)
                or x.shape != (n,) or y.shape != (n,)):
            raise ValueError(f"shapes: x, y ({n},), fields (n_fields, {n}), parity (n_fields,), "
                             f"out (n_fields, {n}, 2 or 5); got x {x.shape}, y {y.shape}, fields "
                             f"{fields.shape}, parity {parity.shape}, out {out.shape}")

    def mapped_derivatives(self, x, y, fields, parity, out, nodes=None, time_ms=None):
        """As ``derivatives``, at the positions (x, y) [m], from the operator of the last full
        build with ``laplacian=True`` (made with ``keep_operator``) mapped by the deformation
        since (``kernels.mfpm.mapped_derivatives``): no build, no neighbour search.  Returns the
        largest strain max |F - I| over ``nodes``; a deformation gradient that is not
        invertible (the nodes tangled since the build) raises ``SimulationError``."""
        if not self.has_laplacian or self.lap_w.shape[0] != 5:
            raise RuntimeError("no operator kept: build with keep_operator and laplacian=True")
        self._check_shapes(x, y, fields, parity, out)
        if nodes is None:
            nodes = self.all_nodes
        status = mapped_derivatives(x, y, nodes, fields, parity, self.start, self.nbr, self.sign,
                                    self.count, self.lap_w, out, self.strain,
                                    chunks(nodes.shape[0]))
        if status:
            raise SimulationError(
                "fluid blew up" + (f" at t = {time_ms:.4f} ms" if time_ms is not None else "")
                + f": node {status - 1} tangled (its deformation gradient since the last "
                f"operator build is not invertible)", time_ms, "blow-up")
        return float(self.strain[nodes].max())

    def build(self, x, y, time_ms=None):
        """The operators at (x, y) [m] with no field: the Brookshaw pair lists and ``cond``."""
        self.derivatives(x, y, self._no_fields, self._no_parity, self._no_out, laplacian=True,
                         time_ms=time_ms)
        return self

    def laplacian_args(self):
        """(start, nbr, sign, count, lap_b) for the Brookshaw-Laplacian kernels; start and count
        as unsigned views (no copy), so that Numba emits no negative-index check on the pair
        index in the kernels' loops (docs/performance.md)."""
        if not self.has_laplacian:
            raise RuntimeError("no Brookshaw pair lists: build with laplacian=True first")
        return (self.start.view(np.uint64), self.nbr, self.sign, self.count.view(np.uint64),
                self.lap_b)

    def hyperviscosity_args(self):
        """(start, nbr, sign, count, lap_b, lap_c, weight) for the hyperviscosity kernels
        (``hyperviscous_term``, ``hyperviscous_flow_operator``)."""
        return (*self.laplacian_args(), self.lap_c, self.adjoint_weight)

    def hyperviscous(self, f, parity, scale, work1, work2, out, consistent=False):
        """out = scale * H f, the hyperviscous term with H = L^3, or K^* L K if ``consistent``
        (``kernels.mfpm.hyperviscous_term``)."""
        if consistent and not self.consistent:
            raise ValueError("K^* L K needs operators built with consistent=True")
        hyperviscous_term(f, parity, *self.hyperviscosity_args(), consistent, scale, work1, work2,
                          out)
        return out

    def hyperviscous_spectral_radius(self, scale, start=None, iterations=60, consistent=False):
        """Largest |eigenvalue| of f -> scale * H f (H = L^3, or K^* L K if ``consistent``) by
        power iteration, and its eigenvector.

        Either operator is self-adjoint and negative semi-definite in the area-weighted inner
        product (real non-positive eigenvalues), so this converges to the stiffest grid mode.  Nodes
        that the flow pushes together raise it, so the solver re-runs a few iterations every step
        from the previous eigenvector (``start``).
        """
        if start is None:
            start = np.random.default_rng(0).standard_normal(self.h.shape[0])
        f = start / np.linalg.norm(start)
        w1, w2, out = np.empty_like(f), np.empty_like(f), np.empty_like(f)
        lam = 0.0
        for _ in range(iterations):
            self.hyperviscous(f, 1.0, scale, w1, w2, out, consistent)
            lam = np.linalg.norm(out)
            f = out / lam
        return lam, f
