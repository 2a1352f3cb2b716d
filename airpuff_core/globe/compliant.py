"""The compliant globe: the chamber's walls as one volume degree of freedom with Friedenwald's law.

The paper's chamber is closed by rigid walls, so the only compliance the cornea meets is the
fluid's artificial compressibility, V / (rho c^2) (about 0.5 uL/mmHg at c = 10 m/s), which makes the
chamber's stiffness a numerical choice.  The living eye's pressure-volume law is Friedenwald's
(Friedenwald, Am. J. Ophthalmol. 20 (1937) 985):

    log10(P / P0) = K dV,   i.e.   dP/dV = ln(10) K P,

with the ocular rigidity K [1/uL] and dV the volume added to the globe (here: pushed in by the
cornea).  ``globe = compliant`` lets the rigid walls behind the fluid (the posterior sphere and the
lateral wall of the sector, the plane of the cap) recede so that the chamber as a whole obeys this
law, whatever the sound speed:

    chamber volume  V_ch(t) = V_ch0 + M (1/rho_bar(P) - 1/rho0),   P = P0 10^(K dV_c),

where dV_c = V_c0 - V_c(t) is the volume the cornea has pushed in, M the fluid mass and rho_bar(P)
the density of the equation of state at pressure P.  The fluid's mean density is then always the
density of the globe's pressure: the wall gives way by the indentation volume MINUS what the fluid
is compressed by, so the fluid's compressibility does not add to the globe's compliance, and
the mean pressure does not depend on c.  (In an incompressible fluid the wall would take exactly
dV_c.)  The wall's position is a function of the cornea's state, with no inertia, so it adds no
stiff mode and no coupling iteration; the fluid carries the acoustic and inertial deviations from
the mean.  On top of it the wall gives way under the fluid's acoustic pressure deviation
(``CompliantWall.commit``): a wall that only followed the cornea would feed the chamber's
acoustic mode.

The walls recede along the axis.  Every wall node moves by w(x) d in -y, with w = 1 on the
posterior sphere (x <= x_c = r_post sin alpha0) and falling linearly in x to 0 at the limbus x_l on
the lateral wall (``cap``: the plane, x_c = 0).  A vertical displacement of a surface of revolution
sweeps exactly the volume int 2 pi x w(x) dx d, so the chamber grows by A_eff d with

    A_eff = pi x_c^2 + 2 pi / (x_l - x_c) [x_l^3/6 - x_l x_c^2/2 + x_c^3/3]

(53 mm^2 in the paper's sector: a few uL move the walls by about a tenth of a millimetre; a radial
shrinking of the small posterior sphere alone, 8.9 uL behind it, would not have room).  The wall
stays no-slip: its nodes carry the wall's velocity.
"""

from __future__ import annotations

import math

import numpy as np

from ..kernels.fluid import tait_pressure_at
from ..kernels.membrane import cornea_polygon_volume, enclosed_volume_rate
from ..kernels.nodes import WALL

LN10 = math.log(10.0)
# s: time in which the wall makes up the fluid's volume drift (CompliantWall.commit); short
# against the puff (~20 ms), long against a solver step (~5 us)
DRIFT_RELAXATION_TIME = 0.1e-3
# s: time in which the walls' transmitted give returns (CompliantWall.commit); 1 ms let the
# chamber ring more (docs/model.md section 11)
GIVE_RELAXATION_TIME = 0.1e-3


def friedenwald_pressure(P0, rigidity_per_m3, dV):
    """P = P0 10^(K dV)  [Pa] for the volume dV [m^3] pushed into the globe (K in 1/m^3)."""
    return P0 * np.power(10.0, rigidity_per_m3 * dV)


def tait_density(P, rho0, p0, c, gamma):
    """Density [kg/m^3] at which the equation of state (5) gives the pressure P [Pa]:
    rho = rho0 (1 + gamma (P - p0) / (rho0 c^2))^(1/gamma)."""
    return rho0 * (1.0 + gamma * (P - p0) / (rho0 * c * c)) ** (1.0 / gamma)


def swept_area(x_c, x_l):
    """A_eff [m^2]: volume swept per metre of axial wall displacement (module docstring)."""
    return math.pi * x_c ** 2 + 2.0 * math.pi / (x_l - x_c) * (
        x_l ** 3 / 6.0 - x_l * x_c ** 2 / 2.0 + x_c ** 3 / 3.0)


def wall_weights(x_wall, x_c, x_l):
    """The share w(x) [1] of the axial displacement of wall nodes at distances ``x_wall`` [m] from
    the axis (module docstring), and the weights of the mean wall pressure: the swept volume each
    node stands for, ~ w x, normalised."""
    weight = np.clip((x_l - x_wall) / (x_l - x_c), 0.0, 1.0)
    swept = weight * x_wall
    return weight, swept / swept.sum()


class CompliantWall:
    """The receding walls of the chamber (SI units): one volume degree of freedom.

    ``nodes``: indices of the wall nodes; ``weight``: their share w(x) of the axial displacement d;
    ``y0``: their reference heights; ``area``: A_eff.
    """

    def __init__(self, x, y, wall_nodes, x_c, x_l, rigidity_per_m3, p0, rho0, mass, gamma,
                 drift_rate_time=0.0, give_speed=0.0):
        self.nodes = np.asarray(wall_nodes)
        self.weight, self.pressure_weight = wall_weights(x[self.nodes], x_c, x_l)
        self.y0 = y[self.nodes].copy()
        self.area = swept_area(x_c, x_l)
        self.rigidity = rigidity_per_m3
        self.p0, self.rho0, self.gamma = p0, rho0, gamma
        self.mass = float(np.sum(mass))
        self.displacement = 0.0  # d [m], positive backwards (-y)
        self.speed = 0.0  # dd/dt [m/s]
        self.pressure = p0  # the globe's pressure P [Pa]
        self.sound_speed = None  # c [m/s] of the last accepted step
        # make-up for the fluid's volume drift (``commit``)
        self.volume_offset = 0.0
        self.drift_displacement = 0.0
        self.drift_speed = 0.0
        # feed-forward of the drift's rate (``commit``): its filter time [s] (0: off), the drift
        # of the last step [m of wall displacement] and the filtered rate [m/s]
        self.drift_rate_time = drift_rate_time
        self.last_drift_target = None
        self.drift_rate = 0.0
        # the wall's give under the fluid's acoustic pressure deviation (``commit``), and the
        # speed c_g [m/s] of its return time GIVE_RELAXATION_TIME c_g / c (0: that time itself)
        self.transmitted_displacement = 0.0
        self.transmitted_speed = 0.0
        self.give_speed = give_speed

    def wall_state(self, cornea_volume_change, cornea_volume_rate, c, dt):
        """Displacement d [m], its rate [m/s] and the globe's pressure P [Pa] at the end of a step
        dt [s] for a cornea whose enclosed volume has changed by ``cornea_volume_change`` [m^3]
        (negative when pushed in), at the rate ``cornea_volume_rate`` [m^3/s], with the sound
        speed c [m/s]:

            A_eff d = -dV_cornea + M (1/rho_bar(P) - 1/rho0) + A_eff d_drift,
            P = P0 10^(-K dV_cornea)

        d_drift makes up for the fluid's volume drift (``commit``).  A change of c from the
        last step (the running-maximum rule) moves the law's wall too: its rate is added to the
        speed, so that the fluid sees it.
        """
        dv_in = -cornea_volume_change
        P = friedenwald_pressure(self.p0, self.rigidity, dv_in)
        rho_bar = tait_density(P, self.rho0, self.p0, c, self.gamma)
        swept = dv_in + self.mass * (1.0 / rho_bar - 1.0 / self.rho0)
        c_prev = c if self.sound_speed is None else self.sound_speed
        rho_prev = tait_density(P, self.rho0, self.p0, c_prev, self.gamma)
        swept_c_rate = self.mass * (1.0 / rho_bar - 1.0 / rho_prev) / dt if dt > 0.0 else 0.0
        # d(1/rho)/dP = -1 / (rho^2 dP/drho),  dP/drho = c^2 (rho/rho0)^(gamma - 1)
        dinv_dP = -1.0 / (rho_bar * rho_bar * c * c * (rho_bar / self.rho0) ** (self.gamma - 1.0))
        dP_dt = LN10 * self.rigidity * P * (-cornea_volume_rate)
        swept_rate = -cornea_volume_rate + self.mass * dinv_dP * dP_dt + swept_c_rate
        extra = self.drift_displacement + self.transmitted_displacement
        extra_speed = self.drift_speed + self.transmitted_speed
        return (swept / self.area + extra + extra_speed * dt, swept_rate / self.area + extra_speed,
                float(P))

    def commit(self, state, fluid_volume, chamber_volume, dt, c, wall_pressure):
        """Accept the wall state of a step of dt [s] with the sound speed c [m/s], and update the
        drift make-up and the transmitted give.

        Transmitted give: the law above places the wall for the cornea's state, whatever the
        fluid does at the wall, so the wall would reflect every acoustic wave that reaches it and,
        moving with the cornea, feed the chamber's acoustic mode (it does work on the fluid
        beyond what the globe's law stores).  The chamber is cut out of a larger eye: behind the
        wall lies the same fluid (the vitreous), into which a wave passes on.  The wall therefore
        also gives way at the particle velocity of a plane wave carrying the deviation of the
        fluid's mean wall pressure ``wall_pressure`` [Pa] from the globe's pressure P,

            u_t = (p_wall - P) / (rho0 c),

        the characteristic (transmitting) boundary condition of the acoustic equations (Engquist
        and Majda, Math. Comp. 31 (1977) 629), taken over the next step.  It absorbs power
        (p_wall - P)^2 A_eff / (rho0 c) >= 0, so the wall can no longer feed a mode, and it has
        no parameter: the impedance rho0 c is the fluid's own.  At rest and in slow motion
        p_wall = P and u_t = 0, so the globe's law is kept.

        Drift make-up: the fluid's own volume, sum m_j/rho_j (``fluid_volume`` [m^3]), drifts from the chamber's
        geometric volume (``chamber_volume``, with the wall at ``state``) by the discretisation
        error of the continuity equation at the moving cornea: about 0.5 % of the volume pushed
        in at coarse resolution.  Its pressure error, rho c^2 / V times that, grows with c^2.  The
        wall therefore gives way by that drift less: d_drift relaxes to -drift / A_eff within
        DRIFT_RELAXATION_TIME, moving at its rate, so that the fluid sees the make-up through
        its velocity like any wall motion.  (Moving the nodes without a velocity would not
        change the density and would feed the drift back; following the drift within one step
        amplifies the fluid's step-to-step noise.)

        The make-up lags the drift by about DRIFT_RELAXATION_TIME times its rate Q, and the fluid
        then holds the volume Q DRIFT_RELAXATION_TIME too little or too much: a mean pressure
        error rho c^2 Q DRIFT_RELAXATION_TIME / V_chamber, which grows with c^2 (docs/model.md
        section 11).  With ``drift_rate_time`` > 0 (the run parameter ``wall_drift_feedforward``)
        the wall also moves at the drift's own rate, low-pass filtered over that time, so that
        the make-up no longer lags a steady drift.
        """
        self.displacement, self.speed, self.pressure = state
        self.sound_speed = c
        drift = fluid_volume - chamber_volume - self.volume_offset
        target = -drift / self.area
        self.drift_displacement += self.drift_speed * dt
        self.drift_speed = (target - self.drift_displacement) / DRIFT_RELAXATION_TIME
        if self.drift_rate_time > 0.0:
            if self.last_drift_target is not None and dt > 0.0:
                step_rate = (target - self.last_drift_target) / dt
                self.drift_rate += (step_rate - self.drift_rate) * min(1.0, dt / self.drift_rate_time)
            self.last_drift_target = target
            self.drift_speed += self.drift_rate
        self.transmitted_displacement += self.transmitted_speed * dt
        self.transmitted_speed = ((wall_pressure - self.pressure) / (self.rho0 * c)
                                  - self.transmitted_displacement / self.give_relaxation_time(c))

    def give_relaxation_time(self, c):
        """The return time tau [s] of the transmitted give at the sound speed c [m/s]:
        GIVE_RELAXATION_TIME, or with ``give_speed`` c_g > 0 (the run parameter
        ``wall_give_speed``) GIVE_RELAXATION_TIME c_g / c, the time a wave takes to cross the
        fixed length c_g GIVE_RELAXATION_TIME.

        Why: in slow motion the fluid's mean wall pressure is not the globe's pressure P (the
        flow's inertial pressure, dp = p_wall - P, about 0.4 mmHg at the deepest point of an IOP
        10 puff), and a steady dp holds the give at dV = A_eff tau dp / (rho0 c).  The fluid
        then holds that much more volume than the law gives it, so its mean pressure stands off
        P by about rho0 c^2 dV / V_chamber = (c tau A_eff / V_chamber) dp, which grows like c
        with a fixed tau, and is (c_g GIVE_RELAXATION_TIME A_eff / V_chamber) dp, independent
        of c, with this scaling.  The dashpot rho0 c is unchanged, and the spring's return is
        the same fraction of the chamber's acoustic period (which falls like 1/c) at every c
        (docs/model.md section 11)."""
        if self.give_speed > 0.0:
            return GIVE_RELAXATION_TIME * self.give_speed / c
        return GIVE_RELAXATION_TIME

    def impose(self, d, speed, y, vx, vy):
        """Heights [m] and velocities [m/s] of the wall nodes for the displacement d."""
        y[self.nodes] = self.y0 - self.weight * d
        vx[self.nodes] = 0.0
        vy[self.nodes] = -self.weight * speed

    def mean_pressure(self, p_wall):
        """Mean pressure [Pa] on the walls from the pressures ``p_wall`` [Pa] of the wall nodes
        (in the order of ``nodes``), weighted by the volume each node sweeps."""
        return float(np.dot(self.pressure_weight, p_wall))


def wall_span(si, geometry):
    """(x_c, x_l) [m]: where the walls' share of the displacement starts to fall (the posterior
    sphere's rim; 0 for the cap's plane) and the limbus, where it reaches 0."""
    x_l = si.R_m * math.sin(si.alpha0_rad)
    x_c = si.r_post_m * math.sin(si.alpha0_rad) if geometry == "sector" else 0.0
    return x_c, x_l


class WallPressure:
    """The fluid's mean pressure on the walls behind it, weighted by the volume each wall node
    sweeps when the globe is compliant (``wall_weights``), for either globe."""

    def __init__(self, si, geometry, chamber):
        x_c, x_l = wall_span(si, geometry)
        self.nodes = np.flatnonzero(chamber.kind == WALL)
        self.weight = wall_weights(chamber.x[self.nodes], x_c, x_l)[1]
        self.rho0, self.p0, self.gamma = si.rho_fluid, si.p0_Pa, si.tait_gamma
        self._pressure = np.empty(self.nodes.shape[0])  # work array [Pa]

    def mean(self, rho, c):
        """The mean wall pressure [Pa] of the density field rho with the sound speed c [m/s]."""
        tait_pressure_at(self.nodes, rho, self.rho0, self.p0, c, self.gamma, self._pressure)
        return float(np.dot(self.weight, self._pressure))


class CompliantGlobe:
    """The globe of ``globe = compliant`` in the coupled step: the ``CompliantWall`` moved by the
    volume the cornea encloses and by the fluid's acoustic pressure on it, its trial state in the
    coupling iterations, and the work of the fluid on it.  The same methods as ``RigidGlobe``."""

    def __init__(self, si, geometry, chamber, X, Y, mass):
        """``si``: SIParams; ``geometry``: sector or cap; ``chamber``: the Chamber; (X, Y) [m]: the
        cornea at rest; ``mass``: the fluid nodes' masses [kg]."""
        # the closing point of the polygon whose volume the cornea encloses
        self.volume_axis_y = 0.0 if geometry == "sector" else float(Y[-1])
        self.cornea_volume0 = cornea_polygon_volume(X, Y, self.volume_axis_y)
        self.walls = WallPressure(si, geometry, chamber)
        self.wall = CompliantWall(chamber.x, chamber.y, self.walls.nodes, *wall_span(si, geometry),
                                  si.ocular_rigidity_per_m3, si.p0_Pa, si.rho_fluid, mass,
                                  si.tait_gamma, si.wall_drift_feedforward_s,
                                  si.wall_give_speed)
        self._trial = None

    def start(self, fluid_volume, chamber_volume):
        """At rest: the fluid's volume sum m/rho and the chamber's [m^3] set the make-up of the
        volume drift (``CompliantWall.volume_offset``)."""
        self.wall.volume_offset = fluid_volume - chamber_volume

    def impose(self, X, Y, VX, VY, c, dt, y, vx, vy):
        """Move the walls where the globe's law puts them for the trial cornea state
        (X, Y, VX, VY) at t^{n+1}, into the trial fluid state (y, vx, vy), with the sound
        speed c [m/s] of a step of dt [s]."""
        volume_change = cornea_polygon_volume(X, Y, self.volume_axis_y) - self.cornea_volume0
        volume_rate = enclosed_volume_rate(X, Y, VX, VY, self.volume_axis_y)
        self._trial = self.wall.wall_state(volume_change, volume_rate, c, dt)
        self.wall.impose(self._trial[0], self._trial[1], y, vx, vy)

    def work(self, rho_n, rho_new, c):
        """Work [J] of the fluid on the walls over the step just coupled: the mean wall pressure
        of its two ends (densities rho_n, rho_new) times the volume the walls gave way by."""
        wall = self.wall
        p_start = self.walls.mean(rho_n, c)
        p_end = self.walls.mean(rho_new, c)
        return 0.5 * (p_start + p_end) * wall.area * (self._trial[0] - wall.displacement)

    def commit(self, fluid_volume, cornea_chamber_volume, dt, c, rho):
        """Accept the trial walls of a step of dt [s]: ``fluid_volume`` sum m/rho [m^3] of the
        new state, ``cornea_chamber_volume`` the chamber's volume [m^3] with the walls at rest,
        ``rho`` the new density field, whose mean wall pressure sets the transmitted give."""
        self.wall.displacement = self._trial[0]
        self.wall.commit(self._trial, fluid_volume, cornea_chamber_volume + self.volume_change(),
                         dt, c, self.walls.mean(rho, c))

    def wall_pressure(self, rho, c):
        """The fluid's mean pressure on the walls [Pa] (``WallPressure``)."""
        return self.walls.mean(rho, c)

    def volume_change(self):
        """Volume [m^3] by which the walls have given way."""
        return self.wall.area * self.wall.displacement

    def pressure(self):
        """The pressure [Pa] of the globe's law for the volume the cornea has pushed in."""
        return self.wall.pressure
