"""Step control of the coupled step: the artificial sound speed and the time-step limits (SI).

Each step takes the sound speed of its rule (``c_rule``, docs/model.md section 4),

    c = c0 + c_slope v_max   (v_max of the last step, or the running maximum; or c = c0),

and the step dt = min(acoustic, viscous) limit,

    dt <= cfl h_min / (c + v_max),     dt <= VISCOUS_SAFETY rho_min h_min^2 / mu,

while the stiff hyperviscosity gamma c h^5 H is sub-cycled within it below its own forward-Euler
limit HV_SAFETY / (gamma c rho(h^5 H)), rho(.) the spectral radius, found by power iteration and
refreshed as the nodes move.
"""

from __future__ import annotations

import math

# forward-Euler step of the HV <= HV_SAFETY / (spectral radius of the HV operator), below the
# forward-Euler limit 2 (docs/model.md section 4); the Runge-Kutta-Legendre stages keep the same
# margin.
HV_SAFETY = 1.4
HV_POWER_ITERATIONS = 2  # power iterations per refresh, warm-started (the mode changes slowly)
HV_REFRESH_STEPS = 4  # steps between refreshes (nodes move < 1 % of a spacing in between)
HV_MARGIN = 1.1  # a warm-started power iteration may underestimate the radius slightly
HV_START_ITERATIONS = 60  # power iterations of the first estimate, from a random start
# dt <= VISCOUS_SAFETY rho h_min^2 / mu: the viscous term is forward Euler in the mid-point scheme.
# The limit of the MFPM operator (eigenvalues of the axisymmetric viscous matrix,
# ``stability.forward_euler_viscous_limit``) is 0.547 (v_x) / 0.579 (v_y) at coarse and paper
# resolution; 0.2 keeps a margin of 2.7 for nodes that the flow pushes together (nearest-neighbour
# spacing down to 0.69 h) and keeps the time error small where this limit sets the step
# (docs/model.md section 4).
VISCOUS_SAFETY = 0.2


def sound_speed(rule, c0, c_slope, v_prev, v_running):
    """Artificial sound speed [m/s]: c = c0 + c_slope v_max (docs/model.md section 4,
    ``c_rule``)."""
    if rule == "fixed":
        return c0
    if rule == "per_step":
        return c0 + c_slope * v_prev
    return c0 + c_slope * v_running


class StepControl:
    """The sound speed ``c`` [m/s] and the time-step limits of one run (``SIParams`` si, the
    ``c_rule``), for the ``FluidStepper`` ``fluid`` (whose operators at t^n give the
    hyperviscosity's spectral radius)."""

    def __init__(self, si, c_rule, fluid):
        self.rule = c_rule
        self.c0, self.c_slope = si.c0, si.c_slope
        self.cfl, self.mu, self.hyperviscosity = si.cfl, si.mu, si.hyperviscosity
        self.fluid = fluid
        self.h_min = fluid.h_min
        self.v_prev = 0.0  # largest fluid speed of the last step [m/s]
        self.v_running = 0.0  # largest fluid speed so far [m/s]
        # the hyperviscosity's stability limit is its stiffer operator's (on the velocity
        # times its strength relative to the density's), each with its own warm-started
        # stiffest mode
        self._hv_kinds = sorted({fluid.hv_consistent_density, fluid.hv_consistent_velocity})
        self.hv_modes = {}
        self.hv_radii = {k: self._hv_spectral_radius(k, None, HV_START_ITERATIONS)
                         for k in self._hv_kinds}
        self.hv_radius_unit = self._hv_radius(self.c0)
        self.hv_radius_max = self.hv_radius_unit
        self._hv_age = 0
        self._hv_builds = fluid.operator_builds  # the HV operator's build of the estimate
        self.c = sound_speed(c_rule, self.c0, self.c_slope, 0.0, 0.0)
        self.dt_hyperviscous = math.inf  # s, stability limit of the hyperviscosity
        self.dt_limits = {}  # s: the acoustic and viscous limits of the last step

    def begin_step(self, t, t_stop=None, dt=None):
        """The sound speed and dt [s] of the step from t [s]: the stable dt unless given, cut so
        that the step ends at ``t_stop`` [s]."""
        self.c = sound_speed(self.rule, self.c0, self.c_slope, self.v_prev, self.v_running)
        dt_stable = self.time_step()
        if dt is None:
            dt = dt_stable
        if t_stop is not None and t + dt > t_stop:
            dt = max(t_stop - t, 1e-12)
        return dt

    def end_step(self, v_max):
        """Take in the largest fluid speed v_max [m/s] of the new state."""
        self.v_prev = v_max
        self.v_running = max(self.v_running, v_max)

    def time_step(self):
        """dt [s] from the acoustic CFL condition, dt <= cfl h_min / (c + v_max), and the viscous
        limit, dt <= VISCOUS_SAFETY rho_min h_min^2 / mu; also refreshes the hyperviscosity's
        stability limit ``dt_hyperviscous``, which the predictor meets by sub-cycling.  The
        two limits that set dt are kept in ``dt_limits`` [s]."""
        fluid = self.fluid
        vmax = fluid.max_speed()
        dt_acoustic = self.cfl * self.h_min / (self.c + vmax)
        dt_viscous = (VISCOUS_SAFETY * float(fluid.rho.min()) * self.h_min ** 2 / self.mu
                      if self.mu > 0 else math.inf)
        self.dt_hyperviscous = self._hyperviscous_limit()
        self.dt_limits = {"acoustic": dt_acoustic, "viscous": dt_viscous}
        return min(dt_acoustic, dt_viscous)

    def max_step(self):
        """An upper bound [s] of the next step's dt: its acoustic limit cfl h_min / (c + v_max),
        with the sound speed c its rule gives and the largest fluid speed v_max of the state
        that ``end_step`` took in, the same figures ``time_step`` will use (infinite when both
        are 0).  The viscous limit and a cut at ``t_stop`` only shorten the step."""
        c = sound_speed(self.rule, self.c0, self.c_slope, self.v_prev, self.v_running)
        return self.cfl * self.h_min / (c + self.v_prev) if c + self.v_prev > 0 else math.inf

    def _hyperviscous_limit(self):
        """Largest stable forward-Euler step [s] of the hyperviscosity gamma c h^5 H."""
        gamma = self.hyperviscosity
        if gamma <= 0:
            return math.inf
        # the stiffest hyperviscous mode moves with the nodes: refresh the estimate
        self._hv_age += 1
        fluid = self.fluid
        # a kept (mapped) operator changes only when rebuilt: then its radius is refreshed at once
        due = self._hv_age >= HV_REFRESH_STEPS or fluid.lagrangian
        if due and fluid.operator_builds != self._hv_builds:
            self._hv_age = 0
            self._hv_builds = fluid.operator_builds
            self.hv_radii = {k: self._hv_spectral_radius(k, self.hv_modes[k],
                                                         HV_POWER_ITERATIONS)
                             for k in self._hv_kinds}
        self.hv_radius_unit = self._hv_radius(self.c)
        self.hv_radius_max = max(self.hv_radius_max, self.hv_radius_unit)
        return HV_SAFETY / (gamma * fluid.density_hyperviscosity_speed(self.c)
                            * self.hv_radius_unit * HV_MARGIN)

    def _hv_radius(self, c):
        """Spectral radius of the hyperviscosity per unit gamma c [1/s per m/s] at sound speed c
        [m/s]: the larger of the density's and the velocity's operator, the latter times its
        relative strength (``FluidStepper.velocity_hyperviscosity_factor``)."""
        fluid = self.fluid
        factor = fluid.velocity_hyperviscosity_factor(c)
        density = self.hv_radii[fluid.hv_consistent_density]
        velocity = self.hv_radii[fluid.hv_consistent_velocity]
        return max(density, velocity * factor) if factor > 0 else density

    def _hv_spectral_radius(self, consistent, start, iterations):
        """Spectral radius of h^5 H (H = K^* L K if ``consistent``, else L^3) [1/s per c], by
        power iteration from ``start``; keeps the mode for the next refresh."""
        radius, self.hv_modes[consistent] = self.fluid.ops_n.hyperviscous_spectral_radius(
            self.fluid.hv_scale_unit, start, iterations, consistent)
        return radius
