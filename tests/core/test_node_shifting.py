"""Node shifting (``node_shifting``, ``kernels/shifting.py``, docs/model.md section 4): a cloud as
regular as the initial one is not moved, a node pushed off its place is moved back, fields are
carried to the new positions exactly where they are linear, and a run with it conserves mass and
keeps the density's volume on the chamber's (coarse resolution)."""

import math

import numpy as np
import pytest

from airpuff_core import RunParams, simulate
from airpuff_core.coupling import CoupledModel
from airpuff_core.kernels.nodes import INTERIOR
from airpuff_core.kernels.shifting import concentration_gradient

SHIFTING = 1.0


def _model():
    return CoupledModel(RunParams(resolution="coarse", node_shifting=SHIFTING))


def _free_interior_node(fluid):
    """An interior node far from walls, cornea and axis (the middle of the chamber)."""
    x, y, kind = fluid.x, fluid.y, fluid.kind
    inside = np.flatnonzero(kind == INTERIOR)
    centre = np.array([np.median(x[inside]), np.median(y[inside])])
    return inside[np.argmin(np.hypot(x[inside] - centre[0], y[inside] - centre[1]))]


def test_a_square_lattice_has_no_concentration_gradient_inside():
    """By symmetry the kernel sum's gradient vanishes at a node whose support is a full square
    lattice; at an edge it points inwards (towards the nodes)."""
    h, kappa, m = 1e-4, 2.7, 15
    ix, iy = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    x = (ix.ravel() + 5.0) * h
    y = iy.ravel() * h
    n = x.shape[0]
    pairs = [(i, j) for i in range(n) for j in range(n)
             if i != j and math.hypot(x[i] - x[j], y[i] - y[j]) < kappa * h]
    start = np.zeros(n + 1, np.int64)
    count = np.bincount([i for i, _ in pairs], minlength=n).astype(np.int64)
    start[1:] = np.cumsum(count)
    nbr = np.array([j for _, j in pairs], np.uint32)
    sign = np.ones(len(pairs))
    grad = np.zeros((n, 2))
    concentration_gradient(x, y, np.full(n, h), np.full(n, h * h), kappa, start, nbr, sign,
                           count, grad)
    centre = (m // 2) * m + m // 2
    assert np.abs(grad[centre]).max() * h < 1e-13
    edge = (m // 2) * m  # iy = 0, the lattice's lower edge
    assert grad[edge, 1] * h > 0.1


def test_the_initial_cloud_is_not_moved():
    model = _model()
    fluid = model.fluid
    fluid.vy[fluid.kind == INTERIOR] = 1.0  # a speed, so that the shift is not zero for it
    x, y, rho = fluid.x.copy(), fluid.y.copy(), fluid.rho.copy()
    fluid.shift(1e-5)
    assert np.array_equal(fluid.x, x) and np.array_equal(fluid.y, y)
    assert np.array_equal(fluid.rho, rho)


SLOPE_RHO, SLOPE_V = 5e3, 10.0  # kg/m^4, 1/s: the linear fields a shift must carry exactly


def displaced_node_with_linear_fields(fluid):
    """Move the middle interior node by (0.3 h, 0.2 h) off its place and set the linear fields
    rho = rho0 + SLOPE_RHO y, v_y = 0.2 + SLOPE_V x, v_x = 0; return the node and its h [m]."""
    i = _free_interior_node(fluid)
    h = fluid.h[i]
    fluid.x[i] += 0.3 * h
    fluid.y[i] += 0.2 * h
    fluid.rho[:] = fluid.rho0 + SLOPE_RHO * fluid.y
    fluid.vy[:] = 0.2 + SLOPE_V * fluid.x
    fluid.vx[:] = 0.0
    fluid.refresh_derivatives()
    return i, h


def assert_linear_fields_carried(fluid):
    np.testing.assert_allclose(fluid.rho, fluid.rho0 + SLOPE_RHO * fluid.y, rtol=1e-12)
    np.testing.assert_allclose(fluid.vy, 0.2 + SLOPE_V * fluid.x, rtol=0, atol=1e-12)


def test_a_displaced_node_is_moved_back_and_linear_fields_are_carried_exactly():
    fluid = _model().fluid
    home_x, home_y = fluid.x.copy(), fluid.y.copy()
    i, h = displaced_node_with_linear_fields(fluid)
    home = np.array([home_x[i], home_y[i]])
    others = np.arange(fluid.x.shape[0]) != i
    x0, y0 = fluid.x.copy(), fluid.y.copy()
    before = np.hypot(*(np.array([fluid.x[i], fluid.y[i]]) - home))
    fluid.shift(0.05 * h / fluid.max_speed())  # v_max dt = h/20
    after = np.hypot(*(np.array([fluid.x[i], fluid.y[i]]) - home))
    assert after < before - 1e-3 * h  # moved back towards its place
    moved = np.hypot(fluid.x - x0, fluid.y - y0)
    assert moved[i] <= 0.05 * h * (1 + 1e-12)  # the per-step limit
    assert moved[others].max() < moved[i]  # its neighbours give way less than it moves
    assert np.count_nonzero(moved) > 1
    assert_linear_fields_carried(fluid)


@pytest.fixture(scope="module")
def shifted_run():
    return simulate(RunParams(resolution="coarse", node_shifting=SHIFTING))


def assert_conserves_mass_and_volume(result):
    """The rigid chamber of the paper preset: the fluid's mass is rho0 times the sector's exact
    volume 2 pi/3 (R^3 - r^3)(1 - cos alpha0), and the solver's volume mismatch stays below a tenth
    of the chamber's volume change."""
    ds = result.to_dataset()
    R, r, a = 7e-3, 2.04e-3, math.radians(60)
    exact_volume = 2 * math.pi / 3 * (R ** 3 - r ** 3) * (1 - math.cos(a))
    assert ds.attrs["solver_mass_kg"] == pytest.approx(1000.0 * exact_volume, rel=1e-12)
    vol = ds.chamber_volume.values
    change = np.max(np.abs(vol - vol[0])) / vol[0]
    assert ds.attrs["solver_max_volume_mismatch"] < 0.1 * change


def test_a_run_with_shifting_conserves_mass_and_volume(shifted_run):
    """As ``test_run.test_conservation``, with the nodes shifted."""
    assert_conserves_mass_and_volume(shifted_run)
