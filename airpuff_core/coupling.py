"""One coupled time step: a cornea model and the MFPM fluid, Dirichlet-Neumann iterations.

``CoupledModel`` holds the parts of one run (SI units) and advances them from t^n to
t^{n+1} = t^n + dt:

- ``StepControl`` (``step_control.py``): the sound speed and dt;
- ``FluidStepper`` (``fluid_stepper.py``): the fluid's predictor, independent of the coupling;
- ``DirichletNeumann`` (``dirichlet_neumann.py``): from the estimate p^n + dt dp/dt (the last
  step's rate of change of the interface pressure; with ``hyperviscosity_interval`` N, that of
  the step N steps back, which the hyperviscosity's application treated alike), the iterations
  k = 1, 2, ... of
  (a) the cornea (``cornea/``, any model of the registry) advanced from its state at t^n with
      the interface pressure going from p^n to the current estimate p^k, and the air pulse
      of the run's instrument (``loads/``) outside, by sub-steps, with its tissue law (``cornea/tissue.py``);
  (b) its position and velocity imposed on the fluid's interface nodes (Dirichlet), the globe's
      walls moved for it (``globe/``: rigid ones do nothing);
  (c) the fluid's density and interface pressure at t^{n+1}, the cornea's load (Neumann);
- then the converged state becomes the state at t^{n+1} (``commit``), the instrument's
  applanation signal is read from it (``readout.py``; the ORA's and the Corvis ST's), and a
  pulse that watches the eye (the ORA's) is told that signal.

The observers of a run (``solver.py``: the energy budget, the blow-up checks, the recorder) are
called by ``step`` after the coupling, with the state at t^n and the trial state at t^{n+1}
(``coupled``), and after the commit (``committed``).
"""

from __future__ import annotations

import numpy as np

from .cornea.apex import apex_curvature, apex_fit_nodes
from .cornea.build import cornea_for_run
from .cornea.reference import static_equilibrium
from .cornea.tissue import tissue_for_run
from .dirichlet_neumann import DirichletNeumann
from .fluid_stepper import STRAIN_LIMIT, FluidStepper
from .geometry import build_chamber, chamber_volume
from .globe import globe_for_run
from .globe.motion import eye_for_run, pulse_force
from .loads import pulse_for_run
from .params import RunParams
from .readout import readout_for_run
from .step_control import StepControl

P_REF = 1.0  # Pa: floor of the normalisation of the coupling residual (meaningful at rest)


class CoupledModel:
    """The parts and the state of one run; ``step()`` advances by one coupled time step.

    The cornea's state, SI units: nodes ``X, Y`` [m], ``VX, VY`` [m/s], apex first (the fluid's
    nodes ``cornea_nodes`` carry it); the fluid's is ``fluid`` (``x, y, vx, vy, rho`` are
    its arrays); time ``t`` [s].  ``reuse`` and ``strain_limit`` (default
    ``fluid_stepper.STRAIN_LIMIT``): see ``FluidStepper``.
    """

    def __init__(self, params: RunParams, reuse: bool = True, strain_limit=None):
        self.params = params
        si = self.si = params.si()
        ch = self.chamber = build_chamber(params.geometry, params.layout, params.resolution,
                                          si.R_m, si.r_post_m, si.alpha0_rad)
        self.jet = pulse_for_run(params, si, ch.phi_cornea)
        self.cornea = cornea_for_run(params, ch.phi_cornea)
        self.fluid = FluidStepper(si, ch, params.hyperviscosity_operator, reuse,
                                  STRAIN_LIMIT if strain_limit is None else strain_limit,
                                  params.hyperviscosity_interval,
                                  params.node_shifting_interval)
        self._start_cornea_at_rest()
        self.globe = globe_for_run(params, si, ch, self.X, self.Y, self.fluid.mass)
        self.globe.start(self.fluid.density_volume(), self.chamber_volume())
        # the cornea starts fully relaxed (E0 is the equilibrium modulus, docs/model.md section 10)
        self.tissue = tissue_for_run(si, self.cornea, self.X, self.Y)
        self.t = 0.0
        self.fluid.refresh_derivatives()
        self.control = StepControl(si, params.c_rule, self.fluid)
        # fluid pressure on the cornea [Pa], its load at t^n
        self.p_interface = np.empty(self.cornea_nodes.shape[0])
        self.fluid.interface_pressure(self.control.c, self.p_interface)
        # the instrument's applanation signal of the current state (NaN for the paper's jet)
        self.readout = readout_for_run(params.instrument, self.X)
        self.applanation_signal = self._read_signal()
        if self.jet.watches_applanation:
            self.jet.observe(self.t, self.applanation_signal)
        N = self.X.shape[0]
        self._cornea_trial = tuple(np.empty(N) for _ in range(4))  # X, Y, VX, VY in iterations
        self._p_interface_n = np.empty(N)  # interface pressure at t^n with this step's c [Pa]
        # (p^{n+1} - p^n) / dt [Pa/s] of the last ``hyperviscosity_interval`` steps, by the
        # step's place in the hyperviscosity's cycle (one array with the default interval 1)
        self._p_rates = [np.zeros(N) for _ in range(params.hyperviscosity_interval)]
        self._step_count = 0
        self._p_start = np.empty(N)  # the coupling's first estimate of p^{n+1} [Pa]
        self.coupling = DirichletNeumann(si.coupling_tol, params.max_coupling_iterations, N)
        self.last_substeps = 0
        self.max_cond = float(self.fluid.ops_n.cond.max())
        self._pulse_pressure = np.empty(N)  # Pa, the pulse on the cornea's nodes (pulse_force)
        # the whole eye's motion behind the cornea (globe/motion.py), driven by the pulse's force
        self.eye = eye_for_run(params, si)
        self.eye.start(self.pulse_force())

    def _start_cornea_at_rest(self):
        """The cornea starts in the exact discrete equilibrium under IOP (and p_a(0) with
        ``jet_start = equilibrium``); the fluid's interface nodes take its positions."""
        ch = self.chamber
        X0, Y0 = ch.x[ch.cornea_nodes].copy(), ch.y[ch.cornea_nodes].copy()
        q = np.full(X0.shape, self.si.p0_Pa)
        if self.params.jet_start == "equilibrium":
            jet_at_rest = np.empty_like(q)
            self.jet.pressures(0.0, ch.phi_cornea, jet_at_rest)
            q -= jet_at_rest
        X, Y, self.equilibrium_residual = static_equilibrium(self.cornea, X0, Y0, q)
        self.cornea.rest(X, Y)
        self.rest_shape_deviation = float(np.max(np.hypot(X - X0, Y - Y0)))
        self.X, self.Y = X, Y
        self.VX = np.zeros_like(X)
        self.VY = np.zeros_like(Y)
        self.fluid.x[ch.cornea_nodes] = X
        self.fluid.y[ch.cornea_nodes] = Y
        self.apex_y0 = Y[0]
        self.n_apex_fit = apex_fit_nodes(X)
        self.apex_acceleration = np.zeros(self.n_apex_fit)  # m/s^2, of the last step

    # -- one coupled step -------------------------------------------------------------------
    def step(self, t_stop=None, dt=None, observers=()):
        """Advance by one coupled step; dt [s] from the stability limits unless given, cut so
        that the step ends at ``t_stop`` [s].  Each of ``observers`` is told of the coupled
        step (``coupled(model, dt)``, before the commit) and of the new state
        (``committed(model, dt)``).  Returns dt."""
        dt = self.control.begin_step(self.t, t_stop, dt)
        c = self.control.c
        self.fluid.predict(dt, c, self.t, self.si.hyperviscosity, self.control.dt_hyperviscous)
        self.couple(dt)
        for observer in observers:
            observer.coupled(self, dt)
        self.commit(dt)
        for observer in observers:
            observer.committed(self, dt)
        return dt

    def couple(self, dt):
        """Dirichlet-Neumann iterations between the cornea and the predicted fluid, until the
        interface pressure settles; then the fluid's full velocity derivatives and density at
        t^{n+1} (into its work arrays).  Raises SimulationError on a blow-up or when the
        iterations do not converge."""
        c = self.control.c
        fluid, cornea, tissue, globe = self.fluid, self.cornea, self.tissue, self.globe
        n_sub = cornea.substeps(self.X, self.Y, dt)
        self.last_substeps = n_sub
        tissue.set_substep(dt / n_sub)
        # pressure at t^n with this step's c (the equation of state changes with c)
        p_interface_n = self._p_interface_n
        fluid.interface_pressure(c, p_interface_n)
        X, Y, VX, VY = self._cornea_trial
        jet = self.jet
        t = self.t

        def interface_pressure(p_est, p_new):
            X[:] = self.X
            Y[:] = self.Y
            VX[:] = self.VX
            VY[:] = self.VY
            cornea.advance(X, Y, VX, VY, p_interface_n, p_est, t, dt, n_sub, jet,
                           tissue.begin_trial(), tissue.viscoelastic)
            fluid.impose_cornea(X, Y, VX, VY)
            globe.impose(X, Y, VX, VY, c, dt, *fluid.trial_walls())
            fluid.new_density(dt, t, interface_only=True)
            return fluid.interface_pressure_change(c, P_REF, p_est, p_new)

        # the first estimate: p^n carried along the rate of change, dp/dt, of the last step in
        # the same place of the hyperviscosity's cycle (the last step with an interval of 1)
        p_rate = self._p_rates[self._step_count % len(self._p_rates)]
        self._step_count += 1
        p_start = self._p_start
        np.multiply(p_rate, dt, out=p_start)
        p_start += p_interface_n
        self.coupling.iterate(interface_pressure, p_start, t * 1e3)
        np.subtract(self.coupling.pressure, p_interface_n, out=p_rate)
        p_rate /= dt
        fluid.new_density(dt, t, interface_only=False)

    def commit(self, dt):
        """The coupled state becomes the state at t^{n+1} (buffers are swapped, not copied); the
        globe, the interface pressure and the speeds that set the next sound speed follow, and
        the instrument's applanation signal is read, and a pulse that watches the eye sees it."""
        self.tissue.commit()
        self.cornea.commit()
        n_fit = self.n_apex_fit
        self.apex_acceleration = (self._cornea_trial[3][:n_fit] - self.VY[:n_fit]) / dt
        cornea_n = (self.X, self.Y, self.VX, self.VY)
        self.X, self.Y, self.VX, self.VY = self._cornea_trial
        self._cornea_trial = cornea_n
        self.fluid.commit(dt)
        self.t += dt
        c = self.control.c
        self.globe.commit(self.fluid.density_volume(), self.cornea_chamber_volume(), dt, c,
                          self.fluid.rho)
        self.control.end_step(self.fluid.max_speed())
        self.fluid.interface_pressure(c, self.p_interface)
        self.eye.advance(dt, self.pulse_force)
        self.applanation_signal = self._read_signal()
        if self.jet.watches_applanation:
            self.jet.observe(self.t, self.applanation_signal)

    def _read_signal(self):
        """The instrument's applanation signal of the current state (``readout.py``), NaN
        without one."""
        return self.readout(self.X, self.Y) if self.readout is not None else float("nan")

    @property
    def trial_cornea(self):
        """(X, Y, VX, VY) of the cornea at t^{n+1} between ``couple`` and ``commit``."""
        return self._cornea_trial

    # -- the state's arrays, by their names in the equations ---------------------------------
    x = property(lambda self: self.fluid.x, lambda self, v: setattr(self.fluid, "x", v))
    y = property(lambda self: self.fluid.y, lambda self, v: setattr(self.fluid, "y", v))
    vx = property(lambda self: self.fluid.vx, lambda self, v: setattr(self.fluid, "vx", v))
    vy = property(lambda self: self.fluid.vy, lambda self, v: setattr(self.fluid, "vy", v))
    rho = property(lambda self: self.fluid.rho, lambda self, v: setattr(self.fluid, "rho", v))

    @property
    def cornea_nodes(self):
        return self.fluid.cornea_nodes

    @property
    def c(self):
        """The sound speed [m/s] of the last step."""
        return self.control.c

    def refresh_derivatives(self):
        """Recompute the fluid's operators and derivatives at the current state (after the state
        arrays were set from outside, e.g. by the stability analysis); the coupling's predictor
        starts again from p^n."""
        self.fluid.refresh_derivatives()
        for p_rate in self._p_rates:
            p_rate[:] = 0.0

    # -- quantities of the current state ----------------------------------------------------
    def apex_moment(self):
        """Meridional bending moment at the apex [N m/m], with the tissue's overstress."""
        return self.cornea.apex_moment(self.X, self.Y, self.tissue.overstress)

    def apex_curvature(self):
        """Apical curvature of the cornea [1/m], positive convex."""
        return apex_curvature(self.X, self.Y, self.n_apex_fit)

    def apex_displacement(self):
        """Inward displacement of the apex since t = 0 against the limbus [m]: the deflection."""
        return self.apex_y0 - self.Y[0]

    def apex_deformation(self):
        """Inward displacement of the apex since t = 0 as the instrument sees it [m]: the
        deflection plus the whole eye's movement away from the nozzle (0 with eye_motion=none)."""
        return self.apex_displacement() + self.eye.displacement

    def apex_deformation_velocity(self):
        """Inward velocity of the apex as the instrument sees it [m/s]: the apex's against the
        limbus plus the whole eye's."""
        return -self.VY[0] + self.eye.velocity

    def pulse_force(self):
        """The net axial force [N] of the air pulse on the cornea at the current state, positive
        away from the nozzle (``globe.motion.pulse_force``): what pushes the whole eye back."""
        self.jet.pressures(self.t, self.chamber.phi_cornea, self._pulse_pressure)
        return pulse_force(self.X, self.Y, self._pulse_pressure)

    def cornea_chamber_volume(self):
        """Volume of the chamber bounded by the cornea and the walls at rest [m^3]."""
        si = self.si
        return chamber_volume(self.params.geometry, self.X, self.Y, si.r_post_m, si.alpha0_rad)

    def chamber_volume(self):
        """Volume of the chamber bounded by the cornea and the walls [m^3]."""
        return self.cornea_chamber_volume() + self.globe.volume_change()

    def density_volume(self):
        """Chamber volume implied by the density field, sum m_j / rho_j [m^3]."""
        return self.fluid.density_volume()

    def pressure(self):
        """The fluid pressure field [Pa] at the current state, eq. (5) with the current c."""
        return self.fluid.pressure(self.control.c)

    def diagnostics(self):
        """What the run reports of its parts (besides the recorder's step statistics)."""
        return {
            "n_fluid": int(self.chamber.n),
            "n_cornea": int(self.X.shape[0]),
            **self.cornea.diagnostics(),
            **self.jet.diagnostics(),
            "rest_shape_deviation_mm": self.rest_shape_deviation * 1e3,
            "equilibrium_residual": self.equilibrium_residual,
            "max_moment_condition": self.max_cond,
            "hyperviscous_radius_per_gamma_c": self.control.hv_radius_max,
            "mass_kg": float(self.fluid.mass.sum()),
            "neighbour_searches": self.fluid.neighbours.searches,
            "operator_builds": self.fluid.operator_builds,
            "operator_strain_limit": self.fluid.strain_limit,
            "apex_fit_nodes": self.n_apex_fit,
            "acoustic_cfl": self.si.cfl,
        }
