"""The Ocular Response Analyzer's air pulse (``instrument = ora``; docs/model.md section 6).

The plenum pressure rises while the pump runs, and the pump is switched off a fixed delay
after the instrument detects the first applanation; the pressure then falls.  Here the pulse
on the cornea is (SI)

    p_a(t, phi) = A(t) exp(-a sin^2 phi),
    A(t) = f(t)                                        for t <= t_off,
    A(t) = max(0, f(t_off) - r_fall (t - t_off))       for t >  t_off,
    f(t) = r_rise t^2 / (2 tau) for t < tau,  r_rise (t - tau/2) after,
    t_off = t_A1 + delay,

with t_A1 the first applanation detected in the run itself: the first peak of the ORA's
reflection signal of at least a tenth of a flat zone's (``readout.py``: ``PeakDetector`` over the
committed steps, refined as ``signal_applanations`` refines the metrics' peaks).
The pump's rate rises over tau (``ora_onset``): a rate that jumped at t = 0 would set the cornea
oscillating at its lowest period, and the phase of that oscillation at the applanation would
scatter t_A1 and P1 about their trend in the IOP (docs/model.md section 6).
The peak f(t_off) depends on the eye: an eye that applanates later sees a higher peak.
The detection uses the committed states only, so it is the same for any number of threads.
"""

from __future__ import annotations

import math

import numpy as np

from ..kernels.air_jet import RAMP, SWITCH_OFF
from ..params import MMHG_PA
from ..readout import ORA_DETECTION_THRESHOLD, PeakDetector
from .pulse import AirPulse


class OraPulse(AirPulse):
    """The ORA's pulse of a run (``SIParams`` si: a, ora_rise_rate_Pa_per_s, ora_delay_s,
    ora_onset_s, ora_fall_rate_Pa_per_s) on the cornea's nodes of reference angles phi [rad]."""

    name = "ora"
    watches_applanation = True

    def __init__(self, si, phi):
        # (RAMP, a, t_off [s], r_fall [Pa/s], t_on [s], r_rise [Pa/s], tau [s]); t_off is set
        # online
        self.kernel_args = np.array([RAMP, si.a, math.inf, si.ora_fall_rate_Pa_per_s, 0.0,
                                     si.ora_rise_rate_Pa_per_s, si.ora_onset_s])
        self.delay = si.ora_delay_s
        self.detected_applanation = math.nan  # s, t_A1 as the instrument saw it
        self._detector = PeakDetector(ORA_DETECTION_THRESHOLD)
        self.set_nodes(phi)

    @property
    def switch_off(self):
        """t_off [s]: inf until the first applanation is detected."""
        return float(self.kernel_args[SWITCH_OFF])

    @property
    def peak_time(self):
        return self.switch_off

    def observe(self, t, signal):
        """Detect the first applanation, the reflection signal's first peak, from the committed
        states so far; the pump is switched off ``delay`` after it, and no earlier than now (a
        delay shorter than the time since the peak already passed: the pulse has risen until
        now)."""
        if math.isfinite(self.switch_off):
            return
        t_A1 = self._detector.add(t, signal)
        if math.isfinite(t_A1):
            self.detected_applanation = t_A1
            self.kernel_args[SWITCH_OFF] = max(t_A1 + self.delay, t)

    def diagnostics(self):
        return {"pulse_applanation_detected_ms": self.detected_applanation * 1e3,
                "pulse_switch_off_ms": self.switch_off * 1e3,
                "pulse_peak_apex_mmHg": (self.at_apex(self.switch_off) / MMHG_PA
                                         if math.isfinite(self.switch_off) else math.nan)}
