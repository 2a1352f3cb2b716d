"""Linear stability of the coupled discrete system about the rest state (docs/model.md section 4).

The step map S: (rho, v_fluid, X_cornea, V_cornea)^n -> (...)^{n+1} is linearised about rest by
central differences (the coupling iterated to round-off, dt and c held fixed), and the eigenvalues
mu of its Jacobian are computed.  A mode grows when |mu| > 1; its growth rate is ln|mu| / dt [1/s].
Fluid positions are left out: at rest they enter only through the operators acting on uniform
fields, which vanish, so they form neutral (Jordan) directions and cannot cause exponential growth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .kernels.nodes import AXIS, INTERIOR
from .params import RunParams
from .coupling import CoupledModel
from .step_control import StepControl


@dataclass
class StabilityReport:
    eigenvalues: np.ndarray  # of the one-step Jacobian
    dt: float  # s
    n_dof: int

    @property
    def growth_rates(self) -> np.ndarray:
        """ln|mu| / dt [1/s] of every mode, largest first."""
        return np.sort(np.log(np.abs(self.eigenvalues)) / self.dt)[::-1]

    @property
    def max_growth_rate(self) -> float:
        return float(self.growth_rates[0])


def _dofs(model: CoupledModel):
    kind = model.fluid.kind
    moving = np.flatnonzero(kind == INTERIOR)
    moving_y = np.flatnonzero((kind == INTERIOR) | (kind == AXIS))
    ncor = model.X.shape[0]
    free_x = np.arange(1, ncor - 1)  # apex x is fixed on the axis, the limbus is fixed
    free_y = np.arange(0, ncor - 1)
    return [("rho", np.arange(model.chamber.n)), ("vx", moving), ("vy", moving_y),
            ("X", free_x), ("Y", free_y), ("VX", free_x), ("VY", free_y)]


def _pack(model, dofs):
    return np.concatenate([getattr(model, name)[idx] for name, idx in dofs])


def linearised_step(params: RunParams, dt: float | None = None, eps_rho=1e-6, eps_v=1e-6,
                    eps_x=1e-9, positions=None, patch=None) -> StabilityReport:
    """Eigenvalues of the linearised one-step map about rest, with pmax forced to 0.

    ``positions``: (x, y) [m] of every fluid node; the interior and axis nodes are moved there
    (a cloud that a run's flow has distorted), the operators and the hyperviscosity's stability
    limit built for it; the state stays at rest (uniform density, no velocity), which remains
    an equilibrium.  The cornea and the walls stay at rest, so the cloud must be of a state near
    rest (after the puff): nodes of a cloud beside a deformed cornea tangle.  ``patch``: indices of fluid nodes; only their density and velocity are
    perturbed and read (every other DOF, the cornea's included, held at rest): the step map of
    a patch, for a mode that lives on a few nodes."""
    params = params.replace(pmax=0.0, c_rule="fixed", coupling_tol=1e-9,
                            max_coupling_iterations=200)
    model = CoupledModel(params)
    if positions is not None:
        free = (model.fluid.kind == INTERIOR) | (model.fluid.kind == AXIS)
        model.x[free] = positions[0][free]
        model.y[free] = positions[1][free]
        model.refresh_derivatives()
        model.control = StepControl(model.si, params.c_rule, model.fluid)
    if dt is None:
        dt = model.control.time_step()
    dofs = _dofs(model)
    if patch is not None:
        dofs = [(name, np.intersect1d(idx, patch)) for name, idx in dofs
                if name in ("rho", "vx", "vy")]
    base = {name: getattr(model, name).copy() for name in ("x", "y", "vx", "vy", "rho", "X", "Y",
                                                          "VX", "VY")}
    scale = {"rho": eps_rho * model.si.rho_fluid, "vx": eps_v, "vy": eps_v, "X": eps_x, "Y": eps_x,
             "VX": eps_v, "VY": eps_v}

    def run(name, i, delta):
        for k, v in base.items():
            setattr(model, k, v.copy())
        if name is not None:
            arr = getattr(model, name)
            arr[i] += delta
            if name in ("X", "Y", "VX", "VY"):
                # the fluid interface nodes carry the cornea's position and velocity
                fl = {"X": "x", "Y": "y", "VX": "vx", "VY": "vy"}[name]
                getattr(model, fl)[model.cornea_nodes[i]] = arr[i]
        model.t = 0.0
        model.refresh_derivatives()
        model.step(dt=dt)
        return _pack(model, dofs)

    n = sum(len(idx) for _, idx in dofs)
    J = np.empty((n, n))
    col = 0
    for name, idx in dofs:
        for i in idx:
            d = scale[name]
            J[:, col] = (run(name, i, d) - run(name, i, -d)) / (2 * d)
            col += 1
    # rescale to make the columns and rows comparable (a similarity transform: same eigenvalues)
    s = np.concatenate([np.full(len(idx), scale[name]) for name, idx in dofs])
    J = J * s[None, :] / s[:, None]
    return StabilityReport(np.linalg.eigvals(J), dt, n)


def viscous_operator(params: RunParams, component: str) -> tuple[np.ndarray, float]:
    """The discrete viscous operator of the momentum equation at the rest state, as a matrix.

    Row i, column j: the viscous term of ``component`` ('vx' or 'vy') at node i for a unit
    velocity at node j [1/m^2], over the nodes that integrate that component (v_x: INTERIOR;
    v_y: INTERIOR and AXIS; the others carry Dirichlet values, zero here):

        v_x: f_xx + f_yy + f_x/x - f/x^2,   v_y: f_xx + f_yy + f_x/x  (2 f_xx + f_yy on the axis),

    with the MFPM derivatives of the solver (mirror images across the axis included).  Returns
    the matrix and the smallest node spacing h_min [m].
    """
    model = CoupledModel(params)
    kind = model.fluid.kind
    if component == "vx":
        nodes, parity = np.flatnonzero(kind == INTERIOR), -1.0
    elif component == "vy":
        nodes, parity = np.flatnonzero((kind == INTERIOR) | (kind == AXIS)), 1.0
    else:
        raise ValueError("component must be 'vx' or 'vy'")
    n = model.chamber.n
    M = np.empty((nodes.size, nodes.size))
    x = model.x
    on_axis = kind[nodes] == AXIS
    xi = np.where(on_axis, 1.0, x[nodes])
    chunk = 256
    for c0 in range(0, nodes.size, chunk):
        cols = nodes[c0:c0 + chunk]
        fields = np.zeros((cols.size, n))
        fields[np.arange(cols.size), cols] = 1.0
        out = np.zeros((cols.size, n, 5))
        model.fluid.ops_n.derivatives(x, model.y, fields, np.full(cols.size, parity), out)
        d = out[:, nodes, :]  # (column, row node, derivative)
        lap = d[..., 2] + d[..., 4] + d[..., 0] / xi
        lap = np.where(on_axis, 2.0 * d[..., 2] + d[..., 4], lap)
        if component == "vx":
            lap -= fields[:, nodes] / xi ** 2
        M[:, c0:c0 + cols.size] = lap.T
    return M, model.fluid.h_min


def forward_euler_viscous_limit(M: np.ndarray, h_min: float) -> tuple[float, int]:
    """The forward-Euler stability limit of dv/dt = nu M v, as C = nu dt_max / h_min^2.

    |1 + nu dt lambda| <= 1 for every eigenvalue lambda = a + ib of M (a < 0) means
    nu dt <= -2 a / |lambda|^2.  Returns C and the number of eigenvalues with a >= 0 (a mode that
    forward Euler cannot damp at any step; expected 0).
    """
    lam = np.linalg.eigvals(M)
    damped = lam.real < 0
    limit = float(np.min(-2.0 * lam.real[damped] / np.abs(lam[damped]) ** 2))
    return limit / h_min ** 2, int(np.count_nonzero(~damped))


def acoustic_self_coupling(model: CoupledModel) -> np.ndarray:
    """The diagonal of D G [1/m^2] at every fluid node, for the operator of ``model`` at its last
    build: the linearised acoustics d^2 rho/dt^2 = c^2 D G rho (D the solver's axisymmetric
    divergence, ``divergence_damping.py``; G its pressure gradient on the velocity components
    that are not Dirichlet values).  On a regular cloud every entry is negative (a density
    excess at a node pushes fluid away from it); a positive entry is a node whose neighbourhood
    the flow has distorted so that its own excess draws fluid in: a mode living on that node
    then grows like exp(c sqrt((D G)_ii) t) unless damped on both fields (docs/model.md
    section 4)."""
    from .divergence_damping import DivergenceDamping
    import scipy.sparse as sp

    fluid = model.fluid
    ops = fluid.ops_n
    n = model.chamber.n
    divergence = DivergenceDamping(1.0, 0.0, model.chamber.h, fluid.pinned_vx, fluid.pinned_vy)
    divergence.assemble(ops, fluid.x, ops.adjoint_weight)
    start, nbr, count, weights = ops.start, ops.nbr, ops.count, ops.lap_w
    rows = np.repeat(np.arange(n), count)
    pairs = (np.concatenate([np.arange(start[i], start[i] + count[i]) for i in range(n)])
             if n else np.zeros(0, np.int64))
    cols = nbr[pairs].astype(np.int64)
    nodes = np.arange(n)

    def gradient(component, free):  # pressure is even across the axis: no sign for images
        w = weights[component, pairs]
        g = sp.csr_matrix((np.concatenate([w, -np.bincount(rows, w, n)]),
                           (np.concatenate([rows, nodes]), np.concatenate([cols, nodes]))),
                          shape=(n, n))
        return sp.diags(free.astype(float)) @ g

    G = sp.vstack([gradient(0, divergence.free_x), gradient(1, divergence.free_y)])
    return (divergence.D @ G).diagonal()
