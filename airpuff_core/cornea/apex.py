"""The apex of the cornea: its curvature, from an even fit over a fixed physical radius."""

from __future__ import annotations

import numpy as np

from ..kernels.membrane import even_fit_curvature

# m: the apex curvature is fitted over the nodes with reference x <= this radius, always with the
# same even quartic, so that every resolution measures the same quantity (the apex curvature, to
# O(R^4) of the fit radius R; docs/reproduction.md section 3).  0.6 mm holds three nodes at coarse
# resolution and stays small against the jet (exp(-a sin^2 phi) falls to 1/e at 1.5 mm), across
# which the net pressure, and with it a membrane's curvature, varies.
APEX_FIT_RADIUS = 0.6e-3


def apex_fit_nodes(X_ref, fit_radius=APEX_FIT_RADIUS):
    """Number of cornea nodes (apex first) whose reference x lies within ``fit_radius``, at least
    three.  Chosen once per run, so the fit follows the same material points throughout."""
    return max(3, int(np.searchsorted(X_ref, fit_radius * (1 + 1e-9), side="right")))


def apex_curvature(X, Y, n_fit):
    """Apical curvature [1/m], positive convex, from the even least-squares fit over the first
    ``n_fit`` nodes (those within APEX_FIT_RADIUS of the axis in the reference state):

        y = c0 + c2 x^2 + c4 x^4,   kappa = -2 c2

    The same form over the same physical radius at every resolution, so the measure converges
    with resolution (to the apex curvature within O(R^4)); the x^4 term keeps the variation of
    the curvature across the fit out of kappa.
    """
    return even_fit_curvature(X, Y, n_fit)
