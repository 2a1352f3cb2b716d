"""Whole-eye motion (globe/motion.py) and the Corvis outputs (metrics.py): the spring-damper step
against the closed forms of its ODE, the pulse's force against exact integrals, the peak distance
of synthetic profiles, and a coarse run whose outputs are consistent (docs/model.md section 14)."""

import json
import math

import numpy as np
import pytest
from scipy.special import erfcx

from airpuff_core.dataset import open_dataset
from airpuff_core.globe.motion import SpringDamperEye, pulse_force
from airpuff_core.metrics import peak_distance
from airpuff_core.result import METRICS

from tests.conftest import airpuff

# Kling et al. 2014, table 3, and a 7.5 g eye
MASS, SPRING, DAMPER = 7.5e-3, 350.0, 100.0


def integrate(eye, force, dt, t_end):
    """x(t) [m] of ``eye`` under force(t) [N] on the steps 0, dt, ..., t_end."""
    n = int(round(t_end / dt))
    eye.start(force(0.0))
    x = np.empty(n + 1)
    x[0] = eye.displacement
    for i in range(1, n + 1):
        eye.advance(dt, lambda: force(i * dt))
        x[i] = eye.displacement
    return np.arange(n + 1) * dt, x


def step_response(t, m, c, k, F0):
    """x(t) of m x'' + c x' + k x = F0 (t >= 0), x(0) = x'(0) = 0, over- or underdamped:
    x = F0/k [1 - (r2 e^{r1 t} - r1 e^{r2 t}) / (r2 - r1)], r1,2 the roots of m r^2 + c r + k."""
    disc = np.sqrt(complex(c * c - 4.0 * m * k))
    r1, r2 = (-c + disc) / (2.0 * m), (-c - disc) / (2.0 * m)
    return (F0 / k * (1.0 - (r2 * np.exp(r1 * t) - r1 * np.exp(r2 * t)) / (r2 - r1))).real


def gaussian_response(t, m, c, k, F0, t0, sigma):
    """x(t) of the overdamped m x'' + c x' + k x = F0 exp(-(t - t0)^2 / sigma^2) from rest at
    t = 0: the impulse response (e^{r1 t} - e^{r2 t}) / (m (r1 - r2)) convolved with the force,
    each exponential's integral in closed form with erfcx (no overflow at large |r|):

        int_0^t e^{r (t - s)} e^{-(s - t0)^2/sigma^2} ds
          = sigma sqrt(pi)/2 [e^{-(t-t0)^2/sigma^2} erfcx(w1) - e^{r t - t0^2/sigma^2} erfcx(w0)],
        w1 = -(t - t0 + r sigma^2/2) / sigma,  w0 = (t0 - r sigma^2/2) / sigma."""
    disc = math.sqrt(c * c - 4.0 * m * k)
    r1, r2 = (-c + disc) / (2.0 * m), (-c - disc) / (2.0 * m)

    def conv(r):
        w1 = -(t - t0 + r * sigma ** 2 / 2.0) / sigma
        w0 = (t0 - r * sigma ** 2 / 2.0) / sigma
        return sigma * math.sqrt(math.pi) / 2.0 * (
            np.exp(-(t - t0) ** 2 / sigma ** 2) * erfcx(w1)
            - np.exp(r * t - t0 ** 2 / sigma ** 2) * erfcx(w0))

    return F0 * (conv(r1) - conv(r2)) / (m * (r1 - r2))


@pytest.mark.parametrize("m,c,k", [(MASS, DAMPER, SPRING),  # Kling's orbit: overdamped
                                   (MASS, 0.5, SPRING)])  # damping ratio 0.15: it rings
def test_step_force_against_closed_form_second_order(m, c, k):
    F0 = 0.07  # N, the paper's jet on the cornea at its peak
    errors = []
    for dt in (20e-6, 10e-6):
        t, x = integrate(SpringDamperEye(m, k, c), lambda s: F0, dt, 0.05)
        exact = step_response(t, m, c, k, F0)
        errors.append(np.max(np.abs(x - exact)) / np.max(np.abs(exact)))
    assert errors[1] < 1e-3
    # the force jumps at t = 0 (the start accelerates the eye at F0/m): the rule stays second order
    assert errors[0] / errors[1] == pytest.approx(4.0, rel=0.15)


def test_gaussian_puff_against_closed_form():
    """The paper's jet on the cornea as a force (F0 = pmax pi R^2 / a, eq. 11 in time, 70.8 mN in
    a run) on Kling's orbit, with the solver's step size: x(t) within 1e-5 of its peak, which
    is close to the impulse over the damper, J / c."""
    F0, t0, sigma = 0.0716, 15e-3, 30e-3 / 5.0  # N, s, s: T / sqrt(b) with T 30 ms, b 25
    force = lambda s: F0 * math.exp(-(s - t0) ** 2 / sigma ** 2)  # noqa: E731
    t, x = integrate(SpringDamperEye(MASS, SPRING, DAMPER), force, 5e-6, 0.035)
    exact = gaussian_response(t, MASS, DAMPER, SPRING, F0, t0, sigma)
    assert np.max(np.abs(x - exact)) < 1e-5 * np.max(exact)
    impulse = F0 * sigma * math.sqrt(math.pi)
    assert 0.85 * impulse / DAMPER < np.max(x) < impulse / DAMPER


def test_pulse_force_exact_integrals():
    # a uniform pressure on any profile: p pi x_limbus^2, exactly
    x = np.sort(np.random.default_rng(1).uniform(0.0, 5e-3, 30))
    x[0] = 0.0
    y = 1e-3 * np.cos(x / 3e-3) + 2e-4 * np.sin(x / 1e-3)
    assert pulse_force(x, y, np.full_like(x, 1234.0)) == pytest.approx(
        1234.0 * math.pi * x[-1] ** 2, rel=1e-13)
    # a Gaussian on a flat disc: p0 pi s^2 (1 - exp(-X^2/s^2)), second order in the node spacing
    p0, s, X = 1e4, 1.5e-3, 5e-3
    exact = p0 * math.pi * s * s * (1.0 - math.exp(-X * X / (s * s)))
    errors = []
    for n in (26, 51):
        x = np.linspace(0.0, X, n)
        errors.append(abs(pulse_force(x, np.zeros(n), p0 * np.exp(-x * x / (s * s))) - exact))
    assert errors[1] < 2e-3 * exact
    assert errors[0] / errors[1] == pytest.approx(4.0, rel=0.2)


def test_peak_distance_of_synthetic_profiles():
    # y = -(x^2 - xp^2)^2: the apex dented, peaks at +-xp, nodes not on the peak; the error
    # falls with the square of the node spacing h (0.24, 0.12, 0.06)
    xp = 2.3
    for n, tol in ((26, 3e-3), (51, 1.5e-3), (101, 3e-4)):
        x = np.linspace(0.0, 6.0, n)
        assert peak_distance(x, -(x * x - xp * xp) ** 2) == pytest.approx(2 * xp, rel=tol)
    # the vertex of a parabola through the nodes is exact
    x = np.linspace(0.0, 6.0, 26)
    assert peak_distance(x, -(x - 2.345) ** 2) == pytest.approx(2 * 2.345, rel=1e-12)
    # a convex cornea (apex highest) has no peaks
    assert math.isnan(peak_distance(x, np.cos(x / 7.0)))


@pytest.fixture(scope="module")
def eye_run(tmp_path_factory):
    """The default coarse run with the eye on Kling's orbit: (metrics, netCDF path)."""
    out = tmp_path_factory.mktemp("eye") / "run.nc"
    proc = airpuff("run", "--resolution", "coarse", "--eye-motion", "spring_damper", "--json",
                   "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout), out


def test_corvis_outputs_consistent(eye_run):
    m, path = eye_run
    ds = open_dataset(path)
    for name in ("DA", "deflection_amplitude", "deflection_amplitude_HC", "WEM_max", "t_WEM_max",
                 "WEM_HC", "peak_distance", "v_A1", "v_A2", "t_A1", "t_A2", "t_HC"):
        assert m[name] is not None and math.isfinite(m[name]), name
        assert ds[name].attrs["units"] == METRICS[name][0]
    t = ds.time.values
    i_hc = int(np.argmax(ds.apex_deformation.values))
    assert m["t_HC"] == t[i_hc]
    # DA = deflection + WEM at the highest concavity
    assert m["DA"] == pytest.approx(m["deflection_amplitude_HC"] + m["WEM_HC"], abs=1e-12)
    assert m["deflection_amplitude"] == float(ds.apex_displacement.max())
    assert m["deflection_amplitude"] <= m["DA"] <= m["deflection_amplitude"] + m["WEM_max"]
    # the eye moves back by at most the pulse's impulse over the damper, and by most of it
    impulse = np.trapezoid(ds.pulse_force.values * 1e-3, t * 1e-3)  # N s
    assert 0.85 * impulse / 100.0 < m["WEM_max"] * 1e-3 < impulse / 100.0
    assert m["WEM_max"] == float(ds.eye_displacement.max())
    # the apex velocities at the applanations are the instrument's: the apex's plus the eye's
    v = ds.apex_velocity.values + ds.eye_velocity.values
    assert m["v_A1"] == pytest.approx(np.interp(m["t_A1"], t, v), abs=2e-3)
    assert m["v_A2"] == pytest.approx(np.interp(m["t_A2"], t, v), abs=2e-3)
    assert m["v_A1"] > 0.0 > m["v_A2"]


def test_eye_motion_does_not_act_back(eye_run, coarse_run):
    """The eye's motion is integrated beside the coupled step: every output of the run with the
    eye at rest is the same bit for bit, but the instrument's displacement and what follows."""
    _, path = eye_run
    _, rest_path = coarse_run
    moving, rest = open_dataset(path), open_dataset(rest_path)
    changed = {"DA", "t_HC", "hc_delay", "WEM_max", "t_WEM_max", "WEM_HC", "v_A1", "v_A2",
               "deflection_amplitude_HC", "peak_distance", "apex_deformation", "eye_displacement",
               "eye_velocity", "eye_motion"}
    snapshots = {v for v in rest.data_vars if "snapshot" in rest[v].dims}
    for name in rest.data_vars:
        if name in changed or name in snapshots:
            continue
        assert np.array_equal(moving[name].values, rest[name].values, equal_nan=True), name
    assert float(moving.DA) > float(rest.DA)
