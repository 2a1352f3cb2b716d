"""The parts of the coupled step, each alone: the Dirichlet-Neumann iteration on a linear model
problem, the rigid globe, the step control's sound-speed rule and limits."""

import math

import numpy as np
import pytest

from airpuff_core import RunParams, SimulationError
from airpuff_core.coupling import CoupledModel
from airpuff_core.dirichlet_neumann import DirichletNeumann
from airpuff_core.globe import RigidGlobe, globe_for_run
from airpuff_core.kernels.nodes import WALL
from airpuff_core.step_control import VISCOUS_SAFETY, sound_speed


def _linear_interface(A, b, p0):
    """The map p -> A p + b of a linear interface problem, as the coupled step's update: it fills
    p_new and returns ||p_new - p_est|| / max(||p_est - p0||, 1) (max norms)."""
    def update(p_est, p_new):
        p_new[:] = A @ p_est + b
        return float(np.max(np.abs(p_new - p_est)) / max(np.max(np.abs(p_est - p0)), 1.0))
    return update


def test_the_coupling_starts_closer_to_the_answer_than_p_n():
    """The first estimate p^n + dt dp/dt (the last step's rate) is second-order close to the
    converged p^{n+1} where p^n is first-order close: during the jet's rise (coarse clinical
    preset, steps 100-300) it is more than 3 times closer than p^n in the median (measured:
    5.1 times)."""
    model = CoupledModel(RunParams(resolution="coarse", model="clinical"))
    ratios = []
    for step in range(300):
        p_n = model.p_interface.copy()
        model.step()
        if step >= 100:
            converged = model.coupling.pressure
            ratios.append(np.linalg.norm(model._p_start - converged)
                          / np.linalg.norm(p_n - converged))
    assert np.median(ratios) < 0.3, np.median(ratios)


def test_dirichlet_neumann_converges_to_the_fixed_point_of_a_contraction():
    rng = np.random.default_rng(3)
    n = 6
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A = Q @ np.diag(np.linspace(-0.5, 0.5, n)) @ Q.T  # spectral radius 0.5
    b = rng.standard_normal(n) * 100.0
    p_fixed = np.linalg.solve(np.eye(n) - A, b)
    dn = DirichletNeumann(1e-10, 200, n)
    iterations = dn.iterate(_linear_interface(A, b, 0.0), np.zeros(n), 1.0)
    # the error contracts by 0.5 per iteration: about log2(|p*| / (tol |p*|)) iterations
    assert 2 <= iterations <= 45 and dn.iterations == iterations and dn.residual < 1e-10
    p_final = A @ dn._pressures[0] + b  # the last estimate mapped once more
    np.testing.assert_allclose(p_final, p_fixed, rtol=1e-8)


def test_dirichlet_neumann_takes_two_iterations_at_least_and_fails_on_divergence_or_nan():
    n = 3
    dn = DirichletNeumann(1e-6, 30, n)
    assert dn.iterate(_linear_interface(np.zeros((n, n)), np.zeros(n), 0.0), np.zeros(n), 0.0) == 2
    with pytest.raises(SimulationError, match="did not converge at t = 2.5000 ms") as err:
        dn.iterate(_linear_interface(1.5 * np.eye(n), np.ones(n), 0.0), np.ones(n), 2.5)
    assert err.value.reason == "coupling"
    with pytest.raises(SimulationError, match="blew up") as err:
        dn.iterate(lambda p_est, p_new: math.nan, np.ones(n), 0.0)
    assert err.value.reason == "blow-up"


def test_the_rigid_globe_does_nothing():
    params = RunParams()
    model = CoupledModel(params)
    n = model.chamber.n
    y, vx, vy = np.arange(float(n)), np.ones(n), -np.ones(n)
    before = (y.copy(), vx.copy(), vy.copy())
    globe = RigidGlobe(params.si(), params.geometry, model.chamber)
    globe.start(1.0, 1.0)
    globe.impose(y, y, vx, vy, 10.0, 1e-6, y, vx, vy)
    globe.commit(1.0, 1.0, 1e-6, 10.0, np.full(n, 1000.0))
    for a, b in zip((y, vx, vy), before):
        np.testing.assert_array_equal(a, b)
    assert globe.work(np.ones(n), 2 * np.ones(n), 10.0) == 0.0
    assert globe.volume_change() == 0.0 and globe.pressure() == params.si().p0_Pa
    # the fluid at its reference density presses on the walls with the IOP
    assert globe.wall_pressure(np.full(n, 1000.0), 10.0) == pytest.approx(params.si().p0_Pa,
                                                                           rel=1e-14)


def test_a_run_with_the_rigid_globe_never_moves_a_wall_node():
    model = CoupledModel(RunParams(t_end=0.2))
    assert isinstance(model.globe, RigidGlobe)
    walls = model.fluid.kind == WALL
    x0, y0 = model.x[walls].copy(), model.y[walls].copy()
    while model.t < 0.2e-3 - 1e-15:
        model.step(t_stop=0.2e-3)
    np.testing.assert_array_equal(model.x[walls], x0)
    np.testing.assert_array_equal(model.y[walls], y0)
    assert model.chamber_volume() == model.cornea_chamber_volume()


def test_the_bound_of_the_next_step_is_its_acoustic_limit():
    """``max_step``, which the recorder asks before a step whether an output time may fall in
    it, is the next step's acoustic limit exactly (so never below its dt) while the jet speeds
    the fluid up and raises the sound speed."""
    model = CoupledModel(RunParams(c_rule="running_max"))
    control = model.control
    for _ in range(40):
        bound = control.max_step()
        dt = model.step()
        assert dt <= bound
        assert bound == control.dt_limits["acoustic"]
    assert control.c > control.c0  # the sound speed did move


def test_sound_speed_rules_and_step_limits():
    assert sound_speed("fixed", 10.0, 20.0, 0.3, 0.5) == 10.0
    assert sound_speed("per_step", 10.0, 20.0, 0.3, 0.5) == 10.0 + 20.0 * 0.3
    assert sound_speed("running_max", 10.0, 20.0, 0.3, 0.5) == 10.0 + 20.0 * 0.5
    params = RunParams(mu=2.5)
    model = CoupledModel(params)
    control = model.control
    dt = control.time_step()
    h, rho = model.fluid.h_min, params.rho_fluid
    assert control.dt_limits["acoustic"] == pytest.approx(0.6 * h / 10.0, rel=1e-12)  # at rest
    assert control.dt_limits["viscous"] == pytest.approx(VISCOUS_SAFETY * rho * h * h / 2.5,
                                                         rel=1e-12)
    assert dt == min(control.dt_limits.values())
    assert control.max_step() == pytest.approx(0.6 * h / 10.0, rel=1e-12)
    assert globe_for_run(params, params.si(), model.chamber, model.X, model.Y,
                         model.fluid.mass).pressure() == params.si().p0_Pa
