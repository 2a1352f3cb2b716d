"""One coupled time step: cornea (membrane or shell) + MFPM fluid, Dirichlet-Neumann iterations.

``CoupledModel`` holds the state of one run (SI units) and advances it from t^n to
t^{n+1} = t^n + dt in three parts, each a method:

1. ``predict_fluid``, the fluid predictor (the paper's mid-point scheme, section 3), independent
   of the coupling:
       rho^{n+1/2} = rho^n - dt/2 rho^n div^n v^n + dt HV(rho^n)
       x^{n+1/2}   = x^n + dt/2 v^n
       v^{n+1}     = v^n - dt/rho^{n+1/2} grad^{n+1/2} p^{n+1/2} + dt mu/rho^n visc^n(v^n)
                     + dt HV(v^n)
       x^{n+1}     = x^{n+1/2} + dt/2 v^{n+1}
   for the nodes that are not on the cornea; HV(f) = gamma c h^5 H f is the stabilising
   hyperviscosity, H = L^3 (L the Brookshaw Laplacian; the default) or K^* L K (K its linearly
   consistent form) by the option ``hyperviscosity_operator`` (docs/model.md section 4).
2. ``couple``, the Dirichlet-Neumann iterations k = 1, 2, ... (docs/model.md section 5):
   (a) advance the cornea from its state at t^n with the interface pressure interpolated from
       p^n to the current estimate p^k (plus the jet), by Verlet sub-steps;
   (b) impose the cornea's position and velocity on the fluid interface nodes (Dirichlet);
   (c) rho^{n+1} = rho^{n+1/2} - dt/2 rho^{n+1/2} div^{n+1} v^{n+1}, p^{n+1} from eq. (5);
       the new interface pressure is the cornea's load (Neumann);
   until ||p^{k} - p^{k-1}|| / max(||p^{k-1} - p0||, p_ref) < coupling_tol, with k >= 2.
3. ``commit``: the converged state becomes the state at t^{n+1}; a blown-up state is an error.
"""

from __future__ import annotations

import math

import numpy as np

from .energy import EnergyBudget
from .errors import SimulationError
from .fluid import KAPPA, NeighbourTable, Operators
from .geometry import build_chamber, chamber_volume
from .globe import CompliantWall, enclosed_volume_rate, wall_weights
from .kernels.energy import jet_pressures
from .kernels.fluid import (advance_density, advance_velocity, axisymmetric_divergence, drift,
                            impose_cornea, interface_pressure_change, max_density_deviation,
                            max_speed, tait_pressure, tait_pressure_at)
from .kernels.membrane import add_pressure_loads, cornea_polygon_volume
from .kernels.hyperviscosity import (hyperviscous_flow_increments, increments_work,
                                     legendre_plan)
from .kernels.nodes import AXIS, CORNEA, WALL
from .membrane import apex_curvature, apex_fit_nodes, static_equilibrium
from .params import RunParams
from .shell import shell_for_run
from .threads import chunks
from .viscoelastic import ViscoelasticHistory

# forward-Euler step of the HV <= HV_SAFETY / (spectral radius of the HV operator); FE limit 2,
# unstable at 2.0 (measured).  The Runge-Kutta-Legendre stages keep the same margin.
HV_SAFETY = 1.4
HV_POWER_ITERATIONS = 2  # power iterations per refresh, warm-started (the mode changes slowly)
HV_REFRESH_STEPS = 4  # steps between refreshes (nodes move < 1 % of a spacing in between)
HV_MARGIN = 1.1  # a warm-started power iteration may underestimate the radius slightly
# dt <= VISCOUS_SAFETY rho h_min^2 / mu: the viscous term is forward Euler in the mid-point scheme.
# Its measured limit on the MFPM operator (eigenvalues of the axisymmetric viscous matrix,
# ``stability.forward_euler_viscous_limit``) is 0.547 (v_x) / 0.579 (v_y) at coarse and paper
# resolution.  0.2 keeps a margin of 2.7 for nodes that the flow pushes together (nearest-neighbour
# spacing down to 0.69 h), and keeps the time error small where the limit sets the step: halving
# the step at mu = 2.5 Pa s moves CH by 0.011 mmHg (0.042 with the consistent hyperviscosity;
# docs/model.md section 4).
VISCOUS_SAFETY = 0.2
P_REF = 1.0  # Pa: floor of the normalisation of the coupling residual (meaningful at rest)
BLOWUP_SPEED = 50.0  # m/s: a fluid speed above this is a blow-up (physical speeds ~0.2-1 m/s)
BLOWUP_DENSITY = 0.2  # relative density change beyond which the run is declared blown up
VELOCITY_PARITY = np.array([-1.0, 1.0])  # v_x is odd in x, v_y even
PRESSURE_PARITY = np.array([1.0])


def sound_speed(rule, c0, c_slope, v_prev, v_running):
    """Artificial sound speed [m/s]: c = c0 + c_slope v_max (docs/model.md section 4,
    ``c_rule``)."""
    if rule == "fixed":
        return c0
    if rule == "per_step":
        return c0 + c_slope * v_prev
    return c0 + c_slope * v_running


class CoupledModel:
    """State and operators of one run; ``step()`` advances by one coupled time step.

    The state, SI units: fluid nodes ``x, y`` [m], ``vx, vy`` [m/s], ``rho`` [kg/m^3] (the nodes
    ``cornea_nodes`` lie on the cornea, apex first); cornea nodes ``X, Y`` [m], ``VX, VY`` [m/s];
    time ``t`` [s].  ``cornea_model`` is the cornea's mechanics: ``substeps(X, Y, dt)`` and
    ``advance(X, Y, VX, VY, p_start, p_end, t, dt, n_sub, jet)`` in the coupling, and its static
    equilibrium at the start (``membrane.py``).  It is a ``ShellModel`` (``shell.py``) for both
    corneas: the paper's membrane is the shell with bending rigidity 0, bit for bit.

    ``reuse=False`` rebuilds every operator and every derivative in full in each coupling
    iteration, instead of only what the moving cornea changes: the same answers, slower (a check
    of the reuse).
    """

    def __init__(self, params: RunParams, reuse: bool = True):
        self.params = params
        self.reuse = reuse
        si = self.si = params.si()
        ch = self.chamber = build_chamber(params.geometry, params.layout, params.resolution,
                                          si.R_m, si.r_post_m, si.alpha0_rad)
        # the cornea's mechanics (``substeps``, ``advance``, static equilibrium)
        self.cornea_model = shell_for_run(params, ch.phi_cornea)
        self.jet = si.jet()
        n = ch.n
        self.kind = ch.kind
        self.cornea_nodes = ch.cornea_nodes
        self.x = ch.x.copy()
        self.y = ch.y.copy()
        self.vx = np.zeros(n)
        self.vy = np.zeros(n)
        self.rho = np.full(n, si.rho_fluid)
        self.mass = si.rho_fluid * ch.volume  # fixed particle masses [kg]
        self._start_cornea_at_rest()
        self._build_globe()
        # the cornea starts fully relaxed (E0 is the equilibrium modulus, docs/model.md section 10)
        self.viscoelastic = (ViscoelasticHistory(self.cornea_model, [si.ve_g], [si.ve_tau_s],
                                                 self.X, self.Y) if si.ve_g > 0.0 else None)
        self.t = 0.0
        self.v_prev = 0.0
        self.v_running = 0.0
        self.h_min = float(ch.h.min())
        self.hv_scale_unit = ch.h ** 5  # HV scale per unit gamma c
        self.neighbours = NeighbourTable(ch.h, KAPPA)
        # H = L^3 or K^* L K on each field (docs/model.md section 4)
        operator = params.hyperviscosity_operator
        self.hv_consistent_density = operator == "consistent"
        self.hv_consistent_velocity = operator in ("consistent", "consistent_velocity")
        # operators at t^n (its Brookshaw lists serve the hyperviscosity), t^{n+1/2}, t^{n+1}
        # (ops_new becomes ops_n at the end of a step)
        self.ops_n = Operators(ch.h, ch.area, KAPPA, self.neighbours,
                               consistent=self.hv_consistent_velocity)
        self.ops_half = Operators(ch.h, ch.area, KAPPA, self.neighbours)
        self.ops_new = Operators(ch.h, ch.area, KAPPA, self.neighbours,
                                 consistent=self.hv_consistent_velocity)
        self._velocity = np.empty((2, n))  # (v_x, v_y) stacked for the MFPM kernel
        self.dv = np.zeros((2, n, 5))  # derivative vectors of v_x (dv[0]) and v_y (dv[1])
        self.div = np.zeros(n)
        self._velocity_derivatives(self.ops_n, self.x, self.y, self.vx, self.vy, self.dv,
                                   self.div, laplacian=True)
        # the hyperviscosity's stability limit is its stiffer operator's, each with its own
        # warm-started stiffest mode
        self._hv_consistent = sorted({self.hv_consistent_density, self.hv_consistent_velocity})
        self.hv_modes = {}
        self.hv_radius_unit = max(self._hv_spectral_radius(k, None, 60)
                                  for k in self._hv_consistent)
        self.hv_radius_max = self.hv_radius_unit
        self._hv_age = 0
        self.c = sound_speed(params.c_rule, si.c0, si.c_slope, 0.0, 0.0)
        # fluid pressure on the cornea [Pa], its load at t^n
        self.p_interface = np.empty(self.cornea_nodes.shape[0])
        tait_pressure_at(self.cornea_nodes, self.rho, si.rho_fluid, si.p0_Pa, self.c,
                         si.tait_gamma, self.p_interface)
        # work arrays (allocated once): the predicted and the trial fluid state of a step
        self._work = {k: np.empty(n) for k in ("hv_rho", "hv_vx", "hv_vy", "rho_half",
                                               "p_half", "vx_new", "vy_new", "x_new", "y_new",
                                               "rho_new", "div_new", "x_half", "y_half")}
        self._grad_p = np.zeros((1, n, 2))  # (p_x, p_y) at t^{n+1/2}
        self._hv_work = increments_work(n)
        self.pinned_vy = (ch.kind == WALL) | (ch.kind == CORNEA)
        self.pinned_vx = self.pinned_vy | (ch.kind == AXIS)
        self._dv_new = np.zeros((2, n, 5))
        # jet on the cornea at t^n and t^{n+1}, fluid pressure [Pa]: work arrays of the budget;
        # the jet at t^{n+1} of one step is the next step's at t^n (at time _jet_time [s])
        self._energy_work = (np.empty(ch.phi_cornea.shape[0]), np.empty(ch.phi_cornea.shape[0]),
                             np.empty(n))
        self._jet_time = math.nan
        N = self.X.shape[0]
        self._cornea_trial = tuple(np.empty(N) for _ in range(4))  # X, Y, VX, VY in iterations
        self._p_trial = (np.empty(N), np.empty(N))  # interface pressure estimates [Pa]
        self._p_interface_n = np.empty(N)  # interface pressure at t^n with this step's c [Pa]
        self.last_iterations = 0
        self.last_residual = 0.0
        self.last_substeps = 0
        self.last_hv_substeps = 0
        self.dt_hyperviscous = math.inf  # s, stability limit of the hyperviscosity (time_step)
        self.dt_limits = {}  # s: the acoustic and viscous limits of the last step
        self.max_cond = float(self.ops_n.cond.max())
        self.budget = EnergyBudget(self.cornea_model, self.viscoelastic, self.mass, si.rho_fluid,
                                   si.p0_Pa, si.tait_gamma)
        self.budget.start(self.X, self.Y, self.VX, self.VY, self.vx, self.vy, self.rho, self.c,
                          self._overstress())
        self._c_last = self.c

    def _start_cornea_at_rest(self):
        """The cornea starts in the exact discrete equilibrium under IOP (and p_a(0) with
        ``jet_start = equilibrium``); the fluid's interface nodes take its positions."""
        ch = self.chamber
        X0, Y0 = ch.x[ch.cornea_nodes].copy(), ch.y[ch.cornea_nodes].copy()
        q = np.full(X0.shape, self.si.p0_Pa)
        if self.params.jet_start == "equilibrium":
            jet_at_rest = np.empty_like(q)
            jet_pressures(0.0, ch.phi_cornea, self.jet, jet_at_rest)
            q -= jet_at_rest
        X, Y, self.equilibrium_residual = static_equilibrium(self.cornea_model, X0, Y0, q)
        self.cornea_model.rest(X, Y)
        self.rest_shape_deviation = float(np.max(np.hypot(X - X0, Y - Y0)))
        self.X, self.Y = X, Y
        self.VX = np.zeros_like(X)
        self.VY = np.zeros_like(Y)
        self.x[ch.cornea_nodes] = X
        self.y[ch.cornea_nodes] = Y
        self.apex_y0 = Y[0]
        self.n_apex_fit = apex_fit_nodes(X)
        self.apex_acceleration = np.zeros(self.n_apex_fit)  # m/s^2, of the last step

    def _build_globe(self):
        """The compliant walls (``globe = compliant``, globe.py), or None for rigid ones."""
        si, ch = self.si, self.chamber
        # the closing point of the polygon whose volume the cornea encloses
        self.volume_axis_y = 0.0 if self.params.geometry == "sector" else float(self.Y[-1])
        self.cornea_volume0 = cornea_polygon_volume(self.X, self.Y, self.volume_axis_y)
        self.wall = None
        self._wall_trial = None
        x_l = si.R_m * math.sin(si.alpha0_rad)
        x_c = si.r_post_m * math.sin(si.alpha0_rad) if self.params.geometry == "sector" else 0.0
        # the walls behind the fluid and the weights of their mean pressure (rigid or compliant)
        self._wall_nodes = np.flatnonzero(ch.kind == WALL)
        self._wall_pressure_weight = wall_weights(ch.x[self._wall_nodes], x_c, x_l)[1]
        self._wall_pressure = np.empty(self._wall_nodes.shape[0])  # work array [Pa]
        if self.params.globe != "compliant":
            return
        self.wall = CompliantWall(ch.x, ch.y, self._wall_nodes, x_c, x_l,
                                  si.ocular_rigidity_per_m3, si.p0_Pa, si.rho_fluid, self.mass,
                                  si.tait_gamma)
        self.wall.volume_offset = self.density_volume() - self.chamber_volume()

    # -- time step --------------------------------------------------------------------------
    def time_step(self):
        """dt [s] from the acoustic CFL condition, dt <= cfl h_min / (c + v_max), and the viscous
        limit, dt <= VISCOUS_SAFETY rho_min h_min^2 / mu; also refreshes the hyperviscosity's
        stability limit ``dt_hyperviscous``, which the predictor meets by sub-cycling.  The
        two limits that set dt are kept in ``dt_limits`` [s]."""
        si = self.si
        vmax = max_speed(self.vx, self.vy)
        dt_acoustic = si.cfl * self.h_min / (self.c + vmax)
        dt_viscous = (VISCOUS_SAFETY * float(self.rho.min()) * self.h_min ** 2 / si.mu
                      if si.mu > 0 else math.inf)
        self.dt_hyperviscous = self._hyperviscous_limit()
        self.dt_limits = {"acoustic": dt_acoustic, "viscous": dt_viscous}
        return min(dt_acoustic, dt_viscous)

    def max_step(self):
        """An upper bound [s] of the next step's dt: the acoustic limit at the smallest sound
        speed any rule gives, c >= c0 (infinite for c0 = 0)."""
        c0 = self.si.c0
        return self.si.cfl * self.h_min / c0 if c0 > 0 else math.inf

    def _hyperviscous_limit(self):
        """Largest stable forward-Euler step [s] of the hyperviscosity gamma c h^5 H."""
        gamma = self.si.hyperviscosity
        if gamma <= 0:
            return math.inf
        # the stiffest hyperviscous mode moves with the nodes: refresh the estimate
        self._hv_age += 1
        if self._hv_age >= HV_REFRESH_STEPS:
            self._hv_age = 0
            self.hv_radius_unit = max(
                self._hv_spectral_radius(k, self.hv_modes[k], HV_POWER_ITERATIONS)
                for k in self._hv_consistent)
            self.hv_radius_max = max(self.hv_radius_max, self.hv_radius_unit)
        return HV_SAFETY / (gamma * self.c * self.hv_radius_unit * HV_MARGIN)

    def _hv_spectral_radius(self, consistent, start, iterations):
        """Spectral radius of h^5 H (H = K^* L K if ``consistent``, else L^3) [1/s per c], by
        power iteration from ``start``; keeps the mode for the next refresh."""
        radius, self.hv_modes[consistent] = self.ops_n.hyperviscous_spectral_radius(
            self.hv_scale_unit, start, iterations, consistent)
        return radius

    def _velocity_derivatives(self, ops, x, y, vx, vy, dv, div, nodes=None, laplacian=False,
                              time_ms=None):
        """dv[0] = D v_x, dv[1] = D v_y and the axisymmetric divergence ``div`` [1/s] at
        ``nodes`` (default all), with the operators of ``ops`` built at (x, y) [m]."""
        velocity = self._velocity
        velocity[0] = vx
        velocity[1] = vy
        ops.derivatives(x, y, velocity, VELOCITY_PARITY, dv, nodes, laplacian, time_ms)
        axisymmetric_divergence(ops.all_nodes if nodes is None else nodes, x, vx, dv[0], dv[1],
                                div)

    def refresh_derivatives(self):
        """Recompute the operators and velocity derivatives at the current state (after the state
        arrays were set from outside, e.g. by the stability analysis)."""
        self._velocity_derivatives(self.ops_n, self.x, self.y, self.vx, self.vy, self.dv,
                                   self.div, laplacian=True)

    # -- one coupled step -------------------------------------------------------------------
    def step(self, t_stop=None, dt=None):
        """Advance by one coupled step; dt [s] from the stability limits unless given, cut so
        that the step ends at ``t_stop`` [s].  Returns dt."""
        si = self.si
        self.c = sound_speed(self.params.c_rule, si.c0, si.c_slope, self.v_prev, self.v_running)
        dt_stable = self.time_step()
        if dt is None:
            dt = dt_stable
        if t_stop is not None and self.t + dt > t_stop:
            dt = max(t_stop - self.t, 1e-12)
        self.predict_fluid(dt)
        self.couple(dt)
        self.commit(dt)
        return dt

    def predict_fluid(self, dt):
        """Part 1: the fluid's mid-point density, positions and new velocities of the nodes off
        the cornea (into the work arrays), from the state at t^n."""
        si = self.si
        w = self._work
        c = self.c
        self._hyperviscous_rates(dt)
        advance_density(self.rho, self.rho, self.div, 0.5 * dt, w["hv_rho"], dt, w["rho_half"])
        drift(self.x, self.y, self.vx, self.vy, 0.5 * dt, w["x_half"], w["y_half"])
        tait_pressure(w["rho_half"], si.rho_fluid, si.p0_Pa, c, si.tait_gamma, w["p_half"])
        self.ops_half.derivatives(w["x_half"], w["y_half"], w["p_half"][np.newaxis],
                                  PRESSURE_PARITY, self._grad_p, time_ms=self.t * 1e3)
        w["vx_new"][:] = 0.0
        w["vy_new"][:] = 0.0
        advance_velocity(self.kind, self.x, self.vx, self.vy, self._grad_p[0], self.dv[0],
                         self.dv[1], w["rho_half"], self.rho, si.mu, dt, w["hv_vx"],
                         w["hv_vy"], w["vx_new"], w["vy_new"])
        drift(w["x_half"], w["y_half"], w["vx_new"], w["vy_new"], 0.5 * dt, w["x_new"], w["y_new"])

    def _hyperviscous_rates(self, dt):
        """HV(rho), HV(v_x), HV(v_y) at t^n [per s] into the work arrays.  HV is stiff: it is
        integrated over the step by Runge-Kutta-Legendre super-steps (``kernels/hyperviscosity.py``:
        K super-steps of s stages cover K (s^2 + s)/2 forward-Euler steps of
        ``dt_hyperviscous``), and its increments, divided by dt, enter the predictor as
        rates."""
        w = self._work
        gamma = self.si.hyperviscosity
        if gamma <= 0:
            w["hv_rho"][:] = 0.0
            w["hv_vx"][:] = 0.0
            w["hv_vy"][:] = 0.0
            return
        scale = gamma * self.c * self.hv_scale_unit
        supersteps, stages = legendre_plan(dt / self.dt_hyperviscous)
        self.last_hv_substeps = supersteps * stages  # applications of the operator
        hyperviscous_flow_increments(self.rho, self.vx, self.vy, self.pinned_vx, self.pinned_vy,
                                     *self.ops_n.hyperviscosity_args(),
                                     self.hv_consistent_density, self.hv_consistent_velocity,
                                     scale, dt, stages, supersteps, chunks(self.x.shape[0]),
                                     *self._hv_work, w["hv_rho"], w["hv_vx"], w["hv_vy"])
        w["hv_rho"] /= dt
        w["hv_vx"] /= dt
        w["hv_vy"] /= dt

    def couple(self, dt):
        """Part 2: Dirichlet-Neumann iterations between the cornea and the predicted fluid, until
        the interface pressure settles; then the full velocity derivatives and density at
        t^{n+1} (into the work arrays).  Raises SimulationError on a blow-up or when the
        iterations do not converge."""
        si = self.si
        w = self._work
        c = self.c
        t_ms = self.t * 1e3
        rho0, p0, gam = si.rho_fluid, si.p0_Pa, si.tait_gamma
        cornea_model = self.cornea_model
        n_sub = cornea_model.substeps(self.X, self.Y, dt)
        self.last_substeps = n_sub
        ve = self.viscoelastic
        if ve is not None:
            ve.set_substep(dt / n_sub)
        # pressure at t^n with this step's c (the EOS changes with c at fixed density)
        p_interface_n = self._p_interface_n
        tait_pressure_at(self.cornea_nodes, self.rho, rho0, p0, c, gam, p_interface_n)
        p_est, p_new = self._p_trial
        p_est[:] = p_interface_n
        cornea = self.cornea_nodes
        X, Y, VX, VY = self._cornea_trial
        max_it = self.params.max_coupling_iterations
        for it in range(1, max_it + 1):
            X[:] = self.X
            Y[:] = self.Y
            VX[:] = self.VX
            VY[:] = self.VY
            history = None if ve is None else ve.begin_trial()
            cornea_model.advance(X, Y, VX, VY, p_interface_n, p_est, self.t, dt, n_sub, self.jet,
                                 history)
            impose_cornea(cornea, X, Y, VX, VY, w["x_new"], w["y_new"], w["vx_new"], w["vy_new"])
            if self.wall is not None:
                self._wall_trial = self._impose_wall(X, Y, VX, VY, dt)
            # only the cornea's density enters the coupling: the operators of the cornea nodes
            # suffice (every node, with reuse=False), the full field follows convergence
            self._velocity_derivatives(self.ops_new, w["x_new"], w["y_new"], w["vx_new"],
                                       w["vy_new"], self._dv_new, w["div_new"],
                                       cornea if self.reuse else None, time_ms=t_ms)
            advance_density(w["rho_half"], w["rho_half"], w["div_new"], 0.5 * dt, w["hv_rho"], 0.0,
                            w["rho_new"])
            residual = interface_pressure_change(cornea, w["rho_new"], rho0, p0, c, gam, P_REF,
                                                 p_est, p_new)
            if not math.isfinite(residual):
                raise SimulationError(f"fluid-structure system blew up at t = {t_ms:.4f} ms: the "
                                      f"interface pressure is not finite", t_ms, "blow-up")
            p_est, p_new = p_new, p_est
            if it >= 2 and residual < si.coupling_tol:
                break
        else:
            raise SimulationError(
                f"Dirichlet-Neumann coupling did not converge at t = {t_ms:.4f} ms: residual "
                f"{residual:.3g} > tolerance {si.coupling_tol:.3g} after {max_it} iterations",
                t_ms, "coupling")
        self.last_iterations = it
        self.last_residual = residual
        self._velocity_derivatives(self.ops_new, w["x_new"], w["y_new"], w["vx_new"],
                                   w["vy_new"], self._dv_new, w["div_new"], laplacian=True,
                                   time_ms=t_ms)
        advance_density(w["rho_half"], w["rho_half"], w["div_new"], 0.5 * dt, w["hv_rho"], 0.0,
                        w["rho_new"])

    def _impose_wall(self, X, Y, VX, VY, dt):
        """Move the compliant walls where the globe's law puts them for the cornea state
        (X, Y, VX, VY) at t^{n+1} (globe.py), in the trial fluid state; returns the wall state
        (displacement, speed, globe pressure)."""
        w = self._work
        volume_change = cornea_polygon_volume(X, Y, self.volume_axis_y) - self.cornea_volume0
        volume_rate = enclosed_volume_rate(X, Y, VX, VY, self.volume_axis_y)
        state = self.wall.wall_state(volume_change, volume_rate, self.c, dt)
        self.wall.impose(state[0], state[1], w["y_new"], w["vx_new"], w["vy_new"])
        return state

    def commit(self, dt):
        """Part 3: the coupled state becomes the state at t^{n+1} (buffers are swapped, not
        copied); the interface pressure and the speeds that set the next sound speed follow.
        Raises SimulationError when the new state has blown up."""
        si = self.si
        w = self._work
        self._account_energy(dt)
        if self.viscoelastic is not None:
            self.viscoelastic.commit()
        self.cornea_model.commit()
        self.apex_acceleration = (self._cornea_trial[3][:self.n_apex_fit]
                                  - self.VY[:self.n_apex_fit]) / dt
        cornea_n = (self.X, self.Y, self.VX, self.VY)
        self.X, self.Y, self.VX, self.VY = self._cornea_trial
        self._cornea_trial = cornea_n
        self.x, w["x_new"] = w["x_new"], self.x
        self.y, w["y_new"] = w["y_new"], self.y
        self.vx, w["vx_new"] = w["vx_new"], self.vx
        self.vy, w["vy_new"] = w["vy_new"], self.vy
        self.rho, w["rho_new"] = w["rho_new"], self.rho
        self.div, w["div_new"] = w["div_new"], self.div
        self.dv, self._dv_new = self._dv_new, self.dv
        self.ops_n, self.ops_new = self.ops_new, self.ops_n
        self.t += dt
        if self.wall is not None:
            self.wall.displacement = self._wall_trial[0]  # chamber_volume() sees the new wall
            self.wall.commit(self._wall_trial, self.density_volume(), self.chamber_volume(), dt,
                             self.c, self._mean_wall_pressure(self.rho))
        vmax = max_speed(self.vx, self.vy)
        self.v_prev = vmax
        self.v_running = max(self.v_running, vmax)
        tait_pressure_at(self.cornea_nodes, self.rho, si.rho_fluid, si.p0_Pa, self.c,
                         si.tait_gamma, self.p_interface)
        if not math.isfinite(vmax) or vmax > BLOWUP_SPEED:
            raise SimulationError(f"fluid blew up at t = {self.t * 1e3:.4f} ms: max speed "
                                  f"{vmax:.3g} m/s", self.t * 1e3, "blow-up")
        dev = max_density_deviation(self.rho, si.rho_fluid)
        if not math.isfinite(dev) or dev > BLOWUP_DENSITY:
            raise SimulationError(f"fluid blew up at t = {self.t * 1e3:.4f} ms: density deviates "
                                  f"by {dev:.3g} from the reference", self.t * 1e3, "blow-up")

    def _overstress(self):
        return None if self.viscoelastic is None else self.viscoelastic.overstress

    def _account_energy(self, dt):
        """Add the work terms of the step just coupled to the energy budget (energy.py): the
        state at t^n is still the model's, the coupled one in the trial and work arrays."""
        si = self.si
        w = self._work
        X, Y = self._cornea_trial[0], self._cornea_trial[1]
        phi = self.chamber.phi_cornea
        jet_new, jet_n, p_n = self._energy_work  # last step's jet at t^{n+1} is in [0]
        if self._jet_time != self.t:
            jet_pressures(self.t, phi, self.jet, jet_n)
        else:
            jet_n, jet_new = jet_new, jet_n
        jet_pressures(self.t + dt, phi, self.jet, jet_new)
        self._energy_work = (jet_new, jet_n, p_n)
        self._jet_time = self.t + dt
        tait_pressure(self.rho, si.rho_fluid, si.p0_Pa, self.c, si.tait_gamma, p_n)
        globe = 0.0 if self.wall is None else self._globe_work()
        ve = self.viscoelastic
        self.budget.account_step(dt, jet_n, jet_new, self.X, self.Y, X, Y, self._overstress(),
                                 None if ve is None else ve.trial_overstress, self.kind, self.x,
                                 self.vx, self.vy, w["vx_new"], w["vy_new"], self.dv, self.rho,
                                 si.mu, w["hv_vx"], w["hv_vy"], w["hv_rho"], p_n, self._c_last,
                                 self.c, globe)
        self._c_last = self.c

    def _mean_wall_pressure(self, rho):
        """The fluid's mean pressure on the walls behind it [Pa] for the density field rho,
        weighted by the volume each wall node sweeps when the globe is compliant (globe.py)."""
        si = self.si
        tait_pressure_at(self._wall_nodes, rho, si.rho_fluid, si.p0_Pa, self.c, si.tait_gamma,
                         self._wall_pressure)
        return float(np.dot(self._wall_pressure_weight, self._wall_pressure))

    def _globe_work(self):
        """Work [J] of the fluid on the compliant walls over the step just coupled: the mean wall
        pressure of its two ends times the volume the walls gave way by."""
        wall = self.wall
        p_start = self._mean_wall_pressure(self.rho)
        p_end = self._mean_wall_pressure(self._work["rho_new"])
        return 0.5 * (p_start + p_end) * wall.area * (self._wall_trial[0] - wall.displacement)

    def apex_budget(self):
        """The apex force budget [Pa] of the current state: over the nodes of the apex fit
        (``apex_fit_nodes``) the balance of the cornea's nodes in the load direction,

            sum m_i a_i = sum F_eq,i + sum F_ve,i + sum a_p,i (p_fluid,i - p_jet,i),

        divided by a = sum a_p,i (a_p,i: the lumped outward area of node i's pressure load,
        ``add_pressure_loads``), read as the jet pressure that the apex carries:

            p_jet = p_fluid + F_eq / a + F_ve / a - m a / a.

        Returns (p_jet, p_fluid, equilibrium, overstress, inertia): the area-weighted jet and
        fluid pressures (the IOP included), the equilibrium law's resistance (its internal
        forces: minus the IOP's membrane tension plus bending and shear), the viscoelastic
        overstress' and minus the nodes' inertia, their acceleration that of the last step."""
        region = slice(0, self.n_apex_fit)
        X, Y = self.X, self.Y
        Fx, Fy = np.zeros_like(X), np.zeros_like(Y)
        add_pressure_loads(X, Y, np.ones_like(X), Fx, Fy)
        area = float(Fy[region].sum())
        Fx[:] = 0.0
        Fy[:] = 0.0
        add_pressure_loads(X, Y, self.p_interface, Fx, Fy)
        fluid = float(Fy[region].sum()) / area
        Fx[:] = 0.0
        Fy[:] = 0.0
        jet = np.empty_like(X)
        jet_pressures(self.t, self.chamber.phi_cornea, self.jet, jet)
        add_pressure_loads(X, Y, jet, Fx, Fy)
        jet_mean = float(Fy[region].sum()) / area
        equilibrium = float(self.cornea_model.internal_forces(X, Y)[1][region].sum()) / area
        overstress = 0.0
        if self.viscoelastic is not None:
            total = self.cornea_model.internal_forces(X, Y, self.viscoelastic)[1]
            overstress = float(total[region].sum()) / area - equilibrium
        inertia = -float(np.dot(self.cornea_model.mass[region], self.apex_acceleration)) / area
        return jet_mean, fluid, equilibrium, overstress, inertia

    def apex_moment(self):
        """Meridional bending moment at the apex [N m/m], with its viscoelastic overstress."""
        return self.cornea_model.apex_moment(self.X, self.Y, self._overstress())

    def energy_terms(self):
        """The energy budget's terms at the current state [uJ] (energy.py)."""
        return self.budget.terms(self.X, self.Y, self.VX, self.VY, self.vx, self.vy, self.rho,
                                 self.c, self._overstress())

    # -- quantities of the current state ----------------------------------------------------
    def apex_curvature(self):
        """Apical curvature of the cornea [1/m], positive convex."""
        return apex_curvature(self.X, self.Y, self.n_apex_fit)

    def apex_displacement(self):
        """Inward displacement of the apex since t = 0 [m]."""
        return self.apex_y0 - self.Y[0]

    def wall_volume_change(self):
        """Volume [m^3] by which the compliant walls have given way (0 for a rigid globe)."""
        return 0.0 if self.wall is None else self.wall.area * self.wall.displacement

    def wall_pressure(self):
        """The fluid's mean pressure on the walls behind it [Pa] (``_mean_wall_pressure``); its
        deviation from ``globe_pressure`` is the chamber's acoustic ringing."""
        return self._mean_wall_pressure(self.rho)

    def globe_pressure(self):
        """Pressure of the globe's law for the volume the cornea has pushed in [Pa] (the IOP for
        a rigid globe)."""
        return self.si.p0_Pa if self.wall is None else self.wall.pressure

    def chamber_volume(self):
        """Volume of the chamber bounded by the cornea and the walls [m^3]."""
        si = self.si
        return (chamber_volume(self.params.geometry, self.X, self.Y, si.r_post_m, si.alpha0_rad)
                + self.wall_volume_change())

    def density_volume(self):
        """Chamber volume implied by the density field, sum m_j / rho_j [m^3]."""
        return float(np.sum(self.mass / self.rho))

    def pressure(self):
        """The fluid pressure field [Pa] at the current state, eq. (5) with the current c."""
        si = self.si
        p = np.empty(self.rho.shape[0])
        tait_pressure(self.rho, si.rho_fluid, si.p0_Pa, self.c, si.tait_gamma, p)
        return p
