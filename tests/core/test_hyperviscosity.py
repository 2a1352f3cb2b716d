"""The boundary-consistent hyperviscosity H = K^* L K (on the velocity by default,
``hyperviscosity_operator``, docs/model.md section 4) annihilates linear fields to round-off at
wall, axis and cornea nodes (the Brookshaw L^3 does not), h^5 H f of a smooth field falls with the
spacing at every node (L^3's does not), and H is self-adjoint and negative semi-definite in the
area-weighted inner product, so it damps and never amplifies."""

import numpy as np
import pytest

from airpuff_core import RunParams
from airpuff_core.coupling import CoupledModel
from airpuff_core.fluid import KAPPA, Operators
from airpuff_core.geometry import build_chamber
from airpuff_core.kernels.mfpm import brookshaw_laplacian
from airpuff_core.kernels.nodes import AXIS, CORNEA, INTERIOR, WALL


@pytest.fixture(scope="module")
def model():
    return CoupledModel(RunParams(resolution="coarse", hyperviscosity_operator="consistent"))


def _apply(model, f, parity):
    n = f.shape[0]
    out, w1, w2 = np.empty(n), np.empty(n), np.empty(n)
    return model.fluid.ops_n.hyperviscous(f, parity, model.fluid.hv_scale_unit, w1, w2, out, consistent=True)


def _brookshaw_cubed(model, f, parity):
    args = model.fluid.ops_n.laplacian_args()
    a, b, c = np.empty_like(f), np.empty_like(f), np.empty_like(f)
    brookshaw_laplacian(f, parity, *args, a)
    brookshaw_laplacian(a, parity, *args, b)
    brookshaw_laplacian(b, parity, *args, c)
    return c * model.fluid.hv_scale_unit


@pytest.mark.parametrize("field", ["even: 1 + y", "odd: x", "even: x + y/2 (off the axis)"])
def test_linear_fields_are_annihilated_at_every_kind_of_node(model, field):
    x, y, kind = model.x, model.y, model.fluid.kind
    scale = 1e3  # 1/m: gradients of order 1 per mm
    if field.startswith("even: 1"):
        f, parity, where = 1.0 + scale * (y - y.mean()), 1.0, np.ones(x.size, bool)
    elif field.startswith("odd"):
        f, parity, where = scale * x, -1.0, np.ones(x.size, bool)
    else:
        # x is not even in x: mirror images make it |x|, so look only beyond the reach of H
        # (three supports) from the axis
        f, parity = scale * (x + 0.5 * y), 1.0
        where = x > 3.5 * KAPPA * model.fluid.ops_n.h.max()
    new = np.abs(_apply(model, f, parity))
    old = np.abs(_brookshaw_cubed(model, f, parity))
    kinds = (WALL, CORNEA, INTERIOR) + ((AXIS,) if parity > 0 and where.all() else ())
    for k in kinds:
        sel = where & (kind == k)
        assert sel.any(), k
        # the inconsistent L^3 is O(1) there at every resolution; the new operator is round-off
        assert new[sel].max() < 1e-10 * old[where & (kind != AXIS)].max(), (k, new[sel].max())
    assert old[where & ((kind == WALL) | (kind == CORNEA))].max() > 1e3 * new[where].max()


def test_the_stabilisation_of_a_smooth_field_vanishes_with_the_spacing():
    """h^5 H f on quadratic fields, largest over all nodes (the largest sit at walls and cornea),
    at coarse, paper and fine resolution (h halves): K^* L K falls like h (observed order >= 0.8
    at each refinement: K f is O(h^0) on a quadratic, L K f and K^* L K f pick up 1/h^2 each at
    a truncated support), while L^3 stays of the order of |grad f| at every resolution (its
    boundary rows do not vanish on the linear part)."""
    largest = {False: [], True: []}
    for resolution in ("coarse", "paper", "fine"):
        p = RunParams(resolution=resolution).si()
        ch = build_chamber("sector", "isotropic", resolution, p.R_m, p.r_post_m, p.alpha0_rad)
        ops = Operators(ch.h, ch.area, KAPPA, consistent=True).build(ch.x, ch.y)
        n = ch.n
        w1, w2, out = np.empty(n), np.empty(n), np.empty(n)
        mm = 1e-3
        fields = ((((ch.y - 6 * mm) / mm) ** 2, 1.0),  # even in x, like rho and v_y
                  ((ch.x / mm) ** 2 + ch.y / mm, 1.0),
                  (ch.x * ch.y / mm ** 2, -1.0))  # odd, like v_x
        for consistent in (False, True):
            largest[consistent].append([
                np.abs(ops.hyperviscous(f, parity, ch.h ** 5, w1, w2, out, consistent)).max()
                for f, parity in fields])
    new, old = np.array(largest[True]), np.array(largest[False])
    order = np.log2(new[:-1] / new[1:])
    assert order.min() >= 0.8, order
    assert (old[1:] / old[:-1]).min() > 0.7 and (old[1:] / old[:-1]).max() < 1.3, old
    assert (new[-1] < 0.05 * old[-1]).all()


@pytest.mark.parametrize("parity", [1.0, -1.0])
def test_self_adjoint_and_negative_semi_definite(model, parity):
    """W H is symmetric with W the node areas, halved on the axis (a node there, of any kind,
    stands only for itself, an off-axis node for itself and its mirror image), and has no
    positive eigenvalue.  An odd field (v_x) vanishes on the axis, so its operator lives on the
    off-axis nodes."""
    x = model.x
    on_axis = x == 0.0
    assert on_axis.sum() > (model.fluid.kind == AXIS).sum()  # the apex and a wall node lie there too
    nodes = np.arange(x.size) if parity > 0 else np.flatnonzero(~on_axis)
    n = x.size
    H = np.empty((n, nodes.size))
    for c, j in enumerate(nodes):
        e = np.zeros(n)
        e[j] = 1.0
        H[:, c] = _apply(model, e, parity) / model.fluid.hv_scale_unit
    H = H[nodes]
    weight = (model.chamber.area * np.where(on_axis, 0.5, 1.0))[nodes]
    WH = weight[:, None] * H
    assert np.abs(WH - WH.T).max() < 1e-9 * np.abs(WH).max()
    eig = np.linalg.eigvalsh(0.5 * (WH + WH.T))
    assert eig.max() < 1e-9 * np.abs(eig).max()
    assert eig.min() < 0
    # the plain node areas would not do near the axis (the check can fail)
    if parity > 0:
        AH = model.chamber.area[nodes][:, None] * H
        assert np.abs(AH - AH.T).max() > 1e-3 * np.abs(AH).max()


@pytest.mark.parametrize("parity", [1.0, -1.0])
def test_with_brookshaw_coefficients_it_is_l_cubed(parity):
    """K = L makes K^* = L (L is self-adjoint in the weight), so K^* L K = L^3, the `brookshaw`
    operator: a check of the adjoint's code against three plain Brookshaw passes, on a random
    field (zero on the axis for the odd parity, as v_x is)."""
    model = CoupledModel(RunParams(resolution="coarse", hyperviscosity_operator="consistent"))
    ops = model.fluid.ops_n
    ops.lap_c[:] = ops.lap_b
    f = np.random.default_rng(1).standard_normal(model.x.size)
    if parity < 0:
        f[model.x == 0.0] = 0.0
    new = _apply(model, f, parity)
    old = _brookshaw_cubed(model, f, parity)
    # an odd field's rows on the axis are not used (v_x is pinned there)
    rows = np.ones(f.size, bool) if parity > 0 else model.x > 0.0
    assert np.abs(new - old)[rows].max() < 1e-11 * np.abs(old).max()


@pytest.mark.parametrize("c", [10.0, 20.0, 40.0])
def test_density_speed_makes_the_density_rate_grow_with_c_squared(c):
    """``hyperviscosity_density_speed`` c_rho: the density's hyperviscous rate is
    gamma c^2/c_rho h^5 H rho, (c / c_rho) times gamma c h^5 H rho, at every node and c, while the
    velocity's (gamma c_v h^5 H v with ``hyperviscosity_speed`` c_v) stays the same
    (docs/model.md section 4)."""
    base = RunParams(resolution="coarse", hyperviscosity_speed=15.0)
    rates = []
    for params in (base, base.replace(hyperviscosity_density_speed=10.0)):
        fluid = CoupledModel(params).fluid
        rng = np.random.default_rng(3)
        n = fluid.x.size
        fluid.rho[:] = params.rho_fluid * (1.0 + 1e-3 * rng.standard_normal(n))
        fluid.vx[:] = np.where(fluid.pinned_vx, 0.0, 1e-2 * rng.standard_normal(n))
        fluid.vy[:] = np.where(fluid.pinned_vy, 0.0, 1e-2 * rng.standard_normal(n))
        # a step far below the stability limit: one forward-Euler application, rate = S H f
        # (from the increment Y - f of fields of order 1000: relative round-off ~1e-7)
        fluid._hyperviscous_rates(1e-9, c, params.hyperviscosity, np.inf)
        rates.append({k: fluid.work[k].copy() for k in ("hv_rho", "hv_vx", "hv_vy")})
    default, option = rates
    assert np.abs(default["hv_rho"]).max() > 0
    np.testing.assert_allclose(option["hv_rho"], c / 10.0 * default["hv_rho"], rtol=1e-6,
                               atol=1e-6 * np.abs(default["hv_rho"]).max())
    for k in ("hv_vx", "hv_vy"):
        np.testing.assert_allclose(option[k], default[k], rtol=1e-6,
                                   atol=1e-6 * np.abs(default[k]).max())
