"""Kinds of the fluid nodes, and where the symmetry axis is (docs/model.md section 2).

Every fluid node has one kind, stored as an int8 array beside the positions:

- ``INTERIOR``: integrates the momentum and continuity equations;
- ``AXIS``: an interior node on the symmetry axis x = 0 (v_x = 0 there, the 1/x terms take their
  limits);
- ``WALL``: on the rigid posterior or lateral wall (no slip, its velocity stays 0);
- ``CORNEA``: on the fluid-cornea interface, moving with the cornea (its position and velocity
  are imposed by the coupling).

A new kind of boundary goes here, so that the kernels and the chamber builder agree on it.
"""

from numba import njit

INTERIOR = 0
AXIS = 1
WALL = 2
CORNEA = 3

AXIS_EPS = 1e-12  # m: a node with x below this lies on the axis (its mirror image is itself)


@njit(cache=True)
def axis_halved_area(x, area, out):
    """out = the node area [m^2], halved for a node on the axis (x < AXIS_EPS): the weight of the
    inner product in which the Brookshaw Laplacian is self-adjoint (an off-axis node stands for
    itself and its mirror image, a node on the axis only for itself)."""
    for i in range(x.shape[0]):
        out[i] = area[i] * (0.5 if x[i] < AXIS_EPS else 1.0)
