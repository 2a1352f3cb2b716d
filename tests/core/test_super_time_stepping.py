"""The hyperviscosity's Runge-Kutta-Legendre integration (kernels/hyperviscosity.py): K
super-steps of s stages give the Legendre polynomial P_s(I + w1 dt/K S H)^K applied to the field,
evaluated here from the polynomial's power-series coefficients (numpy), not from the kernel's
three-term recursion; it stays bounded up to K (s^2 + s)/2 forward-Euler steps; the plan's factor
never falls below forward Euler's; pinned (Dirichlet) values do not move."""

import numpy as np
import pytest
from numpy.polynomial import legendre

from airpuff_core import RunParams, step_control
from airpuff_core.coupling import CoupledModel
from airpuff_core.kernels.hyperviscosity import (hyperviscous_flow_increments, increments_work,
                                                 legendre_plan)
from airpuff_core.kernels.mfpm import flow_operator_work, hyperviscous_flow_operator


@pytest.fixture(scope="module")
def model():
    return CoupledModel(RunParams(resolution="coarse"))


def _operator_args(model):
    return (*model.fluid.ops_n.hyperviscosity_args(), model.fluid.hv_consistent_density,
            model.fluid.hv_consistent_velocity)


def _scaled_operator_matrix(model, slot):
    """The matrix of f -> S H f on field ``slot`` (0 rho, 1 v_x, 2 v_y), column by column."""
    n = model.x.size
    scale = model.si.hyperviscosity * model.c * model.fluid.hv_scale_unit
    M = np.empty((n, n))
    out = np.empty((3, n))
    for j in range(n):
        fields = np.zeros((3, n))
        fields[slot, j] = 1.0
        hyperviscous_flow_operator(*fields, *_operator_args(model), 1, flow_operator_work(n), *out)
        M[:, j] = scale * out[slot]
    return M, scale


def _increments(model, fields, pinned_vx, pinned_vy, scale, dt, stages, supersteps=1,
                rho_source=None):
    n = model.x.size
    out = np.empty((3, n))
    source = np.zeros(n) if rho_source is None else rho_source
    hyperviscous_flow_increments(*fields, pinned_vx, pinned_vy, *_operator_args(model), scale, 1.0,
                                 source, dt, stages, supersteps, 1, *increments_work(n), *out)
    return out


def _legendre_of_matrix(X, s, f):
    """P_s(X) f by Horner's rule on P_s's power-series coefficients."""
    coef = legendre.leg2poly([0.0] * s + [1.0])
    g = coef[-1] * f
    for c in coef[-2::-1]:
        g = X @ g + c * f
    return g


def _plan_factor(z, supersteps, stages):
    """The amplification factor P_s(1 + w1 z / K)^K of the plan at z = dt lambda."""
    w1 = 2.0 / (stages ** 2 + stages)
    return legendre.legval(1.0 + w1 * z / supersteps, [0.0] * stages + [1.0]) ** supersteps


@pytest.mark.parametrize("steps", [0.4, 1.0, 1.7, 3.0, 3.5, 4.5, 5.27, 6.07, 8.0, 11.0, 15.0,
                                   27.0, 60.0])
def test_plan_covers_the_steps_damps_and_costs_no_more_than_forward_euler(steps):
    """Over the range of dt lambda the solver admits, -steps * HV_SAFETY .. 0 (the radius
    estimate exact; HV_MARGIN adds more room), the factor lies in [1 - HV_SAFETY, 1]: no mode
    grows, none is pushed further negative than one forward-Euler sub-step at the same margin
    may push it; and a mode the hyperviscosity acts on is damped."""
    supersteps, stages = legendre_plan(steps)
    assert supersteps * (stages ** 2 + stages) / 2 >= steps
    assert supersteps * stages <= max(1, np.ceil(steps))
    assert stages == 1 or supersteps >= 2
    z = np.linspace(-steps * step_control.HV_SAFETY, 0.0, 4001)
    factor = _plan_factor(z, supersteps, stages)
    assert factor.max() <= 1.0 + 1e-12
    assert factor.min() >= 1.0 - step_control.HV_SAFETY - 1e-12, factor.min()
    assert np.all(np.abs(factor[z < -0.5]) < 1.0)
    # first-order accurate: the factor is 1 + z + O(z^2) for small z
    small = np.array([-1e-4, -1e-3])
    assert np.allclose(_plan_factor(small, supersteps, stages), 1.0 + small, rtol=0, atol=1e-6)


@pytest.mark.parametrize("stages,supersteps", [(1, 1), (2, 1), (3, 1), (4, 1), (6, 1), (2, 2),
                                               (3, 2), (2, 3)])
def test_stages_are_the_legendre_polynomial_and_stay_bounded(model, stages, supersteps):
    """Density (even, no node pinned), at a step of 0.95 times the stability limit
    dt |lambda_max| = K (s^2 + s): increments equal (P_s(I + w1 dt/K M)^K - I) f, and the field
    does not grow in the area-weighted norm (the one in which H is self-adjoint)."""
    M, scale = _scaled_operator_matrix(model, 0)
    lam_max = np.abs(np.linalg.eigvals(M)).max()
    dt = 0.95 * supersteps * (stages ** 2 + stages) / lam_max
    n = model.x.size
    rng = np.random.default_rng(stages)
    f = rng.standard_normal(n)
    none = np.zeros(n, bool)
    out = _increments(model, (f, np.zeros(n), np.zeros(n)), none, none, scale, dt, stages,
                      supersteps)
    w1 = 2.0 / (stages ** 2 + stages)
    X = np.eye(n) + w1 * dt / supersteps * M
    expected = f
    for _ in range(supersteps):
        expected = _legendre_of_matrix(X, stages, expected)
    expected = expected - f
    assert np.abs(out[0] - expected).max() < 1e-9 * np.abs(f).max()
    if stages == 1 and supersteps == 1:  # one forward-Euler step
        assert np.allclose(out[0], dt * M @ f, rtol=0, atol=1e-12 * np.abs(f).max())
    weight = model.fluid.ops_n.adjoint_weight
    assert np.sum(weight * (f + out[0]) ** 2) <= np.sum(weight * f ** 2) * (1 + 1e-12)
    # the stiff modes are damped, not merely bounded: the stiffest mode's factor is P_s^K at
    # 1 - 2 * 0.95 = -0.9
    mode = np.linalg.eig(M)[1][:, np.argmax(np.abs(np.linalg.eigvals(M)))].real
    moved = _increments(model, (mode, np.zeros(n), np.zeros(n)), none, none, scale, dt, stages,
                        supersteps)
    factor = np.dot(mode + moved[0], mode) / np.dot(mode, mode)
    assert abs(factor - legendre.legval(-0.9, [0.0] * stages + [1.0]) ** supersteps) < 1e-6
    assert abs(factor) < 1.0


def test_pinned_values_stay_and_the_rest_follows_the_free_block(model):
    """v_y pinned at walls and the cornea: those entries do not move; the free ones follow
    P_s of the operator's block on the free nodes (the pinned values enter as constants,
    here zero)."""
    M, scale = _scaled_operator_matrix(model, 2)
    pinned = model.fluid.pinned_vy
    free = ~pinned
    n = model.x.size
    stages = 3
    lam_max = np.abs(np.linalg.eigvals(M)).max()
    dt = 0.6 * (stages ** 2 + stages) / lam_max
    f = np.random.default_rng(7).standard_normal(n) * free
    out = _increments(model, (np.zeros(n), np.zeros(n), f), model.fluid.pinned_vx, pinned, scale, dt,
                      stages)
    assert np.all(out[2][pinned] == 0.0)
    assert np.all(out[1] == 0.0)  # v_x = 0 stays 0
    Mff = M[np.ix_(free, free)]
    w1 = 2.0 / (stages ** 2 + stages)
    expected = _legendre_of_matrix(np.eye(free.sum()) + w1 * dt * Mff, stages, f[free]) - f[free]
    assert np.abs(out[2][free] - expected).max() < 1e-9 * np.abs(f).max()


@pytest.mark.parametrize("stages,supersteps", [(1, 1), (3, 2), (6, 2)])
def test_a_density_balanced_against_its_source_is_the_stages_steady_state(model, stages,
                                                                         supersteps):
    """With the source r integrated in the stages (``rho_source``, the option
    ``hyperviscosity_density_speed``), a density f that the hyperviscosity balances against it,
    M f + r = 0, is left where it is at any admitted dt: the increment less the source's own,
    Y - f - dt r, is -dt r, also where dt is many times the forward-Euler limit.  Without the
    source in the stages (the source added beside the increment) f moves by
    (P_s^K - I) f + dt r, which vanishes for one forward-Euler step only."""
    M, scale = _scaled_operator_matrix(model, 0)
    lam_max = np.abs(np.linalg.eigvals(M)).max()
    dt = 0.9 * supersteps * (stages ** 2 + stages) / lam_max
    n = model.x.size
    none = np.zeros(n, bool)
    f = 1000.0 + np.random.default_rng(11).standard_normal(n)
    r = -M @ f
    out = _increments(model, (f, np.zeros(n), np.zeros(n)), none, none, scale, dt, stages,
                      supersteps, rho_source=r)
    assert np.abs(out[0] + dt * r).max() < 1e-9 * dt * np.abs(r).max()
    if stages * supersteps > 1:
        split = _increments(model, (f, np.zeros(n), np.zeros(n)), none, none, scale, dt, stages,
                            supersteps)
        assert np.abs(split[0] + dt * r).max() > 0.1 * dt * np.abs(r).max()
