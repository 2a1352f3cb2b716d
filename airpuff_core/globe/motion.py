"""Whole-eye motion: the globe as a rigid body on a spring and damper behind it (``eye_motion``).

The air pulse pushes the whole eye back into the orbit while it dents the cornea; the Corvis ST
sees the sum (its deformation amplitude DA), and subtracts the eye's movement (its whole-eye
movement, WEM) to give the deflection amplitude.  The solver's cornea is clamped to a limbus that
does not move, so its apex displacement is the deflection.  ``eye_motion = spring_damper`` adds
the eye's axial displacement x(t) [m], positive away from the nozzle, as Kling et al. (PLoS ONE 9
(2014) e104904, table 3) model it: a rigid globe of mass m on the orbit's spring k and damper c,

    m x'' + c x' + k x = F(t),     x(0) = x'(0) = 0,

driven by the net axial force of the air pulse on the cornea, F = the pulse's pressure integrated
over the deformed cornea (``pulse_force``; the IOP is internal to the eye and adds nothing).

The eye's motion is integrated beside the coupled step and does not act back on it.  In the
eye's accelerating frame the fluid and the cornea feel the body force -rho a_eye; across the
chamber it changes the pressure by rho |a_eye| L.  docs/model.md section 14 gives the measured
bound (below 0.01 mmHg with Kling's values, against the jet's tens of mmHg at the applanations),
so the deflection is that of the eye at rest, and DA = deflection + x.

The step is the trapezoidal rule (Newmark's average acceleration, beta = 1/4, gamma = 1/2), second
order and unconditionally stable: with a_n = (F_n - c v_n - k x_n) / m,

    x_{n+1} = x_n + dt v_n + dt^2 (a_n + a_{n+1}) / 4,   v_{n+1} = v_n + dt (a_n + a_{n+1}) / 2,

solved for a_{n+1} (a linear equation).  The orbit's time constant m / c (75 us with Kling's
values and a 7.5 g eye) is far longer than the solver's step (a few us), so the rule is accurate
without sub-steps.
"""

from __future__ import annotations

import numpy as np

from ..kernels.membrane import add_pressure_loads


def pulse_force(X, Y, pulse_pressure):
    """The net axial force [N] of an outside pressure ``pulse_pressure`` [Pa] at the cornea's
    nodes (X, Y) [m] on the eye, positive away from the nozzle (-y):

        F = sum_k (lumped pressure load of node k)_y = integral p 2 pi x dx

    over the deformed cornea (``add_pressure_loads``' half-segment areas; for a uniform pressure p
    it is p pi x_limbus^2 exactly)."""
    Fx = np.zeros_like(X)
    Fy = np.zeros_like(Y)
    add_pressure_loads(X, Y, pulse_pressure, Fx, Fy)
    return float(Fy.sum())


class EyeAtRest:
    """``eye_motion = none`` (the paper's): the eye does not move."""

    displacement = 0.0  # m, away from the nozzle
    velocity = 0.0  # m/s
    acceleration = 0.0  # m/s^2

    def start(self, force):
        """Nothing to set up."""

    def advance(self, dt, force):
        """The eye stays where it is (``force`` is not evaluated)."""


class SpringDamperEye:
    """The globe as a rigid body of mass ``mass`` [kg] on a spring ``spring`` [N/m] and a damper
    ``damper`` [N s/m] (module docstring); state ``displacement`` [m] away from the nozzle,
    ``velocity`` [m/s], ``acceleration`` [m/s^2]."""

    def __init__(self, mass, spring, damper):
        self.mass, self.spring, self.damper = mass, spring, damper
        self.displacement = 0.0
        self.velocity = 0.0
        self.acceleration = 0.0

    def start(self, force):
        """The eye at rest under the force at t = 0 [N] (the pulse's small start, if any,
        accelerates it from rest)."""
        self.acceleration = force / self.mass

    def advance(self, dt, force):
        """One trapezoidal step of dt [s]; ``force()`` gives the force [N] at its end."""
        force = force()
        m, c, k = self.mass, self.damper, self.spring
        x, v, a = self.displacement, self.velocity, self.acceleration
        a_new = ((force - c * (v + 0.5 * dt * a) - k * (x + dt * v + 0.25 * dt * dt * a))
                 / (m + 0.5 * dt * c + 0.25 * dt * dt * k))
        self.displacement = x + dt * v + 0.25 * dt * dt * (a + a_new)
        self.velocity = v + 0.5 * dt * (a + a_new)
        self.acceleration = a_new


def eye_for_run(params, si):
    """The eye's motion of a run (``RunParams`` params, ``SIParams`` si)."""
    if params.eye_motion == "spring_damper":
        return SpringDamperEye(si.eye_mass_kg, si.eye_spring, si.eye_damper)
    return EyeAtRest()
