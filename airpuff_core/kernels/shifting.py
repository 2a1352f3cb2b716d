"""Node shifting: the fluid nodes moved off their streamlines towards a regular cloud (docs/model.md
section 4, "Node shifting"; Lind et al., J. Comput. Phys. 231 (2012) 1499; Sun et al., J. Comput.
Phys. 340 (2017) 439), SI units.

The nodes' concentration C_i = sum_j A_j W(|r_i - r_j|, R_i) (A_j the node area in the meridian
plane [m^2], W the 2-D Wendland C2 kernel of support R_i = kappa h_i, mirror images across the axis
included) is near 1 on a regular cloud; a node the flow squeezed towards its neighbours sits on a
gradient of C, and is moved down it:

    dr_i = -A h_i (v_max dt) (grad C_i - grad C_i^0),

with grad C_i^0 that of node i in the initial cloud (so that a cloud as regular as the initial one
is not moved, also beside the walls), A the option ``node_shifting``, v_max dt the distance the
fastest node moved in the step (the shift keeps pace with the distortion the flow makes), and
|dr_i| at most ``limit`` h_i.  Only INTERIOR and AXIS nodes with no WALL or CORNEA node in their
support move, AXIS nodes along the axis only, and no node across the axis.
"""

import math

from numba import njit

from .nodes import AXIS, CORNEA, INTERIOR, WALL


@njit(cache=True)
def concentration_gradient(x, y, h, area, kappa, start, nbr, sign, count, out):
    """out[i] = grad C_i [1/m] (module docstring) over node i's support pairs ``start[i]`` ...
    ``start[i] + count[i] - 1`` (``nbr``, ``sign`` -1.0 for a mirror image): W(q) = 7/(pi R^2)
    (1 - q)^4 (1 + 4 q), q = r/R < 1, so grad_i W = -20 q (1 - q)^3 7/(pi R^3) (r_i - r_j)/r."""
    for i in range(x.shape[0]):
        support = kappa * h[i]
        scale = 7.0 / (math.pi * support ** 3)
        gx = 0.0
        gy = 0.0
        for p in range(start[i], start[i] + count[i]):
            j = nbr[p]
            dx = x[i] - sign[p] * x[j]
            dy = y[i] - y[j]
            r = math.sqrt(dx * dx + dy * dy)
            q = r / support
            if q >= 1.0 or r == 0.0:
                continue
            slope = -20.0 * q * (1.0 - q) ** 3 * scale * area[j] / r
            gx += slope * dx
            gy += slope * dy
        out[i, 0] = gx
        out[i, 1] = gy


@njit(cache=True)
def shift_displacements(x, kind, h, grad, grad_initial, strength, limit, start, nbr, count,
                        dx_out, dy_out):
    """dx_out, dy_out [m] = dr_i of the module docstring with ``strength`` = A v_max dt [m] and
    |dr_i| <= limit h_i; zero at nodes that do not move (WALL, CORNEA, and nodes with one of
    them in their support)."""
    for i in range(x.shape[0]):
        dx_out[i] = 0.0
        dy_out[i] = 0.0
        if kind[i] != INTERIOR and kind[i] != AXIS:
            continue
        movable = True
        for p in range(start[i], start[i] + count[i]):
            k = kind[nbr[p]]
            if k == WALL or k == CORNEA:
                movable = False
                break
        if not movable:
            continue
        sx = -strength * h[i] * (grad[i, 0] - grad_initial[i, 0])
        sy = -strength * h[i] * (grad[i, 1] - grad_initial[i, 1])
        if kind[i] == AXIS or x[i] + sx <= 0.0:
            sx = 0.0
        size = math.sqrt(sx * sx + sy * sy)
        if size > limit * h[i]:
            sx *= limit * h[i] / size
            sy *= limit * h[i] / size
        dx_out[i] = sx
        dy_out[i] = sy


@njit(cache=True)
def shift_nodes(dx, dy, kind, grad_rho, dvx, dvy, x, y, rho, vx, vy):
    """Moves the nodes by (dx, dy) [m] and carries their fields to the new positions to first
    order, phi += grad(phi) . dr, with the gradients at the old positions (``grad_rho`` columns
    d/dx, d/dy; ``dvx``, ``dvy`` the derivative vectors of v_x, v_y, columns 0, 1 = d/dx, d/dy);
    v_x stays 0 on the axis."""
    for i in range(x.shape[0]):
        if dx[i] == 0.0 and dy[i] == 0.0:
            continue
        rho[i] += grad_rho[i, 0] * dx[i] + grad_rho[i, 1] * dy[i]
        if kind[i] != AXIS:
            vx[i] += dvx[i, 0] * dx[i] + dvx[i, 1] * dy[i]
        vy[i] += dvy[i, 0] * dx[i] + dvy[i, 1] * dy[i]
        x[i] += dx[i]
        y[i] += dy[i]
