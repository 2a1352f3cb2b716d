"""numpy's sum in compiled kernels (airpuff_core/kernels/sums.py): the same value as ``np.sum`` to
the last bit for every length (below, at and across the pairwise blocks of 8 and 128 values,
whose order of additions differs); the compliant globe's volume rate, which sums so, against
numpy's form of the same sums and against the exact derivative of the enclosed volume; the
overstresses' work over a step and their stored energy (kernels/viscoelastic.py) and the apex
budget's pressure-load sums (kernels/membrane.py) against numpy's form, bit for bit."""

import math

import numpy as np
import pytest

from airpuff_core.kernels.membrane import (add_pressure_loads, cornea_polygon_volume,
                                          enclosed_volume_rate, region_pressure_loads)
from airpuff_core.kernels.sums import numpy_sum, pairwise_sum
from airpuff_core.kernels.viscoelastic import (bending_overstress_energy,
                                              membrane_overstress_energy,
                                              paired_overstress_work, row_overstress_energy,
                                              row_overstress_work)


@pytest.mark.parametrize("count", [0, 1, 7, 8, 9, 15, 16, 17, 127, 128, 129, 255, 256, 257, 1000,
                                   4099, 100003])
def test_the_sum_is_numpys_bit_for_bit(count):
    rng = np.random.default_rng(count)
    # terms of widely different size and both signs: the order of the additions shows
    values = rng.standard_normal(count) * 10.0 ** rng.integers(-8, 8, count)
    assert numpy_sum(values) == np.sum(values)
    if count > 10:
        assert pairwise_sum(values, 3, count - 10) == np.sum(values[3:count - 7])


def test_the_order_matters_for_these_values():
    """The check above can fail: a plain left-to-right sum of the same values differs."""
    values = np.random.default_rng(1).standard_normal(1000) * 10.0 ** np.arange(-8, 8).repeat(63)[:1000]
    in_order = 0.0
    for v in values:
        in_order += v
    assert in_order != np.sum(values)


def numpy_volume_rate(xc, yc, vxc, vyc, y_axis):
    """The enclosed volume's rate as numpy expressions (arrays of the polygon's edges)."""
    xs = np.concatenate(([0.0], xc, [0.0]))
    ys = np.concatenate(([y_axis], yc, [y_axis]))
    us = np.concatenate(([0.0], vxc, [0.0]))
    ws = np.concatenate(([0.0], vyc, [0.0]))
    xa, xb, ya, yb = xs[:-1], xs[1:], ys[:-1], ys[1:]
    ua, ub, wa, wb = us[:-1], us[1:], ws[:-1], ws[1:]
    S = np.sum((xa * xa + xa * xb + xb * xb) * (ya - yb))
    dS = np.sum(((2 * xa + xb) * ua + (xa + 2 * xb) * ub) * (ya - yb)
                + (xa * xa + xa * xb + xb * xb) * (wa - wb))
    return math.copysign(1.0, S) * math.pi / 3.0 * dS


@pytest.mark.parametrize("nodes", [12, 26, 51, 200])
def test_the_volume_rate_is_numpys_sum_and_the_exact_derivative(nodes):
    rng = np.random.default_rng(nodes)
    phi = np.linspace(0.0, 1.0, nodes)
    X = 7e-3 * np.sin(phi)
    Y = 7e-3 * np.cos(phi) + 1e-5 * rng.standard_normal(nodes)
    VX, VY = rng.normal(size=nodes), rng.normal(size=nodes)
    for y_axis in (0.0, Y[-1]):
        rate = enclosed_volume_rate(X, Y, VX, VY, y_axis)
        assert rate == numpy_volume_rate(X, Y, VX, VY, y_axis)
        h = 1e-9
        fd = (cornea_polygon_volume(X + h * VX, Y + h * VY, y_axis)
              - cornea_polygon_volume(X - h * VX, Y - h * VY, y_axis)) / (2 * h)
        assert rate == pytest.approx(fd, rel=1e-6)


@pytest.mark.parametrize("segments", [25, 50, 150])
def test_the_overstress_work_is_numpys_bit_for_bit(segments):
    rng = np.random.default_rng(segments)
    area = rng.uniform(1e-7, 1e-6, segments)  # m^2
    q_a, q_b = rng.normal(0.0, 50.0, segments), rng.normal(0.0, 5.0, segments)  # N/m
    a_old, b_old = rng.normal(0.0, 1e-2, segments), rng.normal(0.0, 1e-2, segments)
    a_new = a_old + rng.normal(0.0, 1e-6, segments)
    b_new = b_old + rng.normal(0.0, 1e-6, segments)
    assert (paired_overstress_work(area, q_a, q_b, a_new, a_old, b_new, b_old)
            == np.sum(area * (q_a * (a_new - a_old) + q_b * (b_new - b_old))))
    assert row_overstress_work(area, q_a, a_new, a_old) == np.sum(area * q_a * (a_new - a_old))


@pytest.mark.parametrize("segments", [25, 50, 150])
def test_the_overstress_energies_are_numpys_bit_for_bit(segments):
    """The stored energy's sums (``ViscoelasticTissue.stored_energy``) against numpy's form."""
    rng = np.random.default_rng(segments + 1)
    area = rng.uniform(1e-7, 1e-6, segments)  # m^2
    c11, c22 = rng.uniform(1e-4, 1e-3, segments), rng.uniform(1e-4, 1e-3, segments)  # m/N
    c12 = -0.3 * rng.uniform(1e-4, 1e-3, segments)
    q1, q2 = rng.normal(0.0, 50.0, segments), rng.normal(0.0, 5.0, segments)
    assert (membrane_overstress_energy(area, c11, c12, c22, q1, q2)
            == np.sum(area * (c11 * q1 * q1 + 2.0 * c12 * q1 * q2 + c22 * q2 * q2)))
    inverse, nu = 1.0 / (3e-5 * (1.0 - 0.49 ** 2)), 0.49
    assert (bending_overstress_energy(area, inverse, nu, q1, q2)
            == np.sum(area * inverse * (q1 * q1 - 2.0 * nu * q1 * q2 + q2 * q2)))
    assert row_overstress_energy(area, q1) == np.sum(area * q1 * q1)


@pytest.mark.parametrize("nodes", [5, 8, 11, 50])
def test_the_apex_pressure_loads_are_numpys_sums(nodes):
    """The apex budget's load sums (``apex_budget``) against the loads summed by numpy."""
    rng = np.random.default_rng(nodes)
    phi = np.linspace(0.0, 0.8, 50)
    X, Y = 7.8e-3 * np.sin(phi), 7.8e-3 * np.cos(phi) + rng.normal(0.0, 1e-6, 50)
    q_fluid, q_jet = rng.normal(2e3, 5e2, 50), rng.normal(8e3, 1e3, 50)  # Pa
    expected = []
    for q in (np.ones(50), q_fluid, q_jet):
        Fx, Fy = np.zeros(50), np.zeros(50)
        add_pressure_loads(X, Y, q, Fx, Fy)
        expected.append(Fy[:nodes].sum())
    assert region_pressure_loads(X, Y, q_fluid, q_jet, nodes) == tuple(expected)
