"""The instruments' air pulses (docs/model.md section 6): the kernels against their analytic
definitions written here, the ORA's switch-off at the applanation it detects in a coarse run,
and the bad values of the pulses' parameters named with their range."""

import math
import subprocess
import sys

import numpy as np
import pytest

from airpuff_core import ParameterError, RunParams, simulate
from airpuff_core.kernels.air_jet import RAMP, SWITCH_OFF, TABLE, jet_pressures, pulse_pressure
from airpuff_core.loads import pulse_for_run
from airpuff_core.loads.corvis import CORVIS_APEX_MMHG, CORVIS_START_MS, CORVIS_STEP_MS
from airpuff_core.params import MMHG_PA, ORA_ONSET, ORA_RISE_RATE

PHI = np.linspace(0.0, math.pi / 3, 7)
TIMES = np.linspace(0.0, 0.035, 71)


def _pulse(instrument, **options):
    params = RunParams(instrument=instrument, **options)
    return pulse_for_run(params, params.si(), PHI)


def test_paper_pulse_is_eq_11():
    jet = _pulse("paper", pmax=8.0, a=30.0, b=20.0, T=25.0, t0=12.0)
    out = np.empty_like(PHI)
    for t in TIMES:
        jet.pressures(t, PHI, out)
        expected = 8e3 * np.exp(-30.0 * np.sin(PHI) ** 2) * np.exp(-20.0 * (t - 0.012) ** 2
                                                                   / 0.025 ** 2)
        np.testing.assert_allclose(out, expected, rtol=1e-14, atol=0.0)
    assert jet.peak_time == 0.012 and not jet.watches_applanation


def _ora_rise(t, rate, tau):
    """f(t) of the ORA's pump (docs/model.md section 6), written as the integral of its rate,
    which rises linearly from 0 to ``rate`` over ``tau`` and is constant after."""
    if tau == 0.0:
        return rate * t
    return rate * (t * t / (2.0 * tau) if t < tau else tau / 2.0 + (t - tau))


@pytest.mark.parametrize("tau_ms", [0.0, 3.5])
def test_ora_pulse_rises_then_falls_from_its_switch_off(tau_ms):
    """A(t) = f(t) up to t_off (f' rising from 0 to r_rise over tau, then r_rise), then
    f(t_off) - r_fall (t - t_off) down to 0, times exp(-a sin^2 phi); without a switch-off it
    keeps rising; f is continuous with a continuous rate at tau."""
    jet = _pulse("ora", ora_rise_rate=0.5, ora_fall_rate=0.8, ora_delay=2.0, a=15.0,
                 ora_onset=tau_ms)
    rise, fall, tau = 0.5e6, 0.8e6, tau_ms * 1e-3  # Pa/s, s
    spatial = np.exp(-15.0 * np.sin(PHI) ** 2)
    out = np.empty_like(PHI)
    for t in TIMES:
        jet.pressures(t, PHI, out)
        np.testing.assert_allclose(out, _ora_rise(t, rise, tau) * spatial, rtol=1e-13,
                                   atol=1e-9)
    t_off = 0.011
    jet.kernel_args[SWITCH_OFF] = t_off
    peak = _ora_rise(t_off, rise, tau)
    for t in TIMES:
        amplitude = _ora_rise(t, rise, tau) if t <= t_off else max(0.0, peak - fall * (t - t_off))
        jet.pressures(t, PHI, out)
        np.testing.assert_allclose(out, amplitude * spatial, rtol=1e-13, atol=1e-9)
    assert jet.at_apex(t_off) == pytest.approx(peak, rel=1e-14)
    assert jet.at_apex(t_off + peak / fall + 1e-6) == 0.0
    if tau > 0.0:  # the rate at the end of the onset, from either side
        h = 1e-7
        left = (jet.at_apex(tau) - jet.at_apex(tau - h)) / h
        right = (jet.at_apex(tau + h) - jet.at_apex(tau)) / h
        assert left == pytest.approx(rise, rel=1e-4) and right == pytest.approx(rise, rel=1e-6)
        assert jet.at_apex(1e-4) / (rise * 1e-4) == pytest.approx(1e-4 / (2.0 * tau), rel=1e-12)


def test_ora_switch_off_is_set_once_at_the_detected_applanation_plus_delay():
    """The pump is switched off ``delay`` after the reflection signal's first peak of at least
    the detection threshold: a smaller bump before it is no applanation, and the peak's time is
    the vertex of the parabola through the top sample and its neighbours (at 1, 2, 3 ms through
    0.2, 0.3, 0.25: 2 + 1/6 ms)."""
    jet = _pulse("ora", ora_delay=3.0)
    for t_ms, signal in ((0.0, 0.001), (0.5, 0.05), (0.7, 0.04), (1.0, 0.2), (2.0, 0.3)):
        jet.observe(t_ms * 1e-3, signal)
    assert math.isinf(jet.peak_time) and math.isnan(jet.detected_applanation)
    jet.observe(0.003, 0.25)
    assert jet.detected_applanation == pytest.approx((2.0 + 1.0 / 6.0) * 1e-3, rel=1e-12)
    assert jet.peak_time == pytest.approx((5.0 + 1.0 / 6.0) * 1e-3, rel=1e-12)
    for t_ms, signal in ((4.0, 0.01), (5.0, 0.5), (6.0, 0.1)):  # a later peak does not move it
        jet.observe(t_ms * 1e-3, signal)
    assert jet.peak_time == pytest.approx((5.0 + 1.0 / 6.0) * 1e-3, rel=1e-12)
    late = _pulse("ora", ora_delay=0.0)
    for t_ms, signal in ((1.0, 0.2), (2.0, 0.3), (3.0, 0.25)):
        late.observe(t_ms * 1e-3, signal)
    assert late.peak_time == 0.003  # a delay already passed: switched off now


def test_corvis_pulse_is_its_table_interpolated_linearly():
    jet = _pulse("corvis", a=21.5)
    start, step = CORVIS_START_MS * 1e-3, CORVIS_STEP_MS * 1e-3
    samples = np.asarray(CORVIS_APEX_MMHG) * MMHG_PA
    for k, value in enumerate(samples):
        assert jet.at_apex(start + k * step) == pytest.approx(value, rel=1e-12, abs=1e-9)
    for k in range(len(samples) - 1):
        mid = start + (k + 0.5) * step
        assert jet.at_apex(mid) == pytest.approx(0.5 * (samples[k] + samples[k + 1]), rel=1e-12,
                                                 abs=1e-9)
    assert jet.at_apex(start - 1e-4) == 0.0 and jet.at_apex(0.0) == 0.0
    assert jet.at_apex(start + len(samples) * step) == 0.0
    out = np.empty_like(PHI)
    jet.pressures(0.016, PHI, out)
    np.testing.assert_allclose(out, jet.at_apex(0.016) * np.exp(-21.5 * np.sin(PHI) ** 2),
                               rtol=1e-14)
    assert jet.peak_time == pytest.approx(0.018, rel=1e-12)  # 94.21 mmHg
    assert jet.at_apex(jet.peak_time) / MMHG_PA == pytest.approx(94.21, rel=1e-12)


def test_a_table_pulse_with_a_switch_off_falls_from_it():
    """The kernel's general form: any table switched off at t_off falls at r_fall."""
    jet = np.array([TABLE, 0.0, 0.004, 1e6, 0.0, 0.002, 0.0, 1000.0, 3000.0, 0.0])
    assert pulse_pressure(0.003, 0.0, jet) == pytest.approx(2000.0, rel=1e-14)
    assert pulse_pressure(0.004, 0.0, jet) == pytest.approx(3000.0, rel=1e-14)
    assert pulse_pressure(0.005, 0.0, jet) == pytest.approx(2000.0, rel=1e-12)
    assert pulse_pressure(0.010, 0.0, jet) == 0.0
    ramp = np.array([RAMP, 0.0, math.inf, 0.0, 0.001, 2e6, 0.0])
    out = np.empty(2)
    jet_pressures(0.0005, np.zeros(2), ramp, out)
    assert list(out) == [0.0, 0.0]  # before its onset


def test_ora_run_switches_off_at_its_detected_applanation_plus_delay():
    """A coarse run under the ORA's pulse: the pump is switched off at the first applanation
    the run reports (t_A1, the reflection signal's peak as metrics.py finds it) plus the delay,
    and the stored pulse at the apex is the ramp up to it and the fall after it."""
    delay = 2.0
    result = simulate(RunParams(instrument="ora", ora_delay=delay, t_end=16.0))
    diag, m = result.diagnostics, result.metrics
    assert diag["pulse_applanation_detected_ms"] == pytest.approx(m["t_A1"], abs=1e-9)
    t_off = diag["pulse_switch_off_ms"]
    assert t_off == pytest.approx(m["t_A1"] + delay, abs=1e-9)
    rise = fall = ORA_RISE_RATE * 1e3 / MMHG_PA  # mmHg/ms, the defaults (kPa/ms)
    t = result.time
    f = np.array([_ora_rise(v, rise, ORA_ONSET) for v in t])
    peak = _ora_rise(t_off, rise, ORA_ONSET)
    expected = np.where(t <= t_off, f, np.maximum(0.0, peak - fall * (t - t_off)))
    np.testing.assert_allclose(result.histories["jet_pressure_apex"], expected, rtol=1e-12,
                               atol=1e-12)
    assert diag["pulse_peak_apex_mmHg"] == pytest.approx(peak, rel=1e-12)
    assert m["P1"] == pytest.approx(_ora_rise(m["t_A1"], rise, ORA_ONSET), rel=1e-12)


@pytest.mark.parametrize("options,name,accepted", [
    ({"instrument": "nct"}, "instrument", "one of paper, ora, corvis"),
    ({"instrument": "ora", "ora_delay": 21.0}, "ora_delay", "[0, 20] ms"),
    ({"instrument": "ora", "ora_rise_rate": 0.0}, "ora_rise_rate", "(0, 10] kPa/ms"),
    ({"instrument": "ora", "ora_fall_rate": -1.0}, "ora_fall_rate", "(0, 10] kPa/ms"),
    ({"instrument": "ora", "ora_onset": 21.0}, "ora_onset", "[0, 20] ms"),
    ({"ora_onset": 1.0}, "ora_onset", "instrument=ora"),
    ({"instrument": "corvis", "pmax": 12.0}, "pmax", "instrument=paper"),
    ({"instrument": "ora", "T": 20.0}, "T", "instrument=paper"),
    ({"ora_delay": 3.0}, "ora_delay", "instrument=ora"),
])
def test_bad_pulse_parameters_name_the_parameter_and_the_range(options, name, accepted):
    with pytest.raises(ParameterError) as err:
        RunParams(**options)
    assert err.value.name == name and accepted in str(err.value), str(err.value)


def test_cli_rejects_a_bad_instrument_with_one_line():
    for args, name in ((["--instrument", "nct"], "instrument"),
                       (["--instrument", "ora", "--ora-delay", "30"], "ora_delay")):
        proc = subprocess.run([sys.executable, "-m", "api.cli", "run", *args],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and name.replace("_", "") in lines[0].replace("-", "").replace(
            "_", ""), proc.stderr


def test_ora_onset_leaves_the_cornea_no_free_oscillation():
    """A load whose rate jumps (a sharp ramp) sets an oscillator swinging about its steady
    drift: the apex's inward velocity overshoots and falls back before the applanation.  With
    the pump's rate rising over about the cornea's lowest period (the default ``ora_onset``,
    docs/model.md section 6) the velocity rises without falling back (coarse, clinical)."""
    velocities = {}
    for onset in (0.0, ORA_ONSET):
        result = simulate(RunParams(instrument="ora", model="clinical", ora_onset=onset,
                                    t_end=4.5))
        velocities[onset] = result.histories["apex_velocity"][result.time >= 0.2]
        first = result.time[result.time >= 0.2] <= 2.5  # the sharp ramp's first swing
    sharp, smooth = velocities[0.0], velocities[ORA_ONSET]
    peak = int(np.argmax(sharp[first]))
    assert sharp[peak:].min() < 0.7 * sharp[peak], "the sharp ramp's overshoot is gone"
    assert np.all(np.diff(smooth) > 0.0), "the smooth onset's velocity falls back"
