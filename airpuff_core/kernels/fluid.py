"""Pointwise pieces of the axisymmetric weakly compressible Navier-Stokes equations (SI units).

    d rho/dt  = -rho ( dvx/dx + vx/x + dvy/dy )
    rho dvx/dt = -dp/dx + mu ( lap vx - vx/x^2 )
    rho dvy/dt = -dp/dy + mu lap vy,          lap f = f_xx + f_yy + f_x / x
    p = p0 + rho0 c^2 / gamma [ (rho/rho0)^gamma - 1 ]

On the axis (x = 0) the 1/x terms take their limits: vx/x -> dvx/dx, f_x/x -> f_xx, and vx = 0.
Only INTERIOR and AXIS nodes (``nodes.py``) integrate the momentum equation.
"""

import numpy as np
from numba import njit

from .nodes import AXIS, AXIS_EPS, INTERIOR


@njit(cache=True)
def _axisymmetric_divergence(x, vx, dvx_dx, dvy_dy):
    """dvx/dx + vx/x + dvy/dy [1/s], with the axis limit vx/x -> dvx/dx at x = 0."""
    if x < AXIS_EPS:
        return 2.0 * dvx_dx + dvy_dy
    return dvx_dx + dvy_dy + vx / x


@njit(cache=True)
def axisymmetric_divergence(nodes, x, vx, dvx, dvy, div):
    """div[i] = dvx/dx + vx/x + dvy/dy [1/s] at the listed nodes, from the derivative vectors
    ``dvx``, ``dvy`` (columns 0 = d/dx, 1 = d/dy)."""
    for i in nodes:
        div[i] = _axisymmetric_divergence(x[i], vx[i], dvx[i, 0], dvy[i, 1])


@njit(cache=True)
def _tait(rho, rho0, p0, b, gamma):
    """Equation of state (5) with b = rho0 c^2 / gamma: p = p0 + b [(rho/rho0)^gamma - 1]  [Pa]."""
    return p0 + b * ((rho / rho0) ** gamma - 1.0)


@njit(cache=True)
def tait_pressure(rho, rho0, p0, c, gamma, out):
    """Equation of state (5): p = p0 + rho0 c^2/gamma [(rho/rho0)^gamma - 1]  [Pa]."""
    b = rho0 * c * c / gamma
    for i in range(rho.shape[0]):
        out[i] = _tait(rho[i], rho0, p0, b, gamma)


@njit(cache=True)
def tait_pressure_at(nodes, rho, rho0, p0, c, gamma, out):
    """Equation of state (5) at the listed nodes only: out[k] = p(rho[nodes[k]])  [Pa]."""
    b = rho0 * c * c / gamma
    for k in range(nodes.shape[0]):
        out[k] = _tait(rho[nodes[k]], rho0, p0, b, gamma)


@njit(cache=True)
def advance_density(rho_from, rho_at, div, dt, extra, extra_dt, out):
    """out = rho_from - dt rho_at div + extra_dt * extra  (one explicit continuity update)."""
    for i in range(rho_from.shape[0]):
        out[i] = rho_from[i] - dt * rho_at[i] * div[i] + extra_dt * extra[i]


@njit(cache=True)
def advance_velocity(kind, x, vx, vy, grad_p, dvx, dvy, rho_half, rho_n, mu, dt, hv_x, hv_y,
                     vx_new, vy_new):
    """Mid-point velocity update of the paper (section 3), axisymmetric form:

        v^{n+1} = v^n - dt/rho^{n+1/2} grad p^{n+1/2} + dt mu/rho^n (viscous term)^n + dt HV(v^n)

    ``grad_p`` holds the pressure gradient (p_x, p_y) at n+1/2, ``dvx``/``dvy`` the derivative
    vectors of the velocity at n.  WALL and CORNEA nodes
    are left untouched (their velocity is imposed).
    """
    for i in range(x.shape[0]):
        k = kind[i]
        if k == INTERIOR:
            lap_vx, lap_vy = viscous_laplacian(i, k, x, vx, dvx, dvy)
            vx_new[i] = vx[i] + dt * (-grad_p[i, 0] / rho_half[i] + mu * lap_vx / rho_n[i] + hv_x[i])
            vy_new[i] = vy[i] + dt * (-grad_p[i, 1] / rho_half[i] + mu * lap_vy / rho_n[i] + hv_y[i])
        elif k == AXIS:
            _, lap_vy = viscous_laplacian(i, k, x, vx, dvx, dvy)
            vx_new[i] = 0.0
            vy_new[i] = vy[i] + dt * (-grad_p[i, 1] / rho_half[i] + mu * lap_vy / rho_n[i] + hv_y[i])


@njit(cache=True)
def viscous_laplacian(i, k, x, vx, dvx, dvy):
    """The viscous terms (lap v_x - v_x / x^2, lap v_y) [1/(m s)] at node i of kind k, from the
    derivative vectors ``dvx``, ``dvy``; on the axis (k = AXIS) f_x / x -> f_xx and v_x = 0."""
    if k == AXIS:
        return 0.0, 2.0 * dvy[i, 2] + dvy[i, 4]
    xi = x[i]
    return (dvx[i, 2] + dvx[i, 4] + dvx[i, 0] / xi - vx[i] / (xi * xi),
            dvy[i, 2] + dvy[i, 4] + dvy[i, 0] / xi)


@njit(cache=True)
def max_speed(vx, vy):
    m = 0.0
    for i in range(vx.shape[0]):
        s = vx[i] * vx[i] + vy[i] * vy[i]
        if s > m:
            m = s
    return np.sqrt(m)


@njit(cache=True)
def drift(x, y, vx, vy, tau, x_out, y_out):
    """x_out = x + tau vx, y_out = y + tau vy  [m] (a position update over tau [s])."""
    for i in range(x.shape[0]):
        x_out[i] = x[i] + tau * vx[i]
        y_out[i] = y[i] + tau * vy[i]


@njit(cache=True)
def impose_cornea(cornea, X, Y, VX, VY, x, y, vx, vy):
    """Dirichlet condition of the coupling: the fluid's interface nodes take the membrane's
    positions [m] and velocities [m/s]."""
    for k in range(cornea.shape[0]):
        i = cornea[k]
        x[i] = X[k]
        y[i] = Y[k]
        vx[i] = VX[k]
        vy[i] = VY[k]


@njit(cache=True)
def interface_pressure_change(cornea, rho, rho0, p0, c, gamma, p_ref, p_est, p_new):
    """Neumann side of the coupling: p_new = eq. (5) at the interface nodes [Pa], and the
    normalised change ||p_new - p_est|| / max(||p_est - p0||, p_ref) (RMS norms) that decides
    convergence."""
    b = rho0 * c * c / gamma
    change = 0.0
    size = 0.0
    for k in range(cornea.shape[0]):
        p = _tait(rho[cornea[k]], rho0, p0, b, gamma)
        p_new[k] = p
        change += (p - p_est[k]) ** 2
        size += (p_est[k] - p0) ** 2
    n = cornea.shape[0]
    return np.sqrt(change / n) / max(np.sqrt(size / n), p_ref)


@njit(cache=True)
def max_density_deviation(rho, rho0):
    """max_i |rho_i / rho0 - 1| (NaN if a density is not finite)."""
    m = 0.0
    for i in range(rho.shape[0]):
        d = abs(rho[i] / rho0 - 1.0)
        if not d <= m:
            if np.isnan(d):
                return np.nan
            m = d
    return m
