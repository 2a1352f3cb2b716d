"""The coupled time loop: membrane + MFPM fluid, Dirichlet-Neumann iterations in every step.

One step from t^n to t^{n+1} = t^n + dt (SI units inside):

1. Fluid predictor (the paper's mid-point scheme, section 3), independent of the coupling:
       rho^{n+1/2} = rho^n - dt/2 rho^n div^n v^n + dt HV(rho^n)
       x^{n+1/2}   = x^n + dt/2 v^n
       v^{n+1}     = v^n - dt/rho^{n+1/2} grad^{n+1/2} p^{n+1/2} + dt mu/rho^n visc^n(v^n) + dt HV(v^n)
       x^{n+1}     = x^{n+1/2} + dt/2 v^{n+1}
   for the nodes that are not on the cornea; HV(f) = gamma c h^5 L^3 f is the stabilising
   hyperviscosity (L the Brookshaw Laplacian, SPEC section 4).
2. Dirichlet-Neumann iterations k = 1, 2, ...:
   (a) advance the membrane from its state at t^n with the interface pressure interpolated from
       p^n to the current estimate p^k (plus the jet), by Verlet sub-steps;
   (b) impose the cornea's position and velocity on the fluid interface nodes (Dirichlet);
   (c) rho^{n+1} = rho^{n+1/2} - dt/2 rho^{n+1/2} div^{n+1} v^{n+1}, p^{n+1} from eq. (5);
       the new interface pressure is the membrane's load (Neumann);
   until ||p^{k} - p^{k-1}|| / max(||p^{k-1} - p0||, p_ref) < coupling_tol, with k >= 2.
"""

from __future__ import annotations

import math
import time as _time

import numpy as np

from .errors import SimulationError
from .fluid import NeighbourTable, Operators
from .geometry import build_chamber, chamber_volume
from .kernels.fluid import (AXIS, CORNEA, WALL, advance_density, advance_velocity,
                            axisymmetric_divergence, drift, impose_cornea,
                            interface_pressure_change, max_density_deviation, max_speed,
                            tait_pressure, tait_pressure_at)
from .kernels.mfpm import hyperviscous_flow_increments
from .kernels.membrane import advance_membrane, air_jet, max_wave_speed
from .membrane import (apex_curvature, apex_fit_nodes, build_membrane, jet_pressure,
                       static_equilibrium)
from .metrics import compute_metrics
from .params import MMHG_PA, RunParams
from .result import SNAPSHOT_LABELS, RunResult

KAPPA = 2.7  # MFPM support radius / local spacing (>= 2.2 keeps wall stencils well conditioned)
HV_SAFETY = 1.4  # dt <= HV_SAFETY / (spectral radius of the HV operator); FE limit 2, unstable at 2.0 (measured)
HV_POWER_ITERATIONS = 2  # power iterations per refresh, warm-started (the mode changes slowly)
HV_REFRESH_STEPS = 4  # steps between refreshes (nodes move < 1 % of a spacing in between)
HV_MARGIN = 1.1  # a warm-started power iteration may underestimate the radius slightly
# dt <= VISCOUS_SAFETY rho h_min^2 / mu: the viscous term is forward Euler in the mid-point scheme.
# Its measured limit on the MFPM operator (eigenvalues of the axisymmetric viscous matrix,
# ``stability.forward_euler_viscous_limit``) is 0.547 (v_x) / 0.579 (v_y) at coarse and paper
# resolution; 0.25, the classical five-point-stencil value, keeps a margin of 2.2 for nodes that the
# flow pushes together (nearest-neighbour spacing down to 0.69 h, docs/model.md section 4).
VISCOUS_SAFETY = 0.25
MEMBRANE_SAFETY = 0.4  # membrane sub-step <= MEMBRANE_SAFETY * min chord / wave speed
P_REF = 1.0  # Pa: floor of the normalisation of the coupling residual (meaningful at rest)
BLOWUP_SPEED = 50.0  # m/s: a fluid speed above this is a blow-up (physical speeds ~0.2-1 m/s)
BLOWUP_DENSITY = 0.2  # relative density change beyond which the run is declared blown up
VELOCITY_PARITY = np.array([-1.0, 1.0])  # v_x is odd in x, v_y even
PRESSURE_PARITY = np.array([1.0])


def sound_speed(rule, c0, c_slope, v_prev, v_running):
    """Artificial sound speed [m/s]: c = c0 + c_slope v_max (SPEC section 4, ``c_rule``)."""
    if rule == "fixed":
        return c0
    if rule == "per_step":
        return c0 + c_slope * v_prev
    return c0 + c_slope * v_running


class CoupledModel:
    """State and operators of one run; ``step()`` advances by one coupled time step.

    ``reuse=False`` rebuilds every operator and every derivative in full in each coupling
    iteration, instead of only what the moving cornea changes: the same answers, slower (a check
    of the reuse).
    """

    def __init__(self, params: RunParams, reuse: bool = True):
        self.params = params
        self.reuse = reuse
        si = self.si = params.si()
        ch = self.chamber = build_chamber(params.geometry, params.layout, params.resolution,
                                          si["R"], si["r_post"], si["alpha0"])
        self.membrane = build_membrane(ch.phi_cornea, si["R"], si["p0"], si["E0"], si["h"],
                                       si["nu"], si["fung_k"], si["rho_c"])
        self.jet = np.array([si["pmax"], si["a"], si["b"], si["T"], si["t0"]])
        n = ch.n
        self.kind = ch.kind
        self.cornea = ch.cornea
        self.x = ch.x.copy()
        self.y = ch.y.copy()
        self.vx = np.zeros(n)
        self.vy = np.zeros(n)
        self.rho = np.full(n, si["rho_f"])
        self.mass = si["rho_f"] * ch.volume  # fixed particle masses [kg]
        # the cornea starts in the exact discrete equilibrium under IOP (and p_a(0) if asked)
        X0, Y0 = ch.x[ch.cornea].copy(), ch.y[ch.cornea].copy()
        q = np.full(X0.shape, si["p0"])
        if params.jet_start == "equilibrium":
            q -= jet_pressure(0.0, ch.phi_cornea, *self.jet)
        X, Y, self.equilibrium_residual = static_equilibrium(self.membrane, X0, Y0, q)
        self.rest_shape_deviation = float(np.max(np.hypot(X - X0, Y - Y0)))
        self.X, self.Y = X, Y
        self.VX = np.zeros_like(X)
        self.VY = np.zeros_like(Y)
        self.x[ch.cornea] = X
        self.y[ch.cornea] = Y
        self.apex_y0 = Y[0]
        self.n_apex_fit = apex_fit_nodes(X)
        self.t = 0.0
        self.v_prev = 0.0
        self.v_running = 0.0
        self.h_min = float(ch.h.min())
        self.hv_scale_unit = ch.h ** 5  # HV scale per unit gamma c
        self.neighbours = NeighbourTable(ch.h, KAPPA)
        # operators at t^n (its Brookshaw lists serve the hyperviscosity), t^{n+1/2}, t^{n+1}
        self.ops_n = Operators(ch.h, ch.area, KAPPA, self.neighbours)
        self.ops_half = Operators(ch.h, ch.area, KAPPA, self.neighbours)
        self.ops_new = Operators(ch.h, ch.area, KAPPA, self.neighbours)
        self._velocity = np.empty((2, n))  # (v_x, v_y) stacked for the MFPM kernel
        self.dv = np.zeros((2, n, 5))  # derivative vectors of v_x (dv[0]) and v_y (dv[1])
        self.div = np.zeros(n)
        self._velocity_derivatives(self.ops_n, self.x, self.y, self.vx, self.vy, self.dv,
                                   self.div, laplacian=True)
        self.hv_radius_unit, self.hv_mode = self.ops_n.hyperviscous_spectral_radius(
            self.hv_scale_unit)
        self.hv_radius_max = self.hv_radius_unit
        self._hv_age = 0
        self.c = sound_speed(params.c_rule, si["c0"], si["c_slope"], 0.0, 0.0)
        self.p_interface = np.empty(self.cornea.shape[0])  # fluid pressure on the cornea [Pa]
        tait_pressure_at(self.cornea, self.rho, si["rho_f"], si["p0"], self.c, si["gamma"],
                         self.p_interface)
        # work arrays (allocated once)
        self._w = {k: np.empty(n) for k in ("hv_rho", "hv_vx", "hv_vy", "rho_half",
                                            "p_half", "vx_new", "vy_new", "x_new", "y_new",
                                            "rho_new", "div_new", "x_half", "y_half")}
        self._grad_p = np.zeros((1, n, 2))  # (p_x, p_y) at t^{n+1/2}
        self._hv_work = np.empty((9, n))
        self.pinned_vy = (ch.kind == WALL) | (ch.kind == CORNEA)
        self.pinned_vx = self.pinned_vy | (ch.kind == AXIS)
        self.last_hv_substeps = 0
        self._dv_new = np.zeros((2, n, 5))
        N = X.shape[0]
        self._mF = {k: np.empty(N) for k in ("Fx", "Fy", "q")}
        self._membrane_trial = tuple(np.empty(N) for _ in range(4))  # X, Y, VX, VY in iterations
        self._p_trial = (np.empty(N), np.empty(N))  # interface pressure estimates [Pa]
        self._p_interface_n = np.empty(N)  # interface pressure at t^n with this step's c [Pa]
        self.last_iterations = 0
        self.last_residual = 0.0
        self.last_substeps = 0
        self.dt = 0.0
        self.dt_limits = {}
        self.max_cond = float(self.ops_n.cond.max())

    # ---------------------------------------------------------------------------------------
    def time_step(self):
        """dt [s] from the acoustic CFL condition, dt <= cfl h_min / (c + v_max), and the viscous
        limit, dt <= VISCOUS_SAFETY rho h_min^2 / mu (rho the smallest density); the
        hyperviscosity's limit (``dt_limits``) sets its own sub-steps."""
        si = self.si
        vmax = max_speed(self.vx, self.vy)
        dt_ac = si["cfl"] * self.h_min / (self.c + vmax)
        mu = si["mu"]
        dt_visc = (VISCOUS_SAFETY * float(self.rho.min()) * self.h_min ** 2 / mu if mu > 0
                   else math.inf)
        gamma = si["hyperviscosity"]
        if gamma > 0:
            # the stiffest hyperviscous mode moves with the nodes: refresh the estimate
            self._hv_age += 1
            if self._hv_age >= HV_REFRESH_STEPS:
                self._hv_age = 0
                self.hv_radius_unit, self.hv_mode = self.ops_n.hyperviscous_spectral_radius(
                    self.hv_scale_unit, self.hv_mode, HV_POWER_ITERATIONS)
                self.hv_radius_max = max(self.hv_radius_max, self.hv_radius_unit)
            dt_hv = HV_SAFETY / (gamma * self.c * self.hv_radius_unit * HV_MARGIN)
        else:
            dt_hv = math.inf
        self.dt_limits = {"acoustic": dt_ac, "viscous": dt_visc, "hyperviscosity": dt_hv}
        return min(dt_ac, dt_visc)

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

    def step(self, t_stop=None, dt=None):
        """Advance by one coupled step (dt from the stability limits unless given) [s]."""
        si = self.si
        w = self._w
        self.c = c = sound_speed(self.params.c_rule, si["c0"], si["c_slope"], self.v_prev,
                                 self.v_running)
        dt_stable = self.time_step()  # also refreshes the hyperviscous limit used below
        if dt is None:
            dt = dt_stable
        if t_stop is not None and self.t + dt > t_stop:
            dt = max(t_stop - self.t, 1e-12)
        self.dt = dt
        t_ms = self.t * 1e3
        rho0, p0, gam = si["rho_f"], si["p0"], si["gamma"]
        mem = self.membrane
        c_mem = max_wave_speed(self.X, self.Y, mem.L0, mem.S0, mem.Ebar, mem.nu, mem.k, mem.rho_h)
        n_sub = max(1, int(math.ceil(dt / (MEMBRANE_SAFETY * mem.L0.min() / c_mem))))
        self.last_substeps = n_sub
        ops_n, ops_half, ops_new = self.ops_n, self.ops_half, self.ops_new

        # pressure at t^n with this step's c (the EOS changes with c at fixed density)
        p_interface_n = self._p_interface_n
        tait_pressure_at(self.cornea, self.rho, rho0, p0, c, gam, p_interface_n)

        # 1. fluid predictor
        gamma = si["hyperviscosity"]
        scale = gamma * c * self.hv_scale_unit
        if gamma > 0:
            # HV is stiff: sub-cycle it within the step (its increments, divided by dt, enter
            # the updates below as rates)
            n_hv = max(1, int(math.ceil(dt / self.dt_limits["hyperviscosity"])))
            self.last_hv_substeps = n_hv
            hyperviscous_flow_increments(self.rho, self.vx, self.vy, self.pinned_vx,
                                         self.pinned_vy, *ops_n.hyperviscosity_args(), scale, dt,
                                         n_hv, self._hv_work,
                                         w["hv_rho"], w["hv_vx"], w["hv_vy"])
            w["hv_rho"] /= dt
            w["hv_vx"] /= dt
            w["hv_vy"] /= dt
        else:
            w["hv_rho"][:] = 0.0
            w["hv_vx"][:] = 0.0
            w["hv_vy"][:] = 0.0
        advance_density(self.rho, self.rho, self.div, 0.5 * dt, w["hv_rho"], dt, w["rho_half"])
        drift(self.x, self.y, self.vx, self.vy, 0.5 * dt, w["x_half"], w["y_half"])
        tait_pressure(w["rho_half"], rho0, p0, c, gam, w["p_half"])
        ops_half.derivatives(w["x_half"], w["y_half"], w["p_half"][np.newaxis], PRESSURE_PARITY,
                             self._grad_p, time_ms=t_ms)
        w["vx_new"][:] = 0.0
        w["vy_new"][:] = 0.0
        advance_velocity(self.kind, self.x, self.vx, self.vy, self._grad_p[0], self.dv[0],
                         self.dv[1], w["rho_half"], self.rho, si["mu"], dt, w["hv_vx"],
                         w["hv_vy"], w["vx_new"], w["vy_new"])
        drift(w["x_half"], w["y_half"], w["vx_new"], w["vy_new"], 0.5 * dt, w["x_new"], w["y_new"])

        # 2. Dirichlet-Neumann iterations
        p_est, p_new = self._p_trial
        p_est[:] = p_interface_n
        cornea = self.cornea
        mF = self._mF
        X, Y, VX, VY = self._membrane_trial
        max_it = self.params.max_coupling_iterations
        for it in range(1, max_it + 1):
            X[:] = self.X
            Y[:] = self.Y
            VX[:] = self.VX
            VY[:] = self.VY
            advance_membrane(X, Y, VX, VY, mem.mass, mem.phi, mem.L0, mem.S0, mem.A0, mem.Ebar,
                             mem.nu, mem.k, p_interface_n, p_est, self.t, dt, n_sub, self.jet,
                             mF["Fx"], mF["Fy"], mF["q"])
            impose_cornea(cornea, X, Y, VX, VY, w["x_new"], w["y_new"], w["vx_new"], w["vy_new"])
            # only the cornea's density enters the coupling: the operators of the cornea nodes
            # suffice (every node, with reuse=False), the full field follows convergence
            self._velocity_derivatives(ops_new, w["x_new"], w["y_new"], w["vx_new"],
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
            if it >= 2 and residual < si["tol"]:
                break
        else:
            raise SimulationError(
                f"Dirichlet-Neumann coupling did not converge at t = {t_ms:.4f} ms: residual "
                f"{residual:.3g} > tolerance {si['tol']:.3g} after {max_it} iterations",
                t_ms, "coupling")
        self.last_iterations = it
        self.last_residual = residual
        self._velocity_derivatives(ops_new, w["x_new"], w["y_new"], w["vx_new"], w["vy_new"],
                                   self._dv_new, w["div_new"], laplacian=True, time_ms=t_ms)
        advance_density(w["rho_half"], w["rho_half"], w["div_new"], 0.5 * dt, w["hv_rho"], 0.0,
                        w["rho_new"])

        # commit the step
        self._membrane_trial = (self.X, self.Y, self.VX, self.VY)
        self.X, self.Y, self.VX, self.VY = X, Y, VX, VY
        self.x, w["x_new"] = w["x_new"], self.x
        self.y, w["y_new"] = w["y_new"], self.y
        self.vx, w["vx_new"] = w["vx_new"], self.vx
        self.vy, w["vy_new"] = w["vy_new"], self.vy
        self.rho, w["rho_new"] = w["rho_new"], self.rho
        self.div, w["div_new"] = w["div_new"], self.div
        self.dv, self._dv_new = self._dv_new, self.dv
        self.ops_n, self.ops_new = ops_new, ops_n
        self.t += dt
        vmax = max_speed(self.vx, self.vy)
        self.v_prev = vmax
        self.v_running = max(self.v_running, vmax)
        tait_pressure_at(cornea, self.rho, rho0, p0, c, gam, self.p_interface)
        if not math.isfinite(vmax) or vmax > BLOWUP_SPEED:
            raise SimulationError(f"fluid blew up at t = {self.t * 1e3:.4f} ms: max speed "
                                  f"{vmax:.3g} m/s", self.t * 1e3, "blow-up")
        dev = max_density_deviation(self.rho, rho0)
        if not math.isfinite(dev) or dev > BLOWUP_DENSITY:
            raise SimulationError(f"fluid blew up at t = {self.t * 1e3:.4f} ms: density deviates "
                                  f"by {dev:.3g} from the reference", self.t * 1e3, "blow-up")
        return dt

    # ---------------------------------------------------------------------------------------
    def apex_curvature(self):
        return apex_curvature(self.X, self.Y, self.n_apex_fit)

    def chamber_volume(self):
        si = self.si
        return chamber_volume(self.params.geometry, self.X, self.Y, si["r_post"], si["alpha0"])

    def density_volume(self):
        """Chamber volume implied by the density field, sum m_j / rho_j [m^3]."""
        return float(np.sum(self.mass / self.rho))

    def probe(self):
        """Scalar quantities recorded in the time histories (user units)."""
        si = self.si
        return {
            "apex_displacement": (self.apex_y0 - self.Y[0]) * 1e3,
            "apex_velocity": -self.VY[0],
            "apex_curvature": self.apex_curvature() * 1e-3,
            "jet_pressure_apex": air_jet(self.t, 0.0, *self.jet) / MMHG_PA,
            "fluid_pressure_apex": self.p_interface[0] / MMHG_PA,
            "chamber_volume": self.chamber_volume() * 1e9,
            "coupling_iterations": float(self.last_iterations),
            "sound_speed": self.c,
        }

    def pressure(self):
        """The fluid pressure field [Pa] at the current state, eq. (5) with the current c."""
        si = self.si
        p = np.empty(self.rho.shape[0])
        tait_pressure(self.rho, si["rho_f"], si["p0"], self.c, si["gamma"], p)
        return p

    def snapshot(self):
        return {
            "cornea_x": self.X * 1e3, "cornea_y": self.Y * 1e3,
            "fluid_x": self.x * 1e3, "fluid_y": self.y * 1e3,
            "fluid_pressure": self.pressure() / MMHG_PA,
            "fluid_vx": self.vx.copy(), "fluid_vy": self.vy.copy(),
        }


def simulate(params: RunParams, progress=None, reuse: bool = True) -> RunResult:
    """Run one coupled simulation and return its histories, snapshots and metrics.

    ``progress(t_ms, t_end_ms)`` is called now and then.  ``reuse``: see ``CoupledModel``.
    Raises SimulationError on blow-up, non-convergent coupling or an ill-conditioned operator
    (the message names the time).
    """
    wall0 = _time.monotonic()
    model = CoupledModel(params, reuse)
    si = model.si
    t_end = si["t_end"]
    dt_out = si["output_interval"]
    n_out = int(math.floor(t_end / dt_out + 1e-9)) + 1
    out_t = np.arange(n_out) * dt_out
    hist = {k: np.full(n_out, np.nan) for k in model.probe()}
    prev = model.probe()
    for k, v in prev.items():
        hist[k][0] = v
    next_out = 1
    t_prev = 0.0
    # step-level series for the applanation detection and Imbert-Fick diagnostics
    step_t = [0.0]
    step_kappa = [prev["apex_curvature"]]
    step_pf = [prev["fluid_pressure_apex"]]
    snaps = {label: None for label in SNAPSHOT_LABELS}
    snap_t = {label: math.nan for label in SNAPSHOT_LABELS}
    snaps["initial"], snap_t["initial"] = model.snapshot(), 0.0
    t0 = si["t0"]
    best_da = -math.inf
    n_steps = 0
    iters = []
    dts = []
    max_residual = 0.0
    substeps = []
    hv_substeps = []
    viscous_limited = 0
    vol0 = prev["chamber_volume"]
    dens_vol0 = model.density_volume()
    max_vol_mismatch = 0.0
    last_progress = _time.monotonic()
    if progress:
        progress(0.0, t_end * 1e3)
    while model.t < t_end - 1e-15:
        dt = model.step(t_stop=t_end)
        n_steps += 1
        iters.append(model.last_iterations)
        dts.append(dt)
        substeps.append(model.last_substeps)
        hv_substeps.append(model.last_hv_substeps)
        viscous_limited += model.dt_limits["viscous"] < model.dt_limits["acoustic"]
        max_residual = max(max_residual, model.last_residual)
        cur = model.probe()
        t = model.t
        step_t.append(t * 1e3)
        step_kappa.append(cur["apex_curvature"])
        step_pf.append(cur["fluid_pressure_apex"])
        # snapshots at the applanations (sign changes of the apex curvature) and the jet peak
        if step_kappa[-2] > 0 >= step_kappa[-1] and snaps["first_applanation"] is None:
            snaps["first_applanation"], snap_t["first_applanation"] = model.snapshot(), t * 1e3
        if step_kappa[-2] < 0 <= step_kappa[-1]:
            snaps["second_applanation"], snap_t["second_applanation"] = model.snapshot(), t * 1e3
        if snaps["jet_peak"] is None and t >= t0:
            snaps["jet_peak"], snap_t["jet_peak"] = model.snapshot(), t * 1e3
        # histories on the output grid, linearly interpolated between solver steps
        while next_out < n_out and out_t[next_out] <= t + 1e-15:
            s = (out_t[next_out] - t_prev) / (t - t_prev)
            for k in hist:
                hist[k][next_out] = prev[k] + s * (cur[k] - prev[k])
            if hist["apex_displacement"][next_out] > best_da:
                best_da = hist["apex_displacement"][next_out]
                snaps["max_displacement"], snap_t["max_displacement"] = model.snapshot(), t * 1e3
            next_out += 1
        vol_mismatch = abs((cur["chamber_volume"] - vol0) * 1e-9
                           - (model.density_volume() - dens_vol0)) / (vol0 * 1e-9)
        max_vol_mismatch = max(max_vol_mismatch, vol_mismatch)
        prev, t_prev = cur, t
        if progress and _time.monotonic() - last_progress > 0.2:
            progress(t * 1e3, t_end * 1e3)
            last_progress = _time.monotonic()
    snaps["end"], snap_t["end"] = model.snapshot(), model.t * 1e3
    # the jet is analytic: store eq. (11) exactly on the output grid, not interpolated
    hist["jet_pressure_apex"] = jet_pressure(out_t, 0.0, *model.jet) / MMHG_PA
    if progress:
        progress(t_end * 1e3, t_end * 1e3)

    # fill missing snapshots with NaN arrays of the right shape
    template = snaps["initial"]
    snapshot_arrays = {}
    for name in template:
        rows = [snaps[lbl][name] if snaps[lbl] is not None else np.full_like(template[name], np.nan)
                for lbl in SNAPSHOT_LABELS]
        snapshot_arrays[name] = np.stack(rows)
    snapshot_time = np.array([snap_t[lbl] for lbl in SNAPSHOT_LABELS])

    metrics, notes, extra = compute_metrics(
        out_t * 1e3, hist, np.array(step_t), np.array(step_kappa), np.array(step_pf),
        lambda t_ms: air_jet(t_ms * 1e-3, 0.0, *model.jet) / MMHG_PA, t0 * 1e3)
    wall = _time.monotonic() - wall0
    dts = np.array(dts) if dts else np.array([0.0])
    diagnostics = {
        "steps": n_steps,
        "dt_mean_us": float(dts.mean() * 1e6),
        "dt_min_us": float(dts.min() * 1e6),
        "dt_max_us": float(dts.max() * 1e6),
        "n_fluid": int(model.chamber.n),
        "n_cornea": int(model.X.shape[0]),
        "mean_coupling_iterations": float(np.mean(iters)) if iters else 0.0,
        "max_coupling_iterations": int(np.max(iters)) if iters else 0,
        "max_coupling_residual": float(max_residual),
        "mean_membrane_substeps": float(np.mean(substeps)) if substeps else 0.0,
        "mean_hyperviscous_substeps": float(np.mean(hv_substeps)) if hv_substeps else 0.0,
        "wall_s": wall,
        "prestretch": model.membrane.lambda0,
        "R_ref_mm": model.membrane.R_ref * 1e3,
        "rest_shape_deviation_mm": model.rest_shape_deviation * 1e3,
        "equilibrium_residual": model.equilibrium_residual,
        "max_moment_condition": model.max_cond,
        "hyperviscous_radius_per_gamma_c": model.hv_radius_max,
        "max_volume_mismatch": max_vol_mismatch,
        "mass_kg": float(model.mass.sum()),
        "kappa_support": KAPPA,
        "neighbour_searches": model.neighbours.searches,
        "apex_fit_nodes": model.n_apex_fit,
        "acoustic_cfl": si["cfl"],
        "viscous_limited_steps": int(viscous_limited),
    }
    diagnostics.update(extra)
    return RunResult(params=params, time=out_t * 1e3, histories=hist, snapshot_time=snapshot_time,
                     snapshots=snapshot_arrays, metrics=metrics, metric_notes=notes,
                     diagnostics=diagnostics)
