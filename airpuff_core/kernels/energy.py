"""Energies and powers of the coupled system, for the energy budget of a run (SI units: J, W).

Gauge pressures throughout (the atmosphere is the zero of the jet and of the fluid's p0), so the
work of the IOP on a moving cornea appears once in the cornea's strain energy and once, with the
opposite sign, in the fluid's compression energy.

Fluid compression energy per unit mass, for the equation of state (5) with B = rho0 c^2 / gamma:

    e(rho) = int_{rho0}^{rho} p(r) / r^2 dr
           = (p0 - B) (1/rho0 - 1/rho) + B / (rho0^gamma (gamma - 1)) (rho^(gamma-1) - rho0^(gamma-1))
"""

from numba import njit

from .fluid import viscous_laplacian
from .membrane import add_pressure_loads
from .nodes import AXIS, INTERIOR


@njit(cache=True)
def kinetic_energy(mass, vx, vy):
    """1/2 sum m (vx^2 + vy^2) [J] (masses of revolution [kg], velocities [m/s])."""
    e = 0.0
    for i in range(mass.shape[0]):
        e += 0.5 * mass[i] * (vx[i] * vx[i] + vy[i] * vy[i])
    return e


@njit(cache=True)
def compression_energy(mass, rho, rho0, p0, c, gamma):
    """sum m e(rho) [J], e(rho) of the module docstring (zero at rho = rho0)."""
    B = rho0 * c * c / gamma
    a = B / (rho0 ** gamma * (gamma - 1.0))
    base = rho0 ** (gamma - 1.0)
    e = 0.0
    for i in range(mass.shape[0]):
        e += mass[i] * ((p0 - B) * (1.0 / rho0 - 1.0 / rho[i]) + a * (rho[i] ** (gamma - 1.0) - base))
    return e


@njit(cache=True)
def compression_energy_change(mass, rho, rho0, p0, c_old, c_new, gamma):
    """(sum m e(rho) at c_new) - (the same at c_old) [J]: ``compression_energy`` at both sound
    speeds in one pass over the nodes (each sum formed exactly as ``compression_energy`` forms
    it, so the result is its two calls' difference bit for bit)."""
    B_old = rho0 * c_old * c_old / gamma
    a_old = B_old / (rho0 ** gamma * (gamma - 1.0))
    B_new = rho0 * c_new * c_new / gamma
    a_new = B_new / (rho0 ** gamma * (gamma - 1.0))
    base = rho0 ** (gamma - 1.0)
    e_old = 0.0
    e_new = 0.0
    for i in range(mass.shape[0]):
        inverse_change = 1.0 / rho0 - 1.0 / rho[i]
        power_change = rho[i] ** (gamma - 1.0) - base
        e_old += mass[i] * ((p0 - B_old) * inverse_change + a_old * power_change)
        e_new += mass[i] * ((p0 - B_new) * inverse_change + a_new * power_change)
    return e_new - e_old


@njit(cache=True)
def fluid_dissipation_power(kind, x, vx_n, vy_n, vx_new, vy_new, dvx, dvy, rho_n, mu, hv_vx, hv_vy,
                            mass, p, hv_rho):
    """Rate [W] at which the viscous and hyperviscous terms remove mechanical energy from the
    fluid in one step, with the step's mean velocities v_avg = (v^n + v^{n+1}) / 2 [m/s]: the update of
    the nodes that integrate momentum is v^{n+1} - v^n = dt (a_p + a_visc + a_hv), so
    m (v^{n+1} + v^n)/2 . dt a is exactly each term's share of the change of kinetic energy.

        D = - sum m v_avg . (mu lap v / rho^n + HV(v))  - sum m p / rho^2 HV(rho)

    (the last term: the hyperviscous change of density, d(m e)/drho = m p / rho^2).  ``dvx``,
    ``dvy`` are the derivative vectors of the velocity at t^n (the ones the update used).
    Returns (viscous, hyperviscous) dissipation rates."""
    visc = 0.0
    hyper = 0.0
    for i in range(x.shape[0]):
        k = kind[i]
        if k == INTERIOR or k == AXIS:  # the nodes that integrate momentum
            vx_avg = 0.5 * (vx_n[i] + vx_new[i])
            vy_avg = 0.5 * (vy_n[i] + vy_new[i])
            lap_vx, lap_vy = viscous_laplacian(i, k, x, vx_n, dvx, dvy)
            visc -= mass[i] * mu / rho_n[i] * (vx_avg * lap_vx + vy_avg * lap_vy)
            hyper -= mass[i] * (vx_avg * hv_vx[i] + vy_avg * hv_vy[i])
        hyper -= mass[i] * p[i] / (rho_n[i] * rho_n[i]) * hv_rho[i]
    return visc, hyper


@njit(cache=True)
def pressure_load_work(X0, Y0, X1, Y1, q0, q1, F0x, F0y, F1x, F1y):
    """Work [J] of the lumped loads of a net inside pressure over one step, by the trapezoidal
    rule: 1/2 sum (F(X0, q0) + F(X1, q1)) . (X1 - X0), F the loads of ``add_pressure_loads``
    (F0x ... F1y are work arrays)."""
    for i in range(X0.shape[0]):
        F0x[i] = 0.0
        F0y[i] = 0.0
        F1x[i] = 0.0
        F1y[i] = 0.0
    add_pressure_loads(X0, Y0, q0, F0x, F0y)
    add_pressure_loads(X1, Y1, q1, F1x, F1y)
    w = 0.0
    for i in range(X0.shape[0]):
        w += 0.5 * ((F0x[i] + F1x[i]) * (X1[i] - X0[i]) + (F0y[i] + F1y[i]) * (Y1[i] - Y0[i]))
    return w
