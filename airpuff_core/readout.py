"""The applanation read-outs, every one in this module: the paper's (the apex curvature's sign
changes) and what the ORA's light detector and the Corvis ST's camera see of the central cornea
(docs/model.md section 7; user units: mm, ms, rad).

**The paper's jet** (``curvature_crossings``): convex -> concave of the apex curvature is the
first applanation A1 (the first such crossing), concave -> convex the second, A2 (the last such
crossing after A1), the instants interpolated linearly between solver steps.

The cornea's profile is given by its nodes x_k >= 0 (from the axis, apex first, x_0 = 0) and
y_k (towards the nozzle), an even function of x.

**ORA** (``ora_signal``): a collimated beam lights the central cornea, and the detector sees the
light that the surface reflects within its acceptance: a surface element tilted by theta
deflects the reflected ray by 2 theta, so with an acceptance function A the signal is the
fraction of the light reflected from the zone r <= r_zone that reaches the detector,

    S = (1 / (pi r_zone^2)) int_0^r_zone A(2 atan|y'(r)|) 2 pi r dr,
    A(delta) = exp(-(delta / acceptance)^2).

S = 1 for a flat zone; a sphere of curvature kappa gives, for small slopes,
S = (1 - exp(-u)) / u with u = (2 kappa r_zone / acceptance)^2.  The slope y' is the derivative
of the parabola through each node and its neighbours (0 at the apex by symmetry), linear in x
between nodes, and the integral is 3-point Gauss-Legendre on each segment.

**Corvis ST** (``corvis_departure``): a Scheimpflug section through the axis; the central
cornea's departure from flat over the applanation length L is the mean square of y about its
mean over |x| <= L/2 (uniform in x, as a section weighs it), y linear between nodes:

    D2 = (2/L) int_0^(L/2) (y - ybar)^2 dx,   ybar = (2/L) int_0^(L/2) y dx.

The square, not the rms: D2 is smooth where the profile passes through flat (the rms has a
corner there, which biases the parabolic refinement below by a fraction of a step).

**Applanation times** (``signal_applanations``): the instrument's signal peaks (for the Corvis
the minima of D2).

- ORA: the first applanation is the first peak before the highest concavity, the second the last
  peak after it, as the apex curvature's first and last sign changes are for the paper's jet:
  the cornea's first passage through flat on its way in, and its last on its way out.  A peak
  counts when the signal has come at least four fifths of the way from the resting cornea's
  value s_0 (the run's first step: a convex cornea reflects almost nothing) to its highest in
  the window,

      s_k > s_k-1,  s_k >= s_k+1,  s_k >= s_0 + 0.8 (s_max - s_0).

  A cornea that lingers near flat on its way out (a soft or strongly viscoelastic one at low
  IOP) gives a plateau of nearly equal peaks (0.95-0.99 of the highest), the last of them where
  it leaves flat; the highest of them would flip from one to another as their heights cross (by
  1.3 ms, P2 by about 6 mmHg).  A cornea whose centre alone is flat gives shoulders of about
  half the highest signal, before or after the applanation (0.51 after it at CCT 0.54 mm, IOP
  20 mmHg, G_t 12.33 kPa, g 0.58): those are not passages through flat.
- Corvis ST: the highest peak before the highest concavity and the highest after it.  D2 does
  not fall so steeply: a strongly viscoelastic cornea creeps back to its resting shape over tens
  of milliseconds, and its departure from flat stays within half its resting value long after the
  second applanation, where the last peak would be the creep's last wiggle.

Each peak's time is the vertex of the parabola through the peak step and its two neighbours.

``applanations`` gives a run's two applanations by its instrument's read-out, as the metrics
(``metrics.py``) take them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

FLATNESS_POINTS = 65  # samples of the half-chord [0, L/2] (trapezoidal rule)

# The instruments' detectors (docs/model.md section 7, docs/sources.md section 11).  ORA: the zone
# is Goldmann's applanation area (3.06 mm across) and the acceptance a detector behind a small
# aperture (about 1 degree); neither the ORA's beam nor its aperture is published: choices.
# Corvis ST: the mean first applanation length of 1,304 normal eyes (1.82 +- 0.22 mm).
ORA_ZONE_RADIUS_MM = 1.53
ORA_ACCEPTANCE_RAD = 0.02
CORVIS_LENGTH_MM = 1.82
# the ORA's pump is switched off after the first peak of at least a tenth of a flat zone's signal
# (its peaks over IOP 10-30: 0.23-0.27 at the normal eye's CCT; the convex cornea's: 0.002)
ORA_DETECTION_THRESHOLD = 0.1
# a peak of an instrument's signal is an applanation when it has come this fraction of the way
# from the resting cornea's signal to the highest in its window (module docstring)
APPLANATION_PEAK_LEVEL = 0.8


@njit(cache=True)
def nodal_slopes(x, y):
    """dy/dx at every node [1]: 0 at the apex (an even profile), elsewhere the derivative of the
    parabola through the node and its two neighbours (the last node: its left neighbours)."""
    n = x.shape[0]
    slope = np.zeros(n)
    for k in range(1, n):
        i = min(k, n - 2)  # the middle node of the parabola
        h0, h2 = x[i - 1] - x[i], x[i + 1] - x[i]
        d0, d2 = (y[i - 1] - y[i]) / h0, (y[i + 1] - y[i]) / h2
        # y = y_i + b (s - x_i) + c (s - x_i)^2 through the three nodes
        c = (d2 - d0) / (h2 - h0)
        b = d2 - c * h2
        slope[k] = b + 2.0 * c * (x[k] - x[i])
    return slope


@njit(cache=True)
def ora_signal(x, y, r_zone=ORA_ZONE_RADIUS_MM, acceptance=ORA_ACCEPTANCE_RAD):
    """The ORA's detector signal S in [0, 1] (module docstring) of the profile x, y [mm] (nodes
    out to beyond ``r_zone``) for a zone of radius ``r_zone`` [mm] and an acceptance [rad] of
    the reflected ray's deflection."""
    slope = nodal_slopes(x, y)
    gauss_x = (-math.sqrt(0.6), 0.0, math.sqrt(0.6))  # 3-point Gauss-Legendre on [-1, 1]
    gauss_w = (5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0)
    total = 0.0
    for k in range(x.shape[0] - 1):
        a, b = x[k], min(x[k + 1], r_zone)
        if b <= a:
            break
        half = 0.5 * (b - a)
        for q in range(3):
            r = a + half * (1.0 + gauss_x[q])
            s = slope[k] + (slope[k + 1] - slope[k]) * (r - a) / (x[k + 1] - a)
            deflection = 2.0 * math.atan(abs(s))
            total += half * gauss_w[q] * math.exp(-(deflection / acceptance) ** 2) * 2.0 * r
    return total / (r_zone * r_zone)


@njit(cache=True)
def corvis_departure(x, y, length=CORVIS_LENGTH_MM):
    """The departure from flat D2 [mm^2] (module docstring) of the profile x, y [mm] over the
    applanation length ``length`` [mm]: the trapezoidal rule on FLATNESS_POINTS samples of
    [0, L/2]."""
    n = FLATNESS_POINTS
    ys = np.interp(np.linspace(0.0, 0.5 * length, n), x, y)
    w_end = 0.5 / (n - 1)
    mean = w_end * (ys[0] + ys[-1]) + np.sum(ys[1:-1]) / (n - 1)
    dev = (ys - mean) ** 2
    return w_end * (dev[0] + dev[-1]) + np.sum(dev[1:-1]) / (n - 1)


def curvature_crossings(t, kappa, downward):
    """[(t_c, i, s)]: the times where the apex curvature kappa at the step times t crosses zero
    downward (convex -> flat or concave, kappa_i > 0 >= kappa_i+1) or upward (concave -> flat
    or convex, kappa_i < 0 <= kappa_i+1), linearly interpolated: t_c = t_i + s (t_i+1 - t_i)."""
    out = []
    for i in range(1, len(kappa)):
        a, b = kappa[i - 1], kappa[i]
        if (downward and a > 0 >= b) or (not downward and a < 0 <= b):
            s = a / (a - b)
            out.append((t[i - 1] + s * (t[i] - t[i - 1]), i - 1, s))
    return out


def peak_vertex(t0, t1, t2, s0, s1, s2):
    """The time of the vertex of the parabola through (t0, s0), (t1, s1), (t2, s2), the middle
    sample the highest; t1 where the three are not strictly concave."""
    h0, h2 = t0 - t1, t2 - t1
    c = ((s2 - s1) / h2 - (s0 - s1) / h0) / (h2 - h0)
    if not c < 0.0:
        return float(t1)
    b = (s2 - s1) / h2 - c * h2
    return float(t1 - 0.5 * b / c)


def _passage(t, s, lo, hi, first):
    """The vertex time of the first (or last) peak of s over the steps lo..hi-1 that has come
    APPLANATION_PEAK_LEVEL of the way from the resting value s[0] to the highest there (module
    docstring); NaN when the highest sample is at either end of the window (no peak)."""
    if hi - lo < 3:
        return math.nan
    window = s[lo:hi]
    k_max = int(np.nanargmax(window))
    if k_max == 0 or k_max == hi - lo - 1:
        return math.nan
    level = s[0] + APPLANATION_PEAK_LEVEL * (window[k_max] - s[0])
    inner = np.arange(1, hi - lo - 1)
    peaks = inner[(window[inner] > window[inner - 1]) & (window[inner] >= window[inner + 1])
                  & (window[inner] >= level)]
    k = lo + int(peaks[0] if first else peaks[-1])
    return peak_vertex(t[k - 1], t[k], t[k + 1], s[k - 1], s[k], s[k + 1])


def _highest(t, s, lo, hi):
    """The vertex time of the highest peak of s over the steps lo..hi-1; NaN when the highest
    sample is at either end of the window (no peak)."""
    if hi - lo < 3:
        return math.nan
    k = lo + int(np.nanargmax(s[lo:hi]))
    if k == lo or k == hi - 1:
        return math.nan
    return peak_vertex(t[k - 1], t[k], t[k + 1], s[k - 1], s[k], s[k + 1])


def signal_applanations(t, s, t_split, passages=True):
    """(t_A1, t_A2) [ms] of the signal s at the step times t, split at ``t_split`` (the highest
    concavity; module docstring): with ``passages`` the first peak before and the last after
    (the ORA's), otherwise the highest before and after (the Corvis ST's); NaN for one without
    a peak."""
    t = np.asarray(t)
    s = np.asarray(s)
    k = int(np.searchsorted(t, t_split))
    if passages:
        return _passage(t, s, 0, k, True), _passage(t, s, k, t.shape[0], False)
    return _highest(t, s, 0, k), _highest(t, s, k, t.shape[0])


def _step_position(t, t_a):
    """(t_a, i, s) with t_a between the steps i and i + 1 at the fraction s; None for NaN."""
    if not math.isfinite(t_a):
        return None
    i = min(max(int(np.searchsorted(t, t_a)) - 1, 0), len(t) - 2)
    return t_a, i, (t_a - t[i]) / (t[i + 1] - t[i])


# why an applanation is missing, by read-out: (no A1, no A2)
_MISSING = {
    "curvature": ("the cornea never applanated (apex curvature stayed convex)",
                  "the cornea did not return to convex before the end of the run"),
    "signal": ("the instrument's applanation signal had no peak before the highest concavity",
               "the instrument's applanation signal had no peak after the highest concavity"),
}


def applanations(step_t, step_kappa, step_signal, t_hc, passages=True):
    """A run's two applanations (module docstring) from its step series [ms], apex curvature
    and, for an instrument with a signal (``readout_for_run``), that signal (None for the
    paper's jet: the curvature's sign changes) read by first and last ``passages`` or not
    (``InstrumentReadout.passages``).  Returns (a1, a2, reasons): each applanation (t [ms],
    step i, fraction s between steps i and i + 1) or None, and the reasons for a missing one
    (no A1, no A2)."""
    if step_signal is not None:
        a1, a2 = (_step_position(step_t, t_a) for t_a in
                  signal_applanations(step_t, step_signal, t_hc, passages))
        return a1, a2, _MISSING["signal"]
    down = curvature_crossings(step_t, step_kappa, True)
    a1 = down[0] if down else None
    up = [u for u in curvature_crossings(step_t, step_kappa, False)
          if a1 is not None and u[0] > a1[0]]
    return a1, (up[-1] if up else None), _MISSING["curvature"]


class PeakDetector:
    """The first peak of a signal of at least ``threshold``, found online as the instrument
    does: after each new sample (t, s), the sample before is a peak when it is the higher of
    its neighbours; its time is ``peak_vertex``'s, as ``signal_applanations`` refines its first
    peak."""

    def __init__(self, threshold):
        self.threshold = threshold
        self._samples = []  # the last three (t, s)
        self.peak_time = math.nan

    def add(self, t, s):
        """Take in a sample; the peak's time once found (NaN until then)."""
        if math.isfinite(self.peak_time):
            return self.peak_time
        self._samples = (self._samples + [(t, s)])[-3:]
        if len(self._samples) == 3:
            (t0, s0), (t1, s1), (t2, s2) = self._samples
            if s1 >= self.threshold and s1 > s0 and s1 >= s2:
                self.peak_time = peak_vertex(t0, t1, t2, s0, s1, s2)
        return self.peak_time


class InstrumentReadout:
    """The applanation signal of the run's instrument on the cornea's nodes (SI positions in,
    the signal out): the ORA's reflection signal S [1], or the Corvis ST's -D2 [mm^2] (so that
    both peak at applanation).  It reads the nodes whose reference x lies within twice the
    instrument's zone (the zone's half-length for the Corvis), and one more, so that the zone
    stays covered while the cornea deforms.  ``passages``: the applanations are the signal's
    first and last peaks (the ORA's) rather than its highest (the Corvis ST's)."""

    def __init__(self, instrument, X_ref):
        self.instrument = instrument
        self.passages = instrument == "ora"
        reach_mm = ORA_ZONE_RADIUS_MM if instrument == "ora" else 0.5 * CORVIS_LENGTH_MM
        self.n_nodes = min(X_ref.shape[0],
                           int(np.searchsorted(X_ref, 2e-3 * reach_mm, side="right")) + 1)

    def __call__(self, X, Y):
        x, y = X[:self.n_nodes] * 1e3, Y[:self.n_nodes] * 1e3
        # every argument given: Numba's dispatch of an omitted default costs ~0.1 ms a call
        if self.instrument == "ora":
            return ora_signal(x, y, ORA_ZONE_RADIUS_MM, ORA_ACCEPTANCE_RAD)
        return -corvis_departure(x, y, CORVIS_LENGTH_MM)


def readout_for_run(instrument, X_ref):
    """The ``InstrumentReadout`` of an instrument that reads the applanations from its own
    signal (``ora``, ``corvis``); None for the paper's jet, whose read-out is the apex
    curvature's sign change (``curvature_crossings``)."""
    return InstrumentReadout(instrument, X_ref) if instrument in ("ora", "corvis") else None
