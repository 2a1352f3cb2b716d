"""The viscous time-step limit dt <= C rho h_min^2 / mu (the viscous term is forward Euler in the
paper's mid-point scheme): C sits inside the measured stability limit of the discrete viscous
operator, and at a large viscosity, where the limit sets the step, halving the step moves no
metric."""

import numpy as np
import pytest

from airpuff_core import RunParams, simulate, step_control
from airpuff_core.stability import forward_euler_viscous_limit, viscous_operator


@pytest.mark.parametrize("component", ["vx", "vy"])
def test_safety_constant_within_the_forward_euler_limit(component):
    """Eigenvalues of the assembled MFPM viscous operator (axisymmetric, mirror images on the
    axis, Dirichlet walls and cornea): every mode is damped, and forward Euler is stable up to
    nu dt / h_min^2 = C_FE; the solver's constant keeps a margin of 2 below it."""
    M, h_min = viscous_operator(RunParams(resolution="coarse"), component)
    C_fe, undamped = forward_euler_viscous_limit(M, h_min)
    assert undamped == 0
    assert C_fe >= 2.0 * step_control.VISCOUS_SAFETY, C_fe
    # against the classical bound: the operator is a Laplacian of spacing ~h, so its largest
    # eigenvalue is of order 8/h^2 (five-point stencil) and C_FE of order 1/4, not orders apart
    assert 0.1 < C_fe < 2.0


@pytest.mark.slow
def test_halving_the_step_at_a_large_viscosity_moves_no_metric():
    """mu = 2.5 Pa s (3300 times water): the viscous limit sets every step.  Halving both the
    acoustic and the viscous limit moves no metric beyond 0.05 mmHg / 0.05 ms / 0.005 mm."""
    params = RunParams(resolution="coarse", mu=2.5)
    full = simulate(params)
    d = full.diagnostics
    assert d["viscous_limited_steps"] == d["steps"]
    h = 0.2918e-3  # coarse node spacing [m]
    # rho in the limit is the smallest density of the step, within 1 % of the reference
    assert d["dt_max_us"] * 1e-6 <= step_control.VISCOUS_SAFETY * 1000.0 * h ** 2 / 2.5 * 1.01
    safety = step_control.VISCOUS_SAFETY
    try:
        step_control.VISCOUS_SAFETY = safety / 2
        half = simulate(params.replace(cfl=params.cfl / 2))
    finally:
        step_control.VISCOUS_SAFETY = safety
    assert half.diagnostics["steps"] >= 2 * d["steps"] - 1
    for k, tol in (("P1", 0.05), ("P2", 0.05), ("CH", 0.05), ("t_A1", 0.05), ("t_A2", 0.05),
                   ("DA", 0.005)):
        assert abs(half.metrics[k] - full.metrics[k]) < tol, (k, half.metrics[k], full.metrics[k])
    assert np.isfinite(full.metrics["CH"])
