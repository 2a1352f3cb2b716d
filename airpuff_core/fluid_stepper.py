"""The fluid of the coupled step: the MFPM nodes' state, their operators, and the fluid's parts of
one time step (SI units; docs/model.md sections 2-5).

``FluidStepper`` holds the state at t^n (positions ``x, y`` [m], velocities ``vx, vy`` [m/s],
density ``rho`` [kg/m^3] of fixed-mass nodes) and a trial state at t^{n+1} in work arrays:

1. ``predict``, the predictor of the paper's mid-point scheme (section 3), independent of the
   coupling:
       rho^{n+1/2} = rho^n - dt/2 rho^n div^n v^n + dt HV(rho^n)
       x^{n+1/2}   = x^n + dt/2 v^n
       v^{n+1}     = v^n - dt/rho^{n+1/2} grad^{n+1/2} p^{n+1/2} + dt mu/rho^n visc^n(v^n)
                     + dt HV(v^n)
       x^{n+1}     = x^{n+1/2} + dt/2 v^{n+1}
   for the nodes that are not on the cornea; HV(f) = gamma c h^5 H f is the stabilising
   hyperviscosity, H = L^3 (L the Brookshaw Laplacian) or K^* L K (K its linearly consistent
   form) by the option ``hyperviscosity_operator`` (docs/model.md section 4), integrated by
   Runge-Kutta-Legendre super-steps; with ``hyperviscosity_interval`` N > 1, only every N-th
   step, over the time since its last application (Lie splitting with a step of N fluid
   steps), and HV = 0 in the steps between;
2. in each Dirichlet-Neumann iteration: the cornea's state imposed on the interface nodes
   (``impose_cornea``), then rho^{n+1} = rho^{n+1/2} - dt/2 rho^{n+1/2} div^{n+1} v^{n+1}
   (``new_density``) and the interface pressure of eq. (5) (``interface_pressure_change``);
3. ``commit``: the trial state becomes the state at t^{n+1} (buffers swapped, not copied).

With ``strain_limit`` > 0 (the default ``STRAIN_LIMIT``) one operator serves t^n, t^{n+1/2} and
t^{n+1}: built at reference positions, kept, and mapped to the positions of each evaluation by
the deformation since (``Operators.mapped_derivatives``, docs/model.md section 4, "Kept
operator"); the commit rebuilds it at the new state once a node's strain max |F - I| exceeds
the limit.  Its Brookshaw lists, those of the reference positions, serve the hyperviscosity.
With ``strain_limit`` 0 the operators at t^n (whose Brookshaw lists serve the hyperviscosity),
t^{n+1/2} and t^{n+1} are each built at their positions, sharing one neighbour table; those at
t^{n+1} become those at t^n at the commit.
"""

from __future__ import annotations

import numpy as np

from .divergence_damping import DivergenceDamping
from .fluid import KAPPA, NeighbourTable, Operators
from .kernels.fluid import (advance_density, advance_velocity, axisymmetric_divergence, drift,
                            impose_cornea, interface_pressure_change, max_speed, tait_pressure,
                            tait_pressure_at)
from .kernels.hyperviscosity import (hyperviscous_flow_increments, increments_work,
                                     legendre_plan)
from .kernels.nodes import AXIS, CORNEA, WALL
from .kernels.shifting import concentration_gradient, shift_displacements, shift_nodes
from .threads import chunks

VELOCITY_PARITY = np.array([-1.0, 1.0])  # v_x is odd in x, v_y even
PRESSURE_PARITY = np.array([1.0])
STRAIN_LIMIT = 0.02  # default strain_limit of ``FluidStepper`` (docs/performance.md, issue 31)
SHIFT_LIMIT = 0.05  # largest node shift per step / h (``node_shifting``, kernels/shifting.py)


class StepInterval:
    """Fires every ``interval``-th step with the time of the steps since it last fired: the
    span [s] over which an operation applied only every N-th step integrates (the steps' dt
    summed in order, so that an interval of 1 gives dt itself, exactly)."""

    def __init__(self, interval: int):
        self.interval = int(interval)
        self.steps = 0
        self.span = 0.0

    def tick(self, dt):
        """Count a step of dt [s]; its (span [s], steps) if the operation is due, else None."""
        self.steps += 1
        self.span += dt
        if self.steps < self.interval:
            return None
        due = (self.span, self.steps)
        self.steps = 0
        self.span = 0.0
        return due


class FluidStepper:
    """The fluid's state, operators and work arrays of one run; see the module docstring.

    ``reuse=False`` rebuilds every operator and every derivative in full in each coupling
    iteration, instead of only what the moving cornea changes: the same answers, slower (a check
    of the reuse).  ``strain_limit``: the largest strain max |F - I| a kept operator is mapped
    across before it is rebuilt (module docstring); 0 builds every operator at its positions.
    ``hyperviscosity_interval``: fluid steps per application of the hyperviscosity (module
    docstring; 1: every step).  ``node_shifting_interval``: steps per node shift (``commit``;
    1: every step).
    """

    def __init__(self, si, chamber, hyperviscosity_operator: str, reuse: bool = True,
                 strain_limit: float = STRAIN_LIMIT, hyperviscosity_interval: int = 1,
                 node_shifting_interval: int = 1):
        ch = chamber
        n = ch.n
        self.rho0, self.p0, self.gamma, self.mu = si.rho_fluid, si.p0_Pa, si.tait_gamma, si.mu
        self.reuse = reuse
        self.kind = ch.kind
        self.cornea_nodes = ch.cornea_nodes
        self.x = ch.x.copy()
        self.y = ch.y.copy()
        self.vx = np.zeros(n)
        self.vy = np.zeros(n)
        self.rho = np.full(n, si.rho_fluid)
        self.mass = si.rho_fluid * ch.volume  # fixed particle masses [kg]
        self.h_min = float(ch.h.min())
        self.hv_scale_unit = ch.h ** 5  # HV scale per unit gamma c
        self.neighbours = NeighbourTable(ch.h, KAPPA)
        # H = L^3 or K^* L K on each field (docs/model.md section 4)
        self.hv_consistent_density = hyperviscosity_operator == "consistent"
        self.hv_consistent_velocity = hyperviscosity_operator in ("consistent",
                                                                  "consistent_velocity")
        # the speed in the velocity's hyperviscosity in place of c (0: c itself)
        self.hv_velocity_speed = si.hyperviscosity_speed
        # the density's hyperviscosity gamma c^2/c_rho h^5 with this c_rho (0: gamma c h^5)
        self.hv_density_speed = si.hyperviscosity_density_speed
        # strain_limit > 0: one operator, built at the reference positions and mapped by the
        # deformation since (total Lagrangian form), rebuilt at the state once the largest
        # strain max |F - I| exceeds strain_limit; 0: every operator built at its positions
        self.strain_limit = strain_limit
        self.lagrangian = strain_limit > 0
        self.strain = 0.0  # largest strain of the nodes at t^n since the operator's build
        self.strain_new = 0.0  # the same at t^{n+1}
        self.operator_builds = 0  # full builds with the Brookshaw lists (the HV's operator)
        if self.lagrangian:
            self.ops_n = self.ops_half = self.ops_new = Operators(
                ch.h, ch.area, KAPPA, self.neighbours, consistent=self.hv_consistent_velocity,
                keep_operator=True)
        else:
            self.ops_n = Operators(ch.h, ch.area, KAPPA, self.neighbours,
                                   consistent=self.hv_consistent_velocity)
            self.ops_half = Operators(ch.h, ch.area, KAPPA, self.neighbours)
            self.ops_new = Operators(ch.h, ch.area, KAPPA, self.neighbours,
                                     consistent=self.hv_consistent_velocity)
        self._velocity = np.empty((2, n))  # (v_x, v_y) stacked for the MFPM kernel
        self.dv = np.zeros((2, n, 5))  # derivative vectors of v_x (dv[0]) and v_y (dv[1])
        self.div = np.zeros(n)
        self._dv_new = np.zeros((2, n, 5))
        # work arrays (allocated once): the predicted and the trial state of a step
        self.work = {k: np.empty(n) for k in ("hv_rho", "hv_vx", "hv_vy", "rho_half", "p_half",
                                              "vx_new", "vy_new", "x_new", "y_new", "rho_new",
                                              "div_new", "x_half", "y_half")}
        self._grad_p = np.zeros((1, n, 2))  # (p_x, p_y) at t^{n+1/2}
        self._hv_work = increments_work(n)
        # the rate the density's hyperviscous stages integrate with it (zero without
        # ``hyperviscosity_density_speed``)
        self._rho_source = np.zeros(n)
        self.pinned_vy = (ch.kind == WALL) | (ch.kind == CORNEA)
        self.pinned_vx = self.pinned_vy | (ch.kind == AXIS)
        self.last_hv_substeps = 0
        self.hv_interval = StepInterval(hyperviscosity_interval)
        # the velocity's divergence damped (docs/model.md section 4, issue 25)
        self.divergence_damping = (
            DivergenceDamping(si.hyperviscosity_divergence, si.hyperviscosity_divergence_speed,
                              ch.h, self.pinned_vx, self.pinned_vy)
            if si.hyperviscosity_divergence > 0 else None)
        self._div_increments = (np.empty(n), np.empty(n))
        # node shifting towards a regular cloud (``kernels/shifting.py``; 0: off)
        self.shifting = si.node_shifting
        self.shift_interval = StepInterval(node_shifting_interval)
        if self.shifting > 0:
            self.h = ch.h
            self.area = ch.area
            self._grad_c = np.zeros((n, 2))
            self._grad_c_initial = None  # grad C of the initial cloud, at the first refresh
            self._grad_rho = np.zeros((1, n, 2))
            self._shift = (np.zeros(n), np.zeros(n))

    # -- derivatives ------------------------------------------------------------------------
    def velocity_derivatives(self, ops, x, y, vx, vy, dv, div, nodes=None, laplacian=False,
                             time_ms=None):
        """dv[0] = D v_x, dv[1] = D v_y and the axisymmetric divergence ``div`` [1/s] at
        ``nodes`` (default all), with the operators of ``ops`` built at (x, y) [m]."""
        velocity = self._velocity
        velocity[0] = vx
        velocity[1] = vy
        if self.lagrangian and not laplacian:
            strain = ops.mapped_derivatives(x, y, velocity, VELOCITY_PARITY, dv, nodes, time_ms)
        else:
            ops.derivatives(x, y, velocity, VELOCITY_PARITY, dv, nodes, laplacian, time_ms)
            strain = 0.0
        if laplacian:
            self.operator_builds += 1
        axisymmetric_divergence(ops.all_nodes if nodes is None else nodes, x, vx, dv[0], dv[1],
                                div)
        return strain

    def scalar_gradient(self, ops, x, y, field, gradient, time_ms=None):
        """gradient[0] = grad ``field`` (even across the axis) at the nodes (x, y) [m], by the
        operators of ``ops`` mapped across their strain (Lagrangian reuse) or built there."""
        if self.lagrangian:
            ops.mapped_derivatives(x, y, field[np.newaxis], PRESSURE_PARITY, gradient,
                                   time_ms=time_ms)
        else:
            ops.derivatives(x, y, field[np.newaxis], PRESSURE_PARITY, gradient, time_ms=time_ms)

    def refresh_derivatives(self):
        """The operators and velocity derivatives at t^n for the current state (at the start,
        and after the state arrays were set from outside, e.g. by the stability analysis)."""
        self.velocity_derivatives(self.ops_n, self.x, self.y, self.vx, self.vy, self.dv,
                                  self.div, laplacian=True)
        self.strain = 0.0
        if self.shifting > 0 and self._grad_c_initial is None:
            self._concentration_gradient()
            self._grad_c_initial = self._grad_c.copy()

    # -- the parts of a step ----------------------------------------------------------------
    def predict(self, dt, c, t, hyperviscosity, dt_hyperviscous):
        """The mid-point density, the positions and the new velocities of the nodes off the
        cornea (into the work arrays) from the state at t [s], with the sound speed c [m/s], the
        hyperviscosity's strength gamma and its stable forward-Euler step [s]."""
        w = self.work
        self._hyperviscous_rates(dt, c, hyperviscosity, dt_hyperviscous)
        advance_density(self.rho, self.rho, self.div, 0.5 * dt, w["hv_rho"], dt, w["rho_half"])
        drift(self.x, self.y, self.vx, self.vy, 0.5 * dt, w["x_half"], w["y_half"])
        tait_pressure(w["rho_half"], self.rho0, self.p0, c, self.gamma, w["p_half"])
        self.scalar_gradient(self.ops_half, w["x_half"], w["y_half"], w["p_half"], self._grad_p,
                             time_ms=t * 1e3)
        w["vx_new"][:] = 0.0
        w["vy_new"][:] = 0.0
        advance_velocity(self.kind, self.x, self.vx, self.vy, self._grad_p[0], self.dv[0],
                         self.dv[1], w["rho_half"], self.rho, self.mu, dt, w["hv_vx"],
                         w["hv_vy"], w["vx_new"], w["vy_new"])
        drift(w["x_half"], w["y_half"], w["vx_new"], w["vy_new"], 0.5 * dt, w["x_new"], w["y_new"])

    def _hyperviscous_rates(self, dt, c, gamma, dt_hyperviscous):
        """HV(rho), HV(v_x), HV(v_y) at t^n [per s] into the work arrays.  HV is stiff: it is
        integrated over the step by Runge-Kutta-Legendre super-steps (``kernels/hyperviscosity.py``:
        K super-steps of s stages cover K (s^2 + s)/2 forward-Euler steps of
        ``dt_hyperviscous``), and its increments, divided by dt, enter the predictor as
        rates.  With ``hv_interval`` N > 1 it is integrated only at every N-th step, over the
        span of the N steps up to this one's end, and is zero in the others."""
        w = self.work
        due = self.hv_interval.tick(dt)
        if gamma <= 0 or due is None:
            w["hv_rho"][:] = 0.0
            w["hv_vx"][:] = 0.0
            w["hv_vy"][:] = 0.0
            self.last_hv_substeps = 0
            self._divergence_damping_rates(dt, c)
            return
        span = due[0]
        scale = gamma * self.density_hyperviscosity_speed(c) * self.hv_scale_unit
        supersteps, stages = legendre_plan(span / dt_hyperviscous)
        self.last_hv_substeps = supersteps * stages  # applications of the operator
        source = self._rho_source
        if self.hv_density_speed > 0:
            # the continuity equation's rate at t^n, integrated with the density's
            # hyperviscosity: their balance at any dt (docs/model.md section 4)
            np.multiply(self.rho, self.div, out=source)
            np.negative(source, out=source)
        hyperviscous_flow_increments(self.rho, self.vx, self.vy, self.pinned_vx, self.pinned_vy,
                                     *self.ops_n.hyperviscosity_args(),
                                     self.hv_consistent_density, self.hv_consistent_velocity,
                                     scale, self.velocity_hyperviscosity_factor(c), source, span,
                                     stages, supersteps, chunks(self.x.shape[0]),
                                     *self._hv_work, w["hv_rho"], w["hv_vx"], w["hv_vy"])
        w["hv_rho"] /= dt
        w["hv_vx"] /= dt
        w["hv_vy"] /= dt
        self._divergence_damping_rates(dt, c)

    def _divergence_damping_rates(self, dt, c):
        """The divergence damping's change of the velocity over dt, as rates [m/s^2], added to
        the hyperviscosity's (``divergence_damping.py``); its divergence operator is assembled
        at each build of the operator at t^n."""
        damping = self.divergence_damping
        if damping is None:
            return
        if damping.built_for != self.operator_builds:
            damping.assemble(self.ops_n, self.x, self.ops_n.adjoint_weight)
            damping.built_for = self.operator_builds
        dx, dy = self._div_increments
        damping.increments(self.vx, self.vy, c, dt, dx, dy)
        self.work["hv_vx"] += dx / dt
        self.work["hv_vy"] += dy / dt

    def density_hyperviscosity_speed(self, c):
        """The speed [m/s] in the density's hyperviscosity gamma (speed) h^5 H rho at sound speed
        c [m/s]: c^2 / c_rho with the option's c_rho (``hyperviscosity_density_speed``), c
        without it (docs/model.md section 4)."""
        return c * c / self.hv_density_speed if self.hv_density_speed > 0 else c

    def velocity_hyperviscosity_factor(self, c):
        """The velocity's hyperviscosity strength relative to the density's at sound speed c
        [m/s]: c_v (``hyperviscosity_speed``; c without it) over the density's speed
        (``density_hyperviscosity_speed``)."""
        if self.hv_density_speed > 0:
            velocity_speed = self.hv_velocity_speed if self.hv_velocity_speed > 0 else c
            return velocity_speed / self.density_hyperviscosity_speed(c) if c > 0 else 1.0
        return self.hv_velocity_speed / c if self.hv_velocity_speed > 0 and c > 0 else 1.0

    def impose_cornea(self, X, Y, VX, VY):
        """The cornea's positions [m] and velocities [m/s] on the interface nodes of the trial
        state (the Dirichlet condition)."""
        w = self.work
        impose_cornea(self.cornea_nodes, X, Y, VX, VY, w["x_new"], w["y_new"], w["vx_new"],
                      w["vy_new"])

    def trial_walls(self):
        """The trial arrays (y, vx, vy) in which a compliant globe moves the wall nodes."""
        w = self.work
        return w["y_new"], w["vx_new"], w["vy_new"]

    def new_density(self, dt, t, interface_only):
        """rho^{n+1} of the trial state into the work arrays, from the velocity derivatives at
        t^{n+1} [s]: at the cornea's nodes only if ``interface_only`` (all that the coupling
        reads; every node without ``reuse``), else at every node with the Laplacian's lists."""
        w = self.work
        if interface_only:
            self.velocity_derivatives(self.ops_new, w["x_new"], w["y_new"], w["vx_new"],
                                      w["vy_new"], self._dv_new, w["div_new"],
                                      self.cornea_nodes if self.reuse else None, time_ms=t * 1e3)
        else:  # the full fields; a fresh build keeps its Brookshaw lists for the next step
            self.strain_new = self.velocity_derivatives(
                self.ops_new, w["x_new"], w["y_new"], w["vx_new"], w["vy_new"], self._dv_new,
                w["div_new"], laplacian=not self.lagrangian, time_ms=t * 1e3)
        advance_density(w["rho_half"], w["rho_half"], w["div_new"], 0.5 * dt, w["hv_rho"], 0.0,
                        w["rho_new"])

    def interface_pressure_change(self, c, p_ref, p_est, p_new):
        """p_new = the interface pressure [Pa] of the trial density (eq. (5), sound speed c);
        returns ||p_new - p_est|| / max(||p_est - p0||, p_ref)."""
        return interface_pressure_change(self.cornea_nodes, self.work["rho_new"], self.rho0,
                                         self.p0, c, self.gamma, p_ref, p_est, p_new)

    def commit(self, dt=0.0):
        """The trial state becomes the state at t^{n+1} (buffers swapped, not copied); with
        ``node_shifting`` its nodes are then shifted (``shift``) after a step of dt [s], or with
        ``node_shifting_interval`` N > 1 after every N-th step, by the shift of the N steps'
        time together."""
        w = self.work
        self.x, w["x_new"] = w["x_new"], self.x
        self.y, w["y_new"] = w["y_new"], self.y
        self.vx, w["vx_new"] = w["vx_new"], self.vx
        self.vy, w["vy_new"] = w["vy_new"], self.vy
        self.rho, w["rho_new"] = w["rho_new"], self.rho
        self.div, w["div_new"] = w["div_new"], self.div
        self.dv, self._dv_new = self._dv_new, self.dv
        self.ops_n, self.ops_new = self.ops_new, self.ops_n
        self.strain = self.strain_new
        if self.shifting > 0 and dt > 0:
            due = self.shift_interval.tick(dt)
            if due is not None:
                self.shift(*due)
        if self.lagrangian and not self.strain <= self.strain_limit:  # also NaN
            self.refresh_derivatives()  # the operator rebuilt at the new state

    def _concentration_gradient(self):
        start, nbr, sign, count, _ = self.ops_n.laplacian_args()
        concentration_gradient(self.x, self.y, self.h, self.area, KAPPA, start, nbr, sign, count,
                               self._grad_c)

    def shift(self, dt, steps=1):
        """Node shifting after ``steps`` steps of dt [s] together (``kernels/shifting.py``): the
        nodes moved down the gradient of their concentration by A h (v_max dt) (grad C -
        grad C^0), at most ``steps`` SHIFT_LIMIT h, the density and velocities carried to the
        new positions by their gradients, and the velocity derivatives at t^n re-evaluated
        there."""
        self._concentration_gradient()
        dx, dy = self._shift
        start, nbr, _, count, _ = self.ops_n.laplacian_args()
        shift_displacements(self.x, self.kind, self.h, self._grad_c, self._grad_c_initial,
                            self.shifting * self.max_speed() * dt, SHIFT_LIMIT * steps, start, nbr,
                            count, dx, dy)
        self.scalar_gradient(self.ops_n, self.x, self.y, self.rho, self._grad_rho)
        shift_nodes(dx, dy, self.kind, self._grad_rho[0], self.dv[0], self.dv[1], self.x, self.y,
                    self.rho, self.vx, self.vy)
        if self.lagrangian:
            self.strain = self.velocity_derivatives(self.ops_n, self.x, self.y, self.vx, self.vy,
                                                    self.dv, self.div)
        else:
            self.refresh_derivatives()

    # -- quantities of the state ------------------------------------------------------------
    def max_speed(self):
        """The largest node speed [m/s]."""
        return max_speed(self.vx, self.vy)

    def interface_pressure(self, c, out):
        """The pressure [Pa] of eq. (5) with sound speed c on the cornea's nodes, into ``out``."""
        tait_pressure_at(self.cornea_nodes, self.rho, self.rho0, self.p0, c, self.gamma, out)

    def pressure(self, c, out=None):
        """The pressure field [Pa] of eq. (5) with sound speed c."""
        p = np.empty(self.rho.shape[0]) if out is None else out
        tait_pressure(self.rho, self.rho0, self.p0, c, self.gamma, p)
        return p

    def density_volume(self):
        """Chamber volume implied by the density field, sum m_j / rho_j [m^3]."""
        return float(np.sum(self.mass / self.rho))
