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

INTERIOR = 0
AXIS = 1
WALL = 2
CORNEA = 3

AXIS_EPS = 1e-12  # m: a node with x below this lies on the axis (its mirror image is itself)
