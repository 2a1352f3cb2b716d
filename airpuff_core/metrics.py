"""ORA and Corvis-style metrics from the histories of one run (user units: ms, mmHg, mm, m/s).

Applanation = a sign change of the apical curvature: convex -> concave is the first applanation
A1 (the first such crossing), concave -> convex the second, A2 (the last such crossing).  The
instants are interpolated linearly between solver steps, and P1, P2 are the air-jet pressure at
the apex at those instants (eq. 11 evaluated exactly).  Then, as in the paper (section 4):

    CH = P1 - P2,   IOPg = 0.5 (P1 + P2),   IOPcc = P1 - 0.43 P2

and, beside the paper's IOPcc, the Ocular Response Analyzer's published forms (Luce, "Methodology
for cornea compensated IOP and corneal resistance factor for an Ocular Response Analyzer", IOVS
47 (2006) ARVO E-Abstract 2266; as quoted by Medeiros and Weinreb, J. Glaucoma 15 (2006) 364,
and Kotecha et al., IOVS 47 (2006) 5337), without the device's calibration constants:

    CRF = P1 - 0.7 P2   (corneal resistance factor),   IOPcc_ora = P2 - 0.43 P1

DA (deformation amplitude) and t_HC are the maximum of the stored ``apex_displacement`` history
and its time; the peak inward/outward apex speeds come from ``apex_velocity``.  A run in which
the cornea never applanates is not an error: the applanation metrics are NaN with a reason.
"""

from __future__ import annotations

import math

import numpy as np


def _crossings(t, f, downward):
    """Interpolated times where f crosses zero downward (+ -> -) or upward (- -> +)."""
    out = []
    for i in range(1, len(f)):
        a, b = f[i - 1], f[i]
        if (downward and a > 0 >= b) or (not downward and a < 0 <= b):
            s = a / (a - b)
            out.append((t[i - 1] + s * (t[i] - t[i - 1]), i - 1, s))
    return out


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
                    step_budget=None):
    """Return (metrics, notes, extra diagnostics).  ``step_budget`` (steps, 4): the apex force
    budget at every step [mmHg] (``CoupledModel.apex_budget``: the jet's mean over the apex
    nodes, fluid pressure, equilibrium resistance, viscoelastic overstress, inertia),
    interpolated to the applanations like the fluid pressure:
    P1 = P1_profile + P1_fluid + P1_equilibrium + P1_overstress + P1_inertia + P1_residual, with
    P1_profile = P1 minus the jet's mean over the apex nodes (its spatial decay) and P1_residual
    what the discrete balance leaves (likewise P2); CH_<part> = P1_<part> - P2_<part>."""
    nan = math.nan
    m = {k: nan for k in ("P1", "P2", "CH", "IOPg", "IOPcc", "CRF", "IOPcc_ora", "t_A1", "t_A2",
                          "t_HC", "hc_delay", "DA", "v_in_max", "v_out_max")}
    for part in ("profile",) + BUDGET_PARTS + ("residual",):
        for k in ("P1", "P2", "CH"):
            m[f"{k}_{part}"] = nan
    notes = {}
    extra = {}
    disp = hist["apex_displacement"]
    i_max = int(np.nanargmax(disp))
    m["DA"] = float(disp[i_max])
    m["t_HC"] = float(time_ms[i_max])
    # a pulse switched off by the eye that never applanated has no peak time (inf)
    m["hc_delay"] = m["t_HC"] - t0_ms if math.isfinite(t0_ms) else nan
    vel = hist["apex_velocity"]
    m["v_in_max"] = float(np.nanmax(vel))
    m["v_out_max"] = float(-np.nanmin(vel))

    down = _crossings(step_t, step_kappa, True)
    up = _crossings(step_t, step_kappa, False)
    extra["applanation_crossings_down"] = len(down)
    extra["applanation_crossings_up"] = len(up)
    if down:
        tA1, i, s = down[0]
        m["t_A1"] = tA1
        m["P1"] = jet_apex(tA1)
        extra["fluid_pressure_apex_at_A1"] = step_fluid_p[i] + s * (step_fluid_p[i + 1] - step_fluid_p[i])
        _split(m, "P1", step_budget, i, s)
        up = [u for u in up if u[0] > tA1]
        if up:
            tA2, i, s = up[-1]
            m["t_A2"] = tA2
            m["P2"] = jet_apex(tA2)
            extra["fluid_pressure_apex_at_A2"] = (step_fluid_p[i]
                                                  + s * (step_fluid_p[i + 1] - step_fluid_p[i]))
            _split(m, "P2", step_budget, i, s)
        else:
            for k in ("t_A2", "P2"):
                notes[k] = "the cornea did not return to convex before the end of the run"
    else:
        for k in ("t_A1", "P1", "t_A2", "P2"):
            notes[k] = "the cornea never applanated (apex curvature stayed convex)"
    if math.isfinite(m["P1"]) and math.isfinite(m["P2"]):
        m.update(applanation_readings(m["P1"], m["P2"]))
        for part in ("profile",) + BUDGET_PARTS + ("residual",):
            m[f"CH_{part}"] = m[f"P1_{part}"] - m[f"P2_{part}"]
    else:
        for k in ("CH", "IOPg", "IOPcc", "CRF", "IOPcc_ora"):
            notes[k] = "needs both applanations"
    return m, notes, extra


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
