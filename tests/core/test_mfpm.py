"""MFPM operator: exact derivatives of linear and quadratic fields on perturbed clouds (interior,
walls, axis, corners, cornea), second-order convergence on a smooth field, and the conditioning
guard (docs/model.md section 4)."""

import math

import numpy as np
import pytest
import xarray as xr

from airpuff_core.errors import SimulationError
from airpuff_core.fluid import KAPPA, Operators
from airpuff_core.geometry import build_chamber
from airpuff_core.kernels.mfpm import brookshaw_laplacian, spd_inverse5
from airpuff_core.kernels.nodes import AXIS, CORNEA, WALL

R, RP, A0 = 7e-3, 2.04e-3, math.radians(60)


def perturbed(chamber, frac, seed=1):
    """Node cloud perturbed by up to ``frac`` of the spacing; axis nodes stay on the axis."""
    rng = np.random.default_rng(seed)
    x = chamber.x + frac * chamber.h * rng.uniform(-1, 1, chamber.n)
    y = chamber.y + frac * chamber.h * rng.uniform(-1, 1, chamber.n)
    on_axis = chamber.x < 1e-12
    x[on_axis] = 0.0
    x = np.maximum(x, 0.0)
    return x, y


def exact_quadratics(x, y):
    """Even (parity +1) and odd (parity -1) quadratic fields and their derivative vectors."""
    a, b, c, d = 1.3, 210.0, 4.0e4, -2.5e4
    even = a + b * y + c * x ** 2 + d * y ** 2
    d_even = np.stack([2 * c * x, b + 2 * d * y, np.full_like(x, 2 * c), 0 * x,
                       np.full_like(x, 2 * d)], axis=1)
    e, g = 170.0, 3.0e4
    odd = e * x + g * x * y
    d_odd = np.stack([e + g * y, g * x, 0 * x, np.full_like(x, g), 0 * x], axis=1)
    return (even, d_even, 1.0), (odd, d_odd, -1.0)


def derivative_vector(ops, x, y, f, parity, columns=5, nodes=None):
    """D f at every node (rows of the other nodes NaN when ``nodes`` is given)."""
    out = np.full((1, x.shape[0], columns), np.nan)
    ops.derivatives(x, y, f[np.newaxis], np.array([parity]), out, nodes)
    return out[0]


def max_relative_error(x, y, chamber):
    ops = Operators(chamber.h, chamber.area, KAPPA)
    worst = {}
    for f, dexact, parity in exact_quadratics(x, y):
        out = derivative_vector(ops, x, y, f, parity)
        scale = np.abs(dexact).max()  # one scale per field: some components are exactly 0
        err = np.abs(out - dexact) / scale
        for kind, name in ((0, "interior"), (AXIS, "axis"), (WALL, "wall"), (CORNEA, "cornea")):
            sel = chamber.kind == kind
            if sel.any():
                worst[name] = max(worst.get(name, 0.0), float(err[sel].max()))
    return worst


@pytest.mark.parametrize("geometry,layout", [("sector", "isotropic"), ("sector", "polar"),
                                             ("cap", "isotropic")])
def test_quadratics_exact_on_perturbed_cloud(geometry, layout):
    ch = build_chamber(geometry, layout, "coarse", R, RP, A0)
    x, y = perturbed(ch, 0.25)
    worst = max_relative_error(x, y, ch)
    assert set(worst) >= {"interior", "axis", "wall", "cornea"}
    for name, err in worst.items():
        assert err < 1e-9, f"{name}: relative error {err:.2e}"


def test_quadratics_exact_on_deformed_cloud_of_a_run(coarse_run):
    """The cloud at the maximum apex displacement of a real run."""
    _, path = coarse_run
    ds = xr.open_dataset(path)
    i = list(ds.snapshot_label.values).index("max_displacement")
    x = ds.fluid_x.values[i] * 1e-3
    y = ds.fluid_y.values[i] * 1e-3
    ch = build_chamber("sector", "isotropic", "coarse", R, RP, A0)
    worst = max_relative_error(x, y, ch)
    for name, err in worst.items():
        assert err < 1e-9, f"{name}: relative error {err:.2e}"


def smooth_errors(resolution):
    ch = build_chamber("sector", "isotropic", resolution, R, RP, A0)
    x, y = ch.x, ch.y
    kx, ky = 300.0, 250.0
    f = np.cos(kx * x) * np.sin(ky * y)  # even in x
    fx = -kx * np.sin(kx * x) * np.sin(ky * y)
    fy = ky * np.cos(kx * x) * np.cos(ky * y)
    fxx = -kx ** 2 * f
    fyy = -ky ** 2 * f
    out = derivative_vector(Operators(ch.h, ch.area, KAPPA), x, y, f, 1.0)
    grad_err = np.sqrt(np.mean((out[:, 0] - fx) ** 2 + (out[:, 1] - fy) ** 2)) / ky
    lap_err = np.sqrt(np.mean((out[:, 2] + out[:, 4] - fxx - fyy) ** 2)) / ky ** 2
    return ch.h.max(), grad_err, lap_err


def test_convergence_order_on_smooth_field():
    """RMS errors over all nodes (boundaries included): gradient O(h^2), second derivatives O(h)."""
    res = [smooth_errors(r) for r in ("coarse", "paper", "fine")]
    for (h1, g1, l1), (h2, g2, l2) in zip(res[:-1], res[1:]):
        order_grad = math.log(g1 / g2) / math.log(h1 / h2)
        order_lap = math.log(l1 / l2) / math.log(h1 / h2)
        assert order_grad > 1.8, order_grad
        assert order_lap > 0.9, order_lap


def test_ill_conditioned_support_is_an_error():
    """A support too small for quadratics at the walls must raise, not return garbage."""
    ch = build_chamber("sector", "isotropic", "coarse", R, RP, A0)
    with pytest.raises(SimulationError, match="ill-conditioned"):
        Operators(ch.h, ch.area, 1.2).build(ch.x, ch.y)
    with pytest.raises(SimulationError, match="ill-conditioned"):
        derivative_vector(Operators(ch.h, ch.area, 1.2), ch.x, ch.y, ch.x, -1.0,
                          nodes=np.flatnonzero(ch.kind == WALL))


def test_spd_inverse5_matches_numpy_and_flags_indefinite_matrices():
    """The written-out LDL^T inverse agrees with numpy's LU inverse to round-off (relative to the
    condition number), and an indefinite matrix gives NaN (the caller's singular-support error)."""
    rng = np.random.default_rng(3)
    lower = [(i, j) for i in range(5) for j in range(i + 1)]
    for _ in range(100):
        B = rng.standard_normal((5, 7))
        A = B @ B.T + 1e-3 * np.eye(5)
        got = np.array(spd_inverse5(*[A[i, j] for i, j in lower]))
        ref = np.linalg.inv(A)
        want = np.array([ref[i, j] for i, j in lower])
        assert np.max(np.abs(got - want)) <= 1e-14 * np.linalg.cond(A) * np.max(np.abs(want))
    indefinite = np.diag([1.0, 2.0, 3.0, 4.0, -1.0])
    assert np.all(np.isnan(spd_inverse5(*[indefinite[i, j] for i, j in lower])))


def reference_operators(x, y, h, area, f, parity):
    """The MFPM derivative vector and the Brookshaw Laplacian of f at every node, straight from
    their definitions: a brute-force search over all nodes and their mirror images, and one
    ``numpy.linalg.solve`` of the scaled moment system per node."""
    n = x.shape[0]
    D = np.empty((n, 5))
    lap = np.empty(n)
    for i in range(n):
        s = KAPPA * h[i]
        A = np.zeros((5, 5))
        b = np.zeros(5)
        lap[i] = 0.0
        for image, sign in ((0, 1.0), (1, -1.0)):
            xj = sign * x
            H = KAPPA * np.maximum(h[i], h)
            r = np.hypot(xj - x[i], y - y[i])
            near = r < H
            near[i] = near[i] and image == 1  # a node is not its own neighbour ...
            if image == 1:
                near &= x >= 1e-12  # ... and an axis node is its own image
            for j in np.flatnonzero(near):
                q = r[j] / H[j]
                w = (1 - q) ** 4 * (4 * q + 1)
                u, v = (xj[j] - x[i]) / s, (y[j] - y[i]) / s
                p = np.array([u, v, u * u / 2, u * v, v * v / 2])
                fj = parity * f[j] if image else f[j]
                A += w * np.outer(p, p)
                b += w * p * (fj - f[i])
                lap[i] += 2 * area[j] * 140 / np.pi * (1 - q) ** 3 / H[j] ** 4 * (fj - f[i])
        D[i] = np.linalg.solve(A, b) / np.array([s, s, s * s, s * s, s * s])
    return D, lap


def test_fast_operators_equal_their_definition_on_a_smooth_field():
    """The optimised kernel (skin-filtered candidate lists, written-out inverse, vectorised
    loops, several fields per build) gives the derivatives and the Brookshaw Laplacian of the
    plain definition, for fields that no quadratic reproduces, to round-off; so do its variants
    the solver uses: the gradient only, and a subset of the nodes (the cornea in the coupling
    iterations)."""
    ch = build_chamber("sector", "isotropic", "coarse", R, RP, A0)
    x, y = perturbed(ch, 0.2)
    ops = Operators(ch.h, ch.area, KAPPA)
    fields = np.array([np.cos(900 * x) * np.exp(300 * y), np.sin(900 * x) * y])
    parity = np.array([1.0, -1.0])
    both = np.empty((2, ch.n, 5))
    ops.derivatives(x, y, fields, parity, both, laplacian=True)
    cornea = np.flatnonzero(ch.kind == CORNEA)
    for k in range(2):
        f = fields[k]
        ref_d, ref_lap = reference_operators(x, y, ch.h, ch.area, f, parity[k])
        lap = np.empty(ch.n)
        brookshaw_laplacian(f, parity[k], *ops.laplacian_args(), lap)
        assert np.max(np.abs(both[k] - ref_d) / np.abs(ref_d).max(axis=0)) < 1e-9
        assert np.max(np.abs(lap - ref_lap)) < 1e-11 * np.abs(ref_lap).max()
        # one field alone, the gradient only, and the cornea only: the same sums
        assert np.array_equal(derivative_vector(ops, x, y, f, parity[k]), both[k])
        assert np.array_equal(derivative_vector(ops, x, y, f, parity[k], columns=2),
                              both[k][:, :2])
        sub = derivative_vector(ops, x, y, f, parity[k], nodes=cornea)
        assert np.array_equal(sub[cornea], both[k][cornea])
        assert np.isnan(np.delete(sub, cornea, axis=0)).all()  # no other row is written


def test_operator_shapes_are_checked():
    """The kernel does not check bounds, so its wrapper refuses arrays of the wrong shape."""
    ch = build_chamber("sector", "isotropic", "coarse", R, RP, A0)
    ops = Operators(ch.h, ch.area, KAPPA)
    fields = np.zeros((2, ch.n))
    with pytest.raises(ValueError, match="shapes"):
        ops.derivatives(ch.x, ch.y, fields, np.ones(2), np.zeros((2, ch.n, 3)))
    with pytest.raises(ValueError, match="shapes"):
        ops.derivatives(ch.x, ch.y, fields[:, :-1], np.ones(2), np.zeros((2, ch.n, 5)))
    with pytest.raises(ValueError, match="shapes"):
        ops.derivatives(ch.x, ch.y, fields, np.ones(1), np.zeros((2, ch.n, 5)))
