"""ORA and Corvis-style metrics from the histories of one run (user units: ms, mmHg, mm, m/s).

The applanations A1 and A2 are read as ``readout.py`` reads them: for the paper's jet the sign
changes of the apical curvature, for the ORA and the Corvis ST the peaks of the instrument's
applanation signal before and after the highest concavity.  P1, P2 are the air pulse's pressure
at the apex at those instants (evaluated exactly).  Then, as in the paper (section 4):

    CH = P1 - P2,   IOPg = 0.5 (P1 + P2),   IOPcc = P1 - 0.43 P2

and, beside the paper's IOPcc, the Ocular Response Analyzer's published forms (Luce, "Methodology
for cornea compensated IOP and corneal resistance factor for an Ocular Response Analyzer", IOVS
47 (2006) ARVO E-Abstract 2266; as quoted by Medeiros and Weinreb, J. Glaucoma 15 (2006) 364,
and Kotecha et al., IOVS 47 (2006) 5337), without the device's calibration constants:

    CRF = P1 - 0.7 P2   (corneal resistance factor),   IOPcc_ora = P2 - 0.43 P1

The Corvis ST's outputs (docs/model.md section 7): DA (deformation amplitude) and t_HC (highest
concavity) are the maximum of the ``apex_deformation`` history (the apex as the instrument sees
it: the deflection against the limbus plus the whole eye's movement, ``globe/motion.py``) and its
time; the deflection amplitude the maximum of ``apex_displacement`` (without the eye's movement);
WEM the maximum of ``eye_displacement`` and its time; at t_HC, DA = deflection + WEM.  The peak
distance is the ``peak_distance`` history at t_HC (``peak_distance``), and the apex velocities at
the applanations are the instrument's (the eye's velocity included), interpolated between steps
like P1 and P2.  The peak inward/outward apex speeds come from ``apex_velocity`` (against the
limbus).  A run in which the cornea never applanates is not an error: the applanation metrics are
NaN with a reason.
"""

from __future__ import annotations

import math

import numpy as np

from .readout import applanations, curvature_crossings


def peak_distance(x, y):
    """The distance [units of x] between the two peaks of an axisymmetric profile y(x) (x >= 0
    from the axis, y towards the nozzle): 2 x_p, with x_p the most anterior point of the
    profile, located within its nodes by the vertex of the parabola through the highest node
    and its two neighbours.  NaN when the apex (x = 0) is the highest point (no concavity) or
    the highest node is the last one (no vertex between nodes)."""
    k = int(np.argmax(y))
    if k == 0 or k == len(y) - 1:
        return math.nan
    x0, x1, x2 = x[k - 1], x[k], x[k + 1]
    y0, y1, y2 = y[k - 1], y[k], y[k + 1]
    # y = A x^2 + B x + C through the three nodes; vertex at -B / (2 A)
    denom = (x0 - x1) * (x0 - x2) * (x1 - x2)
    A = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / denom
    B = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / denom
    return float(2.0 * (-B / (2.0 * A)))


BUDGET_PARTS = ("fluid", "equilibrium", "overstress", "inertia")

# The coefficients of the applanation readings: the paper's IOPcc (P1 - 0.43 P2), and the two the
# ORA stores as fixed (``iop_cc_coef``, ``crf_coef``: docs/sources.md section 2).
IOPCC_COEF = 0.43
CRF_COEF = 0.70


def applanation_readings(p1, p2) -> dict:
    """The readings of the two applanation pressures p1, p2 [mmHg] (floats or arrays), in the
    forms of the module docstring: CH = p1 - p2, IOPg = (p1 + p2)/2, IOPcc = p1 - 0.43 p2,
    CRF = p1 - 0.70 p2, IOPcc_ora = p2 - 0.43 p1 (without the device's constants; the
    calibration, ``calibration.py``, adds its own)."""
    return {"CH": p1 - p2, "IOPg": 0.5 * (p1 + p2), "IOPcc": p1 - IOPCC_COEF * p2,
            "CRF": p1 - CRF_COEF * p2, "IOPcc_ora": p2 - IOPCC_COEF * p1}


def compute_metrics(time_ms, hist, step_t, step_kappa, step_fluid_p, jet_apex, t0_ms,
                    step_budget=None, step_velocity=None, step_signal=None,
                    signal_passages=True):
    """Return (metrics, notes, extra diagnostics).  ``step_budget`` (steps, 4): the apex force
    budget at every step [mmHg] (``CoupledModel.apex_budget``: the jet's mean over the apex
    nodes, fluid pressure, equilibrium resistance, viscoelastic overstress, inertia),
    interpolated to the applanations like the fluid pressure:
    P1 = P1_profile + P1_fluid + P1_equilibrium + P1_overstress + P1_inertia + P1_residual, with
    P1_profile = P1 minus the jet's mean over the apex nodes (its spatial decay) and P1_residual
    what the discrete balance leaves (likewise P2); CH_<part> = P1_<part> - P2_<part>.
    ``step_velocity``: the apex's inward velocity as the instrument sees it at every step [m/s]
    (v_A1, v_A2).  ``step_signal``: the instrument's applanation signal at every step
    (``readout.py``), whose peaks are then the applanations (its first and last with
    ``signal_passages``, else its highest: ``readout.signal_applanations``); None: the apex
    curvature's sign changes."""
    nan = math.nan
    m = {k: nan for k in ("P1", "P2", "CH", "IOPg", "IOPcc", "CRF", "IOPcc_ora", "t_A1", "t_A2",
                          "t_HC", "hc_delay", "DA", "deflection_amplitude",
                          "deflection_amplitude_HC", "WEM_max", "t_WEM_max", "WEM_HC",
                          "peak_distance", "v_A1", "v_A2", "v_in_max", "v_out_max")}
    for part in ("profile",) + BUDGET_PARTS + ("residual",):
        for k in ("P1", "P2", "CH"):
            m[f"{k}_{part}"] = nan
    notes = {}
    extra = {}
    deformation = hist["apex_deformation"]
    i_hc = int(np.nanargmax(deformation))
    m["DA"] = float(deformation[i_hc])
    m["t_HC"] = float(time_ms[i_hc])
    # a pulse switched off by the eye that never applanated has no peak time (inf)
    m["hc_delay"] = m["t_HC"] - t0_ms if math.isfinite(t0_ms) else nan
    m["deflection_amplitude"] = float(np.nanmax(hist["apex_displacement"]))
    m["deflection_amplitude_HC"] = float(hist["apex_displacement"][i_hc])
    eye = hist["eye_displacement"]
    i_wem = int(np.nanargmax(eye))
    m["WEM_max"] = float(eye[i_wem])
    m["WEM_HC"] = float(eye[i_hc])
    if m["WEM_max"] > 0.0:
        m["t_WEM_max"] = float(time_ms[i_wem])
    else:
        notes["t_WEM_max"] = "the eye never moved back (eye_motion=none)"
    m["peak_distance"] = float(hist["peak_distance"][i_hc])
    if not math.isfinite(m["peak_distance"]):
        notes["peak_distance"] = ("the apex was the cornea's most anterior point at the highest "
                                  "concavity")
    vel = hist["apex_velocity"]
    m["v_in_max"] = float(np.nanmax(vel))
    m["v_out_max"] = float(-np.nanmin(vel))

    extra["applanation_crossings_down"] = len(curvature_crossings(step_t, step_kappa, True))
    extra["applanation_crossings_up"] = len(curvature_crossings(step_t, step_kappa, False))
    a1, a2, (never, missing) = applanations(step_t, step_kappa, step_signal, m["t_HC"],
                                              signal_passages)
    if a1 is not None:
        _applanation(m, extra, "1", a1, jet_apex, step_fluid_p, step_velocity, step_budget)
        if a2 is not None:
            _applanation(m, extra, "2", a2, jet_apex, step_fluid_p, step_velocity, step_budget)
        else:
            for k in ("t_A2", "P2", "v_A2"):
                notes[k] = missing
    else:
        for k in ("t_A1", "P1", "t_A2", "P2", "v_A1", "v_A2"):
            notes[k] = never
    if math.isfinite(m["P1"]) and math.isfinite(m["P2"]):
        m.update(applanation_readings(m["P1"], m["P2"]))
        for part in ("profile",) + BUDGET_PARTS + ("residual",):
            m[f"CH_{part}"] = m[f"P1_{part}"] - m[f"P2_{part}"]
    else:
        for k in ("CH", "IOPg", "IOPcc", "CRF", "IOPcc_ora"):
            notes[k] = "needs both applanations"
    return m, notes, extra


def _applanation(m, extra, n, at, jet_apex, step_fluid_p, step_velocity, step_budget):
    """The metrics of applanation n ("1" or "2") at ``at`` = (t [ms], step i, fraction s)."""
    t_a, i, s = at
    m[f"t_A{n}"] = t_a
    m[f"P{n}"] = jet_apex(t_a)
    extra[f"fluid_pressure_apex_at_A{n}"] = _at(step_fluid_p, i, s)
    m[f"v_A{n}"] = _at(step_velocity, i, s)
    _split(m, f"P{n}", step_budget, i, s)


def _at(step_series, i, s):
    """A step-level series interpolated between steps i and i + 1 at s (NaN without one)."""
    if step_series is None:
        return math.nan
    return float(step_series[i] + s * (step_series[i + 1] - step_series[i]))


def _split(m, name, step_budget, i, s):
    """m[name_<part>]: the apex force budget interpolated between steps i and i + 1 at s, and
    the residual m[name] minus the parts."""
    if step_budget is None:
        return
    jet_mean, *parts = step_budget[i] + s * (step_budget[i + 1] - step_budget[i])
    m[f"{name}_profile"] = m[name] - float(jet_mean)
    for part, value in zip(BUDGET_PARTS, parts):
        m[f"{name}_{part}"] = float(value)
    m[f"{name}_residual"] = float(jet_mean) - float(np.sum(parts))
