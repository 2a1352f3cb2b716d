"""The instruments' applanation read-outs (``airpuff_core.readout``) on closed-form shapes."""

import math

import numpy as np
import pytest

from airpuff_core.readout import (corvis_departure, nodal_slopes, ora_signal,
                                  signal_applanations)

# nodes of a profile out to 2.5 mm, non-uniform like a mesh graded towards the apex
X = np.concatenate([[0.0], np.cumsum(np.linspace(0.12, 0.3, 12))])


def cap(kappa):
    """A spherical cap of curvature kappa [1/mm] (convex > 0), apex at y = 0."""
    if kappa == 0.0:
        return np.zeros_like(X)
    r = 1.0 / kappa
    return np.sign(r) * (np.sqrt(r * r - X * X) - abs(r))


def test_nodal_slopes_exact_on_parabola():
    y = 0.3 - 0.07 * X ** 2
    assert np.allclose(nodal_slopes(X, y), -0.14 * X, rtol=0, atol=1e-12)


@pytest.mark.parametrize("kappa", [0.0, 0.004, -0.01, 0.03])
@pytest.mark.parametrize("r_zone,acceptance", [(1.0, 0.05), (1.5, 0.02)])
def test_ora_signal_of_a_cap(kappa, r_zone, acceptance):
    """S = (1 - exp(-u)) / u, u = (2 kappa r_zone / acceptance)^2, for slopes small enough
    that atan and the cap's slope are kappa r to within 1e-4 (relative)."""
    u = (2.0 * kappa * r_zone / acceptance) ** 2
    expected = 1.0 if u == 0.0 else (1.0 - math.exp(-u)) / u
    assert ora_signal(X, cap(kappa), r_zone, acceptance) == pytest.approx(expected, rel=2e-3)


@pytest.mark.parametrize("kappa", [0.0, 0.01, -0.05])
def test_corvis_departure_of_a_parabola(kappa):
    """y = -kappa x^2 / 2 over |x| <= h = L/2: D2 = kappa^2 h^4 / 45."""
    length = 1.82
    h = 0.5 * length
    d = corvis_departure(X, -0.5 * kappa * X ** 2, length)
    # the profile is linear between nodes: within the chord's interpolation error
    assert d == pytest.approx(kappa ** 2 * h ** 4 / 45.0, rel=0.04, abs=1e-15)


def test_signal_applanations_of_a_sequence_of_caps():
    """Caps whose curvature falls through 0 at t1, reaches a concave extreme and rises through
    0 at t2: the ORA signal peaks (flat caps) and the Corvis departure's minima are at t1, t2,
    on steps that straddle them unevenly."""
    t1, t2, t_split = 8.3137, 21.0711, 15.0
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.02, 0.06, 700))  # to about 28 ms
    kappa = 0.13 * np.sin(math.pi * (t - t1) / (t2 - t1) + math.pi)
    s_ora = np.array([ora_signal(X, cap(k), 1.0, 0.05) for k in kappa])
    s_corvis = -np.array([corvis_departure(X, cap(k), 1.82) for k in kappa])
    dt = np.max(np.diff(t))
    for s, passages in ((s_ora, True), (s_corvis, False), (s_corvis, True)):
        a1, a2 = signal_applanations(t, s, t_split, passages)
        assert abs(a1 - t1) < 0.05 * dt and abs(a2 - t2) < 0.05 * dt


def plateau(t, heights, times=(20.3, 20.95, 21.6), width=0.25):
    """Nearly equal Gaussian humps [1] at ``times`` [ms] over a floor of 0.002: a cornea that
    lingers near flat."""
    return 0.002 + sum(h * np.exp(-((t - tk) / width) ** 2) for h, tk in zip(heights, times))


def test_the_last_of_nearly_equal_peaks_is_the_second_applanation():
    """A plateau whose earlier hump is the highest (0.262 against 0.261 and 0.259) and one whose
    last is: the second applanation is the last hump's vertex in both, where the highest peak
    would jump by 1.3 ms.  Before the split, the first of two humps is the first applanation."""
    t = np.cumsum(np.random.default_rng(2).uniform(0.02, 0.06, 700))
    for heights in ((0.262, 0.259, 0.261), (0.261, 0.259, 0.262)):
        s = plateau(t, heights) + plateau(t, heights[::-1], (8.0, 8.65, 9.3))
        a1, a2 = signal_applanations(t, s, 15.0)
        # a neighbouring hump's tail shifts the vertex by a few thousandths of a millisecond
        assert a1 == pytest.approx(8.0, abs=0.01) and a2 == pytest.approx(21.6, abs=0.01)


def test_a_shoulder_is_not_a_peak():
    """Shoulders more than half way from the resting signal to the peak (0.15 of 0.26: only the
    centre flat) after the last applanation's peak and before the first: neither is an
    applanation."""
    t = np.linspace(0.0, 30.0, 3001)
    s = plateau(t, (0.15, 0.26, 0.26, 0.15), (5.0, 8.0, 21.0, 22.5))
    a1, a2 = signal_applanations(t, s, 15.0)
    assert a1 == pytest.approx(8.0, abs=1e-3) and a2 == pytest.approx(21.0, abs=1e-3)


def test_a_departure_that_rests_near_flat_is_measured_from_rest():
    """A resting departure from flat (0.01 mm^2) far below the highest concavity's (0.2): as
    first and last passages, wiggles of the resting cornea are not applanations, the minima of
    D2 about 8 and 21 ms are (the signal's range would count the wiggles)."""
    t = np.linspace(0.0, 30.0, 3001)
    d2 = (0.01 + 1e-5 * np.sin(40.0 * t)
          + (0.2 - 0.01) * np.exp(-((t - 14.5) / 3.0) ** 2)  # the concave phase
          - 0.0099 * (np.exp(-((t - 8.0) / 0.4) ** 2) + np.exp(-((t - 21.0) / 0.4) ** 2)))
    a1, a2 = signal_applanations(t, -d2, 14.5)
    assert a1 == pytest.approx(8.0, abs=0.05) and a2 == pytest.approx(21.0, abs=0.05)


def test_no_peak_is_nan():
    t = np.linspace(0.0, 10.0, 50)
    for passages in (True, False):  # rising throughout: no peak
        a1, a2 = signal_applanations(t, t.copy(), 5.0, passages)
        assert math.isnan(a1) and math.isnan(a2)
