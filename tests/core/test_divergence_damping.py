"""The divergence damping dv/dt = -W^-1 D^T S W D v (``hyperviscosity_divergence``, docs/model.md
section 4): D is the axisymmetric divergence (exact on analytic quadratic fields at every kind of
node), the damping annihilates divergence-free fields, is W-self-adjoint and negative
semi-definite on the free velocity components, leaves a fluid at rest at rest, and, with the
velocity's hyperviscosity at a fixed speed, the linearised coupled step has no growing mode at
coarse resolution."""

import numpy as np
import pytest

from airpuff_core import RunParams, simulate
from airpuff_core.coupling import CoupledModel
from airpuff_core.kernels.nodes import AXIS, CORNEA, INTERIOR, WALL
from airpuff_core.stability import linearised_step

SCALE = 1e3  # 1/m: velocity gradients of order 1 per mm


@pytest.fixture(scope="module")
def model():
    m = CoupledModel(RunParams(resolution="coarse", hyperviscosity_divergence=0.5))
    f = m.fluid
    f.divergence_damping.assemble(f.ops_n, f.x, f.ops_n.adjoint_weight)
    return m


def _divergence(model, vx, vy):
    return model.fluid.divergence_damping.D @ np.concatenate([vx, vy])


def test_divergence_of_analytic_fields_at_every_kind_of_node(model):
    x, y, kind = model.x, model.y, model.fluid.kind
    # v = (x, 0): (1/x) d(x^2)/dx = 2, also on the axis (limit 2 dv_x/dx)
    expand = _divergence(model, SCALE * x, np.zeros_like(x))
    # v = (x y, -y^2) / mm: (1/x) d(x^2 y)/dx - 2 y = 0 (divergence-free, quadratic)
    solenoidal = _divergence(model, SCALE ** 2 * x * y, -SCALE ** 2 * y * y)
    # v = (x y, x^2 + y^2) / mm (v_x odd, v_y even in x): 2 y + 2 y = 4 y
    quadratic = _divergence(model, SCALE ** 2 * x * y, SCALE ** 2 * (x * x + y * y))
    for k in (WALL, CORNEA, INTERIOR, AXIS):
        sel = kind == k
        assert sel.any(), k
        assert np.abs(expand[sel] - 2.0 * SCALE).max() < 1e-9 * SCALE, k
        assert np.abs(solenoidal[sel]).max() < 1e-9 * SCALE, k
        assert np.abs(quadratic[sel] - 4.0 * SCALE ** 2 * y[sel]).max() < 1e-9 * SCALE, k


def test_divergence_free_fields_are_not_damped(model):
    x, y = model.x, model.y
    vx, vy = SCALE * x * y * 1e-3, -SCALE * y * y * 1e-3  # m/s, quadratic, divergence-free
    out_x, out_y = np.empty_like(x), np.empty_like(x)
    model.fluid.divergence_damping.rate(vx, vy, 0.5 * 10.0 * model.fluid.divergence_damping.h,
                                        out_x, out_y)
    # an expanding field of the same size is damped at a rate of order c / h
    ex_x, ex_y = np.empty_like(x), np.empty_like(x)
    model.fluid.divergence_damping.rate(SCALE * x * 1e-3 * x / x.max(), np.zeros_like(x),
                                        0.5 * 10.0 * model.fluid.divergence_damping.h, ex_x, ex_y)
    assert np.abs(np.concatenate([out_x, out_y])).max() < 1e-9 * np.abs(ex_x).max()
    assert np.abs(ex_x).max() > 1.0


def test_self_adjoint_and_negative_semi_definite_on_the_free_components(model):
    damping = model.fluid.divergence_damping
    n = model.x.size
    free = np.concatenate([damping.free_x, damping.free_y])
    cols = np.flatnonzero(free)
    M = np.empty((cols.size, cols.size))
    unit = np.zeros(2 * n)
    out_x, out_y = np.empty(n), np.empty(n)
    for k, j in enumerate(cols):
        unit[:] = 0.0
        unit[j] = 1.0
        damping.rate(unit[:n], unit[n:], damping.h, out_x, out_y)
        M[:, k] = np.concatenate([out_x, out_y])[cols]
    W = np.concatenate([damping.weight, damping.weight])[cols]
    WM = W[:, None] * M
    assert np.abs(WM - WM.T).max() < 1e-10 * np.abs(WM).max()
    eig = np.linalg.eigvalsh(0.5 * (WM + WM.T))
    assert eig.max() < 1e-10 * np.abs(eig).max()
    assert eig.min() < 0.0  # it does damp something
    # the damping never touches a Dirichlet value (walls, cornea, v_x on the axis)
    kind = model.fluid.kind
    assert not damping.free_y[(kind == WALL) | (kind == CORNEA)].any()
    assert not damping.free_x[kind == AXIS].any()


def test_the_compiled_rate_is_scipys_products_bit_for_bit(model):
    """``rate`` (kernels/divergence_damping.py) forms -W_f^-1 D^T S W D v with the sums of
    ``scipy.sparse``'s products by D and by its transpose, bit for bit."""
    damping = model.fluid.divergence_damping
    n = model.x.size
    rng = np.random.default_rng(2)
    transpose = damping.D.T.tocsr()
    out_x, out_y = np.empty(n), np.empty(n)
    for _ in range(3):
        vx, vy, scale = rng.standard_normal(n), rng.standard_normal(n), rng.random(n)
        g = transpose @ (scale * damping.weight * (damping.D @ np.concatenate([vx, vy])))
        damping.rate(vx, vy, scale, out_x, out_y)
        assert np.array_equal(out_x, np.where(damping.free_x, -g[:n] / damping.weight, 0.0))
        assert np.array_equal(out_y, np.where(damping.free_y, -g[n:] / damping.weight, 0.0))


def test_a_fixed_speed_takes_the_sound_speeds_place(model):
    """With ``hyperviscosity_divergence_speed`` c_d the bulk viscosity is gamma_div c_d h at every
    sound speed c: the increments at any c equal those of c_d in place of c."""
    damping = model.fluid.divergence_damping
    n = model.x.size
    rng = np.random.default_rng(3)
    vx, vy = 1e-2 * rng.standard_normal(n), 1e-2 * rng.standard_normal(n)  # m/s
    dt = 2e-6  # s
    expected_x, expected_y, out_x, out_y = (np.empty(n) for _ in range(4))
    try:
        damping.speed = 0.0
        expected_steps = damping.increments(vx, vy, 15.0, dt, expected_x, expected_y)
        damping.speed = 15.0
        for c in (10.0, 40.0, 80.0):
            steps = damping.increments(vx, vy, c, dt, out_x, out_y)
            assert steps == expected_steps
            assert np.array_equal(out_x, expected_x) and np.array_equal(out_y, expected_y)
        assert np.abs(expected_x).max() > 0.0
    finally:
        damping.speed = 0.0


def test_rest_stays_at_rest():
    params = RunParams(model="clinical", pmax=0.0, t_end=2.0, hyperviscosity_speed=15.0,
                       hyperviscosity_divergence=0.5)
    result = simulate(params)
    assert np.max(np.abs(result.histories["apex_displacement"])) < 1e-9  # mm
    assert np.max(np.abs(result.histories["wall_volume_change"])) < 1e-9  # uL


@pytest.mark.slow
@pytest.mark.parametrize("c0, divergence_speed", [(10.0, 0.0), (40.0, 0.0), (40.0, 15.0)])
def test_no_growing_mode_with_the_velocity_hyperviscosity_at_a_fixed_speed(c0, divergence_speed):
    report = linearised_step(RunParams(resolution="coarse", c0=c0, hyperviscosity_speed=15.0,
                                       hyperviscosity_divergence=0.5,
                                       hyperviscosity_divergence_speed=divergence_speed))
    assert report.max_growth_rate < 1.0, report.growth_rates[:5]


def test_without_the_velocity_hyperviscosity_modes_grow():
    """The density's hyperviscosity alone does not stabilise the fluid (a speed c_v of 1 mm/s
    leaves the velocity's a 1e-4th of the default at c = 10 m/s)."""
    report = linearised_step(RunParams(resolution="coarse", hyperviscosity_speed=1e-3))
    assert report.max_growth_rate > 100.0
