"""Quasi-linear viscoelasticity: Simo's recursive update against the hereditary integral.

The reference values are closed forms of S(t) = int G(t - s) dS_e/ds ds, computed here from the
relaxation function, not from the kernel."""

import math

import numpy as np
import pytest

from airpuff_core.kernels.viscoelastic import (prony_step_factors, relax_in_place,
                                               relax_resultant, relaxation_function)


def run_history(times, s_eq, g, tau):
    """Total resultant at each knot of a piecewise-linear equilibrium-law history s_eq(times),
    one kernel step per segment (any step sizes)."""
    g, tau = np.asarray(g, float), np.asarray(tau, float)
    decay, weight = np.empty_like(g), np.empty_like(g)
    q = np.zeros(g.shape[0])
    out = [s_eq[0]]
    for n in range(len(times) - 1):
        prony_step_factors(times[n + 1] - times[n], g, tau, decay, weight)
        out.append(relax_resultant(s_eq[n], s_eq[n + 1], decay, weight, q))
    return np.array(out)


def hereditary_integral(t, knots, s_eq, g, tau):
    """Exact S(t) for a piecewise-linear s_eq with zero history before knots[0]:
    S = s_eq(t) + sum_i g_i/G_inf sum_pieces slope tau_i (exp(-(t-b)/tau_i) - exp(-(t-a)/tau_i))."""
    g_inf = 1.0 - sum(g)
    total = np.interp(t, knots, s_eq)
    for gi, ti in zip(g, tau):
        for a, b, sa, sb in zip(knots[:-1], knots[1:], s_eq[:-1], s_eq[1:]):
            if a >= t:
                break
            b_ = min(b, t)
            slope = (sb - sa) / (b - a)
            total += gi / g_inf * slope * ti * (math.exp(-(t - b_) / ti) - math.exp(-(t - a) / ti))
    return total


def test_strain_step_relaxes_as_G():
    """A step of the elastic resultant (applied within 1e-9 s) relaxes as S(t) = S_e G(t), with
    S_e = S_eq / G_inf the instantaneous response, to 1e-6, over steps of any size."""
    g, tau = [0.3], [10e-3]
    rng = np.random.default_rng(1)
    dts = rng.uniform(0.01e-3, 2e-3, 60)  # irregular steps, up to 0.2 tau
    times = np.concatenate(([0.0, 1e-9], 1e-9 + np.cumsum(dts)))
    s_eq_step = 2.5  # N/m
    s_eq = np.full(times.shape, s_eq_step)
    s_eq[0] = 0.0
    S = run_history(times, s_eq, g, tau)
    G = relaxation_function(times[1:], g, tau)
    g_inf = 1.0 - sum(g)
    np.testing.assert_allclose(S[1:] * g_inf / s_eq_step, G, rtol=1e-6, atol=0)
    # long after the step: fully relaxed, the equilibrium law
    S_late = run_history(np.array([0.0, 1e-9, 1.0]), np.array([0.0, s_eq_step, s_eq_step]), g, tau)
    assert S_late[-1] == pytest.approx(s_eq_step, rel=1e-12)


@pytest.mark.parametrize("g,tau", [([0.3], [10e-3]), ([0.2, 0.45], [1e-3, 25e-3])])
def test_piecewise_linear_history_is_exact_for_any_step(g, tau):
    """Simo's update is exact for piecewise-linear histories: ramps up and down with steps of
    0.001 to 3 tau agree with the hereditary integral to round-off."""
    rng = np.random.default_rng(7)
    knots = np.concatenate(([0.0], np.cumsum(rng.uniform(0.01e-3, 30e-3, 40))))
    s_eq = np.concatenate(([0.0], rng.normal(0.0, 3.0, 40)))
    S = run_history(knots, s_eq, g, tau)
    exact = np.array([hereditary_integral(t, knots, s_eq, g, tau) for t in knots])
    np.testing.assert_allclose(S, exact, rtol=0, atol=1e-12 * np.max(np.abs(exact)))


def test_zero_g_recovers_the_elastic_law_exactly():
    rng = np.random.default_rng(3)
    n = 17
    old, new = rng.normal(size=n), rng.normal(size=n)
    g, tau = np.zeros(1), np.array([10e-3])
    decay, weight = np.empty(1), np.empty(1)
    prony_step_factors(1e-6, g, tau, decay, weight)
    q = np.zeros((1, n))
    values = new.copy()
    relax_in_place(values, old.copy(), decay, weight, q, True)
    assert np.array_equal(values, new)
    assert not np.any(q)


def test_in_place_update_matches_the_scalar_update():
    """One step in place: the totals and overstresses of the scalar update, and ``previous``
    becomes the new equilibrium values; without ``advance`` the stored overstresses are only
    added."""
    rng = np.random.default_rng(5)
    g, tau = np.array([0.2, 0.3]), np.array([2e-3, 20e-3])
    decay, weight = np.empty(2), np.empty(2)
    prony_step_factors(0.7e-3, g, tau, decay, weight)
    old, new = rng.normal(size=6), rng.normal(size=6)
    q = rng.normal(size=(2, 6))
    q_ref = q.copy()
    values, previous = new.copy(), old.copy()
    relax_in_place(values, previous, decay, weight, q, True)
    np.testing.assert_array_equal(previous, new)
    for k in range(6):
        col = q_ref[:, k].copy()
        assert values[k] == relax_resultant(old[k], new[k], decay, weight, col)
        np.testing.assert_array_equal(col, q[:, k])
    held = new.copy()
    relax_in_place(held, previous, decay, weight, q, False)
    np.testing.assert_allclose(held, new + q.sum(axis=0), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(previous, new)


def test_cycle_dissipates():
    """A closed cycle of a linear law (S_eq = K E) absorbs positive work, int S dE > 0, and none
    with g = 0 (to round-off)."""
    K = 100.0
    t = np.linspace(0.0, 20e-3, 401)
    E = 0.01 * np.sin(np.pi * t / 20e-3) ** 2  # 0 -> peak -> 0
    for g, positive in (([0.3], True), ([0.0], False)):
        S = run_history(t, K * E, g, [10e-3])
        work = float(np.sum(0.5 * (S[1:] + S[:-1]) * np.diff(E)))
        if positive:
            assert work > 1e-3 * K * 0.01 ** 2
        else:
            assert abs(work) < 1e-12
