"""The kept MFPM operator mapped by the deformation since its build (total Lagrangian form,
``kernels.mfpm.mapped_derivatives``, ``FluidStepper``'s ``strain_limit``): exact derivatives of
quadratic fields under affine deformations, a fresh build's derivatives within a stated tolerance
under a curved one, and its error shrinking with the strain (docs/performance.md, issue 31)."""

import math

import numpy as np
import pytest

from airpuff_core.errors import SimulationError
from airpuff_core.fluid import KAPPA, Operators
from airpuff_core.fluid_stepper import STRAIN_LIMIT
from airpuff_core.geometry import build_chamber
from airpuff_core.kernels.mfpm import mapped_derivatives
from tests.core.test_mfpm import exact_quadratics, perturbed

R, RP, A0 = 7e-3, 2.04e-3, math.radians(60)


@pytest.fixture(scope="module")
def kept():
    """A perturbed paper-resolution cloud (X, Y) and its operator, kept."""
    chamber = build_chamber("sector", "isotropic", "paper", R, RP, A0)
    X, Y = perturbed(chamber, 0.2)
    ops = Operators(chamber.h, chamber.area, KAPPA, keep_operator=True)
    ops.build(X, Y)
    return chamber, X, Y, ops


def mapped_errors(ops, x, y, nodes=None):
    """Largest error of the mapped operator's derivatives of an even and an odd quadratic at
    (x, y), relative to each field's largest derivative: (gradient, second derivatives), and
    the largest strain."""
    worst = [0.0, 0.0]
    strain = 0.0
    for f, exact, parity in exact_quadratics(x, y):
        out = np.zeros((1, x.size, 5))
        strain = ops.mapped_derivatives(x, y, f[np.newaxis], np.array([parity]), out, nodes)
        sel = ops.all_nodes if nodes is None else nodes
        err = np.abs(out[0] - exact)[sel] / np.abs(exact).max()
        worst = [max(worst[0], float(err[:, :2].max())), max(worst[1], float(err[:, 2:].max()))]
    return worst, strain


def curved(X, Y, eps):
    """A smooth deformation of strain about eps, odd in x and even in y as the fields' images
    need: x = X (1 + eps cos(Y / l)), y = Y + eps X^2 / l, l twice the cloud's width."""
    length = 2.0 * np.abs(X).max()
    return X * (1.0 + eps * np.cos(Y / length)), Y + eps * X ** 2 / length


def test_at_its_build_positions_it_is_exact(kept):
    _, X, Y, ops = kept
    (grad, second), strain = mapped_errors(ops, X, Y)
    assert strain < 1e-12
    assert grad < 1e-9 and second < 1e-9


def test_an_axisymmetric_affine_deformation_keeps_it_exact(kept):
    """x = 1.03 X, y = 0.97 Y + 0.05 mm (a stretch, a squeeze and a shift, the axis kept): the
    mapped operator still reproduces every quadratic to round-off, at every node."""
    _, X, Y, ops = kept
    (grad, second), strain = mapped_errors(ops, 1.03 * X, 0.97 * Y + 5e-5)
    assert strain == pytest.approx(0.03, rel=1e-9)
    assert grad < 1e-9 and second < 1e-9


def test_a_shear_keeps_it_exact_away_from_the_axis(kept):
    """x = X + 0.02 Y (a shear, which has no mirror image across the axis): exact at the nodes
    whose support holds no image."""
    _, X, Y, ops = kept
    no_image = np.array([i for i in ops.all_nodes
                         if np.all(ops.sign[ops.start[i]:ops.start[i] + ops.count[i]] > 0)])
    assert no_image.size > 0.8 * X.size
    (grad, second), _ = mapped_errors(ops, X + 0.02 * Y, Y, no_image)
    assert grad < 1e-9 and second < 1e-9


def test_a_curved_deformation_within_the_strain_limit_stays_close_to_a_fresh_build(kept):
    """Under a curved deformation of strain up to the solver's limit the mapped operator gives a
    fresh build's derivatives of the quadratics (exact, to 1e-9) within 1e-5 (gradient) and
    5e-3 (second derivatives) of the field's largest derivative (1.0e-7 and 1.2e-3 measured at
    strain 0.02), and its error falls at least linearly with the strain."""
    chamber, X, Y, ops = kept
    errors = {}
    for eps in (STRAIN_LIMIT, STRAIN_LIMIT / 2):
        x, y = curved(X, Y, eps)
        errors[eps], strain = mapped_errors(ops, x, y)
        assert strain <= 1.5 * eps
        fresh = Operators(chamber.h, chamber.area, KAPPA)
        for f, exact, parity in exact_quadratics(x, y):
            out = np.zeros((1, x.size, 5))
            fresh.derivatives(x, y, f[np.newaxis], np.array([parity]), out)
            assert np.abs(out[0] - exact).max() < 1e-9 * np.abs(exact).max()
    grad, second = errors[STRAIN_LIMIT]
    assert grad < 1e-5 and second < 5e-3, errors
    half_grad, half_second = errors[STRAIN_LIMIT / 2]
    assert half_grad < 0.55 * grad and half_second < 0.55 * second, errors


def test_tangled_nodes_are_an_error(kept):
    """A deformation gradient with a negative determinant (x mirrored) is a blow-up, named."""
    _, X, Y, ops = kept
    out = np.zeros((1, X.size, 2))
    with pytest.raises(SimulationError, match="tangled"):
        ops.mapped_derivatives(X, -Y, Y[np.newaxis], np.array([1.0]), out, time_ms=1.0)


@pytest.mark.parametrize("parities", [(1.0,), (-1.0, 1.0)])
def test_the_gradient_alone_is_the_full_evaluations_bit_for_bit(kept, parities):
    """Asked for the gradient only (``out`` of two columns), the mapped operator forms fewer
    sums per pair; its gradient and strains are those of the full evaluation bit for bit, on
    any chunks, and it finds the same tangled node."""
    _, X, Y, ops = kept
    x, y = curved(X, Y, STRAIN_LIMIT)
    rng = np.random.default_rng(5)
    fields = rng.standard_normal((len(parities), X.size))
    parity = np.array(parities)
    full = np.zeros((len(parities), X.size, 5))
    ops.mapped_derivatives(x, y, fields, parity, full)
    strain_full = ops.strain.copy()
    for n_chunks in (1, 3):
        gradient = np.zeros((len(parities), X.size, 2))
        strain = np.zeros(X.size)
        status = mapped_derivatives(x, y, ops.all_nodes, fields, parity, ops.start, ops.nbr,
                                    ops.sign, ops.count, ops.lap_w, gradient, strain, n_chunks)
        assert status == 0
        assert np.array_equal(gradient, full[:, :, :2])
        assert np.array_equal(strain, strain_full)
    tangled_x = x.copy()
    tangled_x[7] = -tangled_x[7] - 1e-3  # node 7 pushed through its neighbours
    statuses = []
    for columns in (5, 2):
        out = np.zeros((len(parities), X.size, columns))
        statuses.append(mapped_derivatives(tangled_x, y, ops.all_nodes, fields, parity,
                                           ops.start, ops.nbr, ops.sign, ops.count, ops.lap_w,
                                           out, np.zeros(X.size), 1))
    assert statuses[0] == statuses[1] != 0
