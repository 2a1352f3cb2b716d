"""How far the clinical fit's two values move with the fit's choices (issue 27, item 3).

The fit (``studies/fit_clinical.py``) sets G_t on the CCT slope and g on CH at a reference eye,
under one pulse, at one resolution, with the other tissue values published.  Each of those
choices is moved here by its published spread, one at a time, and the fit is run again (the same
``fit_clinical.main``, one call per variation, all sharing one storage of runs so that what two
fits have in common is computed once):

* the reference eye: IOP 16 +- 2.9 mmHg and CCT 0.54 +- 0.031 mm (the 1,304-eye Corvis cohort's
  SDs, PMC7001013; the slope's CCTs move with it);
* the pulse (ORA only): the rise rate by the spread of the two records' first applanation times
  it was calibrated on (8.18 and 8.40 ms about their mean 8.29, D: :func:`rise_rate_for`), the
  switch-off delay and the fall rate by a chosen +-1 ms and +-25 % (neither is published:
  docs/model.md section 6);
* the resolution: every other resolution of the solver;
* the other tissue values: E0 0.5 +- 0.1 MPa (Pye's relative SD, 0.06 of 0.29 MPa, D: a secant
  modulus of another model), tau 10 ms halved and doubled (Kling et al. 2014 give one value: a
  choice), the globe's rigidity 0.0126 -> 0.0215 per uL (Friedenwald's enucleated-eye average
  against Pallikaris et al.'s in-vivo mean; Pallikaris's SD was not found);
* the targets: the Goldmann slope's 95 % CI 2.3 and 3.6 mmHg per 100 um (PMC2915858), the
  non-contact slope 4.6 (Br J Ophthalmol 89 (2005) 851), TwinsUK's mean CH 10.3 mmHg.

Spreads and their sources: ``VARIATIONS`` (docs/sources.md sections 4, 6, 7; docs/model.md
sections 6 and 11).  Options this study does not know are passed to every fit unchanged (e.g.
``--raw --development``, ``--workers 2``, ``--slope-tolerance``).

    python -m studies.fit_sensitivity --out sens_ora --resolution paper --workers 2
    python -m studies.fit_sensitivity --out /tmp/sens_dev --resolution coarse --instrument paper \\
        --raw --development --only tau-,tau+

Outputs: ``<out>/<variation>/`` each fit's own records (``fit.json``, ``fit.md``, ...),
``<out>/points/`` the runs, ``<out>/sensitivity.json`` and ``<out>/sensitivity.md`` (the table:
each fitted value and its move from the baseline fit).

**First order** (``--linear FIT_JSON``, no fits): a full fit is about 150 runs, one evaluation
of the responses F = (CCT slope, CH) about 12 (the slope's CCTs and the calibration's reference
sweep, refitted at every (G_t, g) as the fit does).  At the fitted point theta* = (G_t*, g*) of
a finished fit (its ``fit.json``; same model version) the 2x2 Jacobian J = dF/dtheta is
measured by central differences (``--steps``, default 0.5 kPa and 0.02: 4 evaluations), each
variation's F once at theta* with its choice moved, and its fitted values move by

    d theta = J^-1 (d target - (F_variation(theta*) - F_baseline(theta*)))

(a moved target needs no run).  The fit's own solver (``fit_clinical.fit``) is run on that
linear model, so a move that leaves a range stops at the edge as the fit does, and the table
says so.  ``--check NAMES`` evaluates those variations again at their first-order values: the
residual there and the Newton step from it measure the linearisation's error.  The runs are
stored in ``--points`` (default ``<out>/points``), the fit's own stored runs linked in first;
the fit's options come from its ``fit.json`` (``--workers`` and the like may be added).

    python -m studies.fit_sensitivity --out sens_linear --linear fit_ora/fit.json --workers 1 \\
        --skip resolution-fine --check E0+

Outputs: ``<out>/linear.json``, ``<out>/linear.md`` (the table: each variation's change of F at
theta*, d theta, the first-order values clipped at the ranges' edges, whether the move stays in
range) and ``<out>/evaluations.jsonl``.
"""

from __future__ import annotations

import json
import math
import os
import shlex
import shutil
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from airpuff_core.atomic import atomic_write
from airpuff_core.params import CHOICES, PARAMETERS, RunParams
from airpuff_core.provenance import model_version

from . import fit_clinical
from .fit_clinical import (CCT_POINTS, RATIO, REFERENCE, REFERENCE_CCT, SHEAR, FitLog, Target,
                           _floats, _json_default, _number)

BASELINE = "baseline"
# the spreads (module docstring)
IOP_SD = 2.9  # mmHg, PMC7001013 (16.8 +- 2.9, 1,304 eyes)
CCT_SD = 0.031  # mm, PMC7001013 (531 +- 31 um)
E0_SD = 0.1  # MPa: 0.5 x 0.06 / 0.29 (Pye, PLoS ONE 15 (2020) e0224824), D
ORA_TIME_IN = (8.18, 8.40)  # ms, the two ORA records the rise rate was calibrated on
ORA_TIME_IN_MEAN = 8.29  # ms, their mean: the first applanation the rise rate was set to
ORA_DELAY_STEP = 1.0  # ms, a choice (the delay is not published)
ORA_FALL_FACTOR = 0.25  # a choice (the fall is not published)
RIGIDITY_FRIEDENWALD = 0.0215  # 1/uL, Friedenwald 1937 (enucleated eyes), docs/model.md sec. 11


@dataclass(frozen=True)
class Variation:
    """One fit with one choice moved: its ``name``, ``group``, what moved (``moved``), the
    options it adds to the fit (``argv``), the spread's ``source``, and the instrument it
    belongs to (None: every instrument)."""

    name: str
    group: str
    moved: str
    argv: tuple[str, ...]
    source: str
    instrument: str | None = None


def _default(name: str) -> float:
    return float(PARAMETERS[name].default)


def rise_rate_for(time_in: float, rise_rate: float, onset: float,
                  calibrated_time_in: float = ORA_TIME_IN_MEAN) -> float:
    """The ORA rise rate [kPa/ms] that moves the first applanation from ``calibrated_time_in``
    to ``time_in`` [ms], the eye unchanged.

    The pulse on the apex while the pump runs (``airpuff_core/loads/ora.py``) is
    f(t) = r t^2 / (2 tau) for t < tau and r (t - tau/2) after, tau = ``onset``.  The first
    applanation comes when f reaches the pressure that applanates the eye, the same for any
    rate if the eye is: r (t_A1 - tau/2) = const (t_A1 > tau).  So
    r' = r (t_cal - tau/2) / (t_in - tau/2): with tau = 3.5 ms the records' 8.18 and 8.40 ms
    give x 1.0169 and x 0.9835, where 1/t_A1 (a pulse without its onset ramp) gives x 1.0134 and
    x 0.9869.  The rate's own effect on the applanation (a faster pulse meets a stiffer
    viscoelastic cornea) is left out: a first-order estimate of the spread, not a recalibration.
    """
    if min(time_in, calibrated_time_in) <= onset:
        raise ValueError(f"the first applanation ({time_in:g}, {calibrated_time_in:g} ms) must "
                         f"come after the onset ramp ({onset:g} ms)")
    return rise_rate * (calibrated_time_in - onset / 2) / (time_in - onset / 2)


def variations(resolution: str, ccts: tuple[float, ...] = CCT_POINTS,
               reference_cct: float = REFERENCE_CCT) -> list[Variation]:
    """Every variation of the fit about ``resolution`` and the slope's CCTs ``ccts``."""
    out = [Variation(BASELINE, "", "nothing", (), "the fit's own choices")]
    iop = REFERENCE["IOP"]
    for sign, tag in ((-1, "-"), (1, "+")):
        value = iop + sign * IOP_SD
        out.append(Variation(f"IOP{tag}", "reference eye", f"IOP {iop:g} -> {value:.3g} mmHg",
                             ("--set", f"IOP={value!r}"), "SD of 1,304 eyes, PMC7001013"))
    for sign, tag in ((-1, "-"), (1, "+")):
        shift = sign * CCT_SD
        shifted = ",".join(repr(round(c + shift, 6)) for c in ccts)
        out.append(Variation(
            f"CCT{tag}", "reference eye",
            f"CCT {reference_cct:g} -> {reference_cct + shift:.3g} mm (the slope's CCTs too)",
            ("--cct", shifted, "--reference-cct", repr(round(reference_cct + shift, 6))),
            "SD of 1,304 eyes, PMC7001013"))
    rise, onset = _default("ora_rise_rate"), _default("ora_onset")
    for tag, t_in in (("-", ORA_TIME_IN[1]), ("+", ORA_TIME_IN[0])):
        value = rise_rate_for(t_in, rise, onset)
        out.append(Variation(f"rise{tag}", "pulse", f"ora_rise_rate {rise:g} -> {value:.4g} "
                             f"kPa/ms", ("--set", f"ora_rise_rate={value!r}"),
                             f"D: the ORA records' TimeIn {t_in:g} ms instead of their mean "
                             f"{ORA_TIME_IN_MEAN:g}, the onset ramp {onset:g} ms kept "
                             f"(docs/sources.md section 1)", "ora"))
    delay = _default("ora_delay")
    for sign, tag in ((-1, "-"), (1, "+")):
        value = delay + sign * ORA_DELAY_STEP
        out.append(Variation(f"delay{tag}", "pulse", f"ora_delay {delay:g} -> {value:g} ms",
                             ("--set", f"ora_delay={value!r}"),
                             "choice: the delay is not published (docs/model.md section 6)",
                             "ora"))
    fall = _default("ora_fall_rate")
    for sign, tag in ((-1, "-"), (1, "+")):
        value = fall * (1 + sign * ORA_FALL_FACTOR)
        out.append(Variation(f"fall{tag}", "pulse", f"ora_fall_rate {fall:g} -> {value:.4g} "
                             f"kPa/ms", ("--set", f"ora_fall_rate={value!r}"),
                             "choice: the fall is not published (docs/model.md section 6)",
                             "ora"))
    for other in CHOICES["resolution"]:
        if other != resolution:
            out.append(Variation(f"resolution-{other}", "resolution",
                                 f"resolution {resolution} -> {other}",
                                 ("--resolution", other), "the solver's resolutions"))
    e0 = REFERENCE["E0"]
    for sign, tag in ((-1, "-"), (1, "+")):
        value = e0 + sign * E0_SD
        out.append(Variation(f"E0{tag}", "tissue", f"E0 {e0:g} -> {value:.3g} MPa",
                             ("--set", f"E0={value!r}"),
                             "D: Pye 2020's relative SD (0.06 of 0.29 MPa), another model's "
                             "secant modulus"))
    tau = RunParams.from_dict({"model": "clinical"}).ve_tau
    for factor, tag in ((0.5, "-"), (2.0, "+")):
        out.append(Variation(f"tau{tag}", "tissue", f"ve_tau {tau:g} -> {tau * factor:g} ms",
                             ("--set", f"ve_tau={tau * factor!r}"),
                             "choice: Kling et al. 2014 give one value, no spread"))
    rigidity = _default("ocular_rigidity")
    out.append(Variation("rigidity+", "tissue",
                         f"ocular_rigidity {rigidity:g} -> {RIGIDITY_FRIEDENWALD:g} per uL",
                         ("--set", f"ocular_rigidity={RIGIDITY_FRIEDENWALD!r}"),
                         "Friedenwald 1937 (enucleated eyes) against Pallikaris et al. 2005 "
                         "(in vivo); Pallikaris's SD not found"))
    slope = fit_clinical.SLOPE_TARGET.value
    for value, source in ((2.3, "95 % CI low, PMC2915858"), (3.6, "95 % CI high, PMC2915858"),
                          (4.6, "non-contact tonometer, Br J Ophthalmol 89 (2005) 851")):
        out.append(Variation(f"slope-target-{value:g}", "target",
                             f"CCT slope target {slope:g} -> {value:g} mmHg per 100 um",
                             ("--slope-target", repr(value)), source))
    ch = fit_clinical.CH_TARGET.value
    out.append(Variation("CH-target-10.3", "target", f"CH target {ch:g} -> 10.3 mmHg",
                         ("--ch-target", "10.3"), "TwinsUK mean, 2,501 eyes (IOVS 2362078)"))
    return out


# -- the table ------------------------------------------------------------------------------------
def moves(results: dict[str, dict]) -> list[dict]:
    """Each variation's fitted values and their moves from the baseline's.

    ``results``: variation name -> {``G_t``, ``g`` (fitted values), ``G_t_status``,
    ``g_status``, ...} with the baseline under ``BASELINE``; a move is NaN where either fit
    has no value."""
    base = results[BASELINE]
    out = []
    for name, r in results.items():
        out.append({**r, "variation": name, "dG_t": r["G_t"] - base["G_t"],
                    "dg": r["g"] - base["g"]})
    return out


def fit_result(fit_json: dict) -> dict:
    """The fitted values, statuses and responses reached of one fit's ``fit.json``."""
    fitted = fit_json["fitted"]
    return {"G_t": _number(fitted[SHEAR.name]["value"]), "g": _number(fitted[RATIO.name]["value"]),
            "G_t_status": fitted[SHEAR.name]["status"], "g_status": fitted[RATIO.name]["status"],
            "slope": _number(fitted[SHEAR.name]["reached"]),
            "CH": _number(fitted[RATIO.name]["reached"]), "mode": fit_json["mode"],
            "model_version": fit_json["model_version"], "resolution": fit_json["resolution"],
            "error": fit_json.get("error", "")}


def _fmt(value: float, spec: str) -> str:
    return "NaN" if not math.isfinite(value) else format(value, spec)


def markdown(summary: dict) -> str:
    lines = [f"# {summary['title']}", "", f"Command: `{summary['command']}`  ",
             f"Model version {summary['model_version']}; each fit's options: "
             f"`{' '.join(summary['fit_options']) or '(the fit defaults)'}`; "
             f"{summary['wall_s']:.0f} s.", "",
             "| variation | group | moved | source | G_t [kPa] | move | g | move | status "
             "(G_t, g) | slope, CH reached |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in summary["rows"]:
        lines.append(
            f"| {r['variation']} | {r['group']} | {r['moved']} | {r['source']} | "
            f"{_fmt(r['G_t'], '.4g')} | {_fmt(r['dG_t'], '+.3g')} | {_fmt(r['g'], '.4g')} | "
            f"{_fmt(r['dg'], '+.3g')} | {r['G_t_status']}, {r['g_status']} | "
            f"{_fmt(r['slope'], '.3f')}, {_fmt(r['CH'], '.3f')} |")
    if summary["skipped"]:
        lines += ["", "Not run (another instrument's): " + ", ".join(summary["skipped"])]
    return "\n".join(lines) + "\n"


# -- the first-order (linearised) sensitivity ---------------------------------------------------
# the finite-difference steps of the Jacobian about the fit (G_t [kPa], g): about 4 % of each
# range, moving the slope by about 0.2 mmHg per 100 um and CH by about 0.15 mmHg at the coarse
# fit, several times the fit's tolerances (0.05) and the size of the variations' moves
JACOBIAN_STEPS = (0.5, 0.02)


@dataclass
class Jacobian:
    """The responses F = (CCT slope, CH) at ``at`` = (G_t, g) and at ``at`` +- ``steps`` along
    each parameter: ``plus[:, j]`` = F(at + h_j e_j), ``minus[:, j]`` = F(at - h_j e_j)."""

    at: tuple[float, float]
    steps: tuple[float, float]
    centre: np.ndarray
    plus: np.ndarray
    minus: np.ndarray

    @property
    def central(self) -> np.ndarray:
        """dF_i/dtheta_j by central differences, (F(+h) - F(-h)) / 2h: exact for a quadratic
        F, error h^2/6 F''' otherwise."""
        return (self.plus - self.minus) / (2 * np.asarray(self.steps))

    @property
    def forward(self) -> np.ndarray:
        return (self.plus - self.centre[:, None]) / np.asarray(self.steps)

    @property
    def backward(self) -> np.ndarray:
        return (self.centre[:, None] - self.minus) / np.asarray(self.steps)

    @property
    def curvature(self) -> np.ndarray:
        """d2F_i/dtheta_j2, (F(+h) - 2 F + F(-h)) / h^2: how far F is from linear."""
        return (self.plus - 2 * self.centre[:, None] + self.minus) / np.asarray(self.steps) ** 2


def measure_jacobian(evaluate: Callable[[float, float], np.ndarray], at: tuple[float, float],
                     steps: tuple[float, float] = JACOBIAN_STEPS) -> Jacobian:
    """F = ``evaluate(G_t, g)`` at ``at`` and at the four points ``at`` +- ``steps``."""
    at = (float(at[0]), float(at[1]))
    centre = np.asarray(evaluate(*at), dtype=float)
    plus, minus = np.empty((2, 2)), np.empty((2, 2))
    for j in range(2):
        for sign, columns in ((1, plus), (-1, minus)):
            moved = list(at)
            moved[j] += sign * steps[j]
            columns[:, j] = evaluate(*moved)
    return Jacobian(at, (float(steps[0]), float(steps[1])), centre, plus, minus)


@dataclass
class LinearResponses:
    """The fit's two responses to first order about ``at`` = (G_t, g), F(theta) = ``values`` +
    ``jacobian`` (theta - at), with the :class:`fit_clinical.Responses` methods that
    :func:`fit_clinical.fit` calls, so that the fit's own solver (and its stop at a range's
    edge) runs on them."""

    at: tuple[float, float]
    values: np.ndarray
    jacobian: np.ndarray

    def _value(self, i: int, shear: float, ratio: float) -> float:
        d = np.array([shear - self.at[0], ratio - self.at[1]])
        return float(self.values[i] + self.jacobian[i] @ d)

    def slope(self, shear: float, ratio: float, solve: str = "") -> float:
        return self._value(0, shear, ratio)

    def ch(self, shear: float, ratio: float, solve: str = "") -> float:
        return self._value(1, shear, ratio)


def first_order_move(jacobian: np.ndarray, at: tuple[float, float], response_change,
                     target_change=(0.0, 0.0),
                     targets=(fit_clinical.SLOPE_TARGET.value, fit_clinical.CH_TARGET.value)
                     ) -> dict:
    """How far the fitted (G_t, g) move, to first order, when a choice moves the responses at
    the fitted point ``at`` by ``response_change`` = F_variation(at) - F_baseline(at) and the
    targets by ``target_change``.

    The fit solves F(theta) = target; to first order about the baseline fit, F(theta) =
    F_baseline(at) + dF + J (theta - at), so the move is d theta = J^-1 (d target - dF)
    (``dG_t``, ``dg``: unclipped).  ``G_t``, ``g``: the fit itself (:func:`fit_clinical.fit`)
    run on that linear model from ``at`` (tolerances 1e-9), so a move that leaves a parameter's
    range stops it at the edge and fits the other parameter there, as the fit does;
    ``in_range`` says whether the unclipped move stays inside both ranges."""
    J = np.asarray(jacobian, dtype=float)
    dF = np.asarray(response_change, dtype=float)
    dT = np.asarray(target_change, dtype=float)
    d_theta = np.linalg.solve(J, dT - dF)
    model = LinearResponses(at, np.asarray(targets, dtype=float) + dF, J)
    tight = [Target(**{**asdict(t), "value": value + change, "tolerance": 1e-9})
             for t, value, change in ((fit_clinical.SLOPE_TARGET, targets[0], dT[0]),
                                      (fit_clinical.CH_TARGET, targets[1], dT[1]))]
    result = fit_clinical.fit(model, *tight, start=at, max_outer=100, max_evaluations=30)
    unclipped = (at[0] + d_theta[0], at[1] + d_theta[1])
    return {"dG_t": float(d_theta[0]), "dg": float(d_theta[1]),
            "G_t_unclipped": float(unclipped[0]), "g_unclipped": float(unclipped[1]),
            "in_range": bool(SHEAR.low <= unclipped[0] <= SHEAR.high
                             and RATIO.low <= unclipped[1] <= RATIO.high),
            "G_t": result.shear, "g": result.ratio, "G_t_status": result.shear_status,
            "g_status": result.ratio_status}


def evaluate_responses(responses: fit_clinical.Responses, label: str):
    """F(G_t, g) = (CCT slope, CH) of ``responses`` (calibration refitted at each (G_t, g),
    as the fit does), as a function."""
    def evaluate(shear: float, ratio: float) -> np.ndarray:
        return np.array([responses.slope(shear, ratio, label), responses.ch(shear, ratio, label)])
    return evaluate


def seed_points(source: Path, points: Path) -> int:
    """Hard-links (or copies) the stored runs of ``source`` missing from ``points``, so that
    the fit's runs are reused; returns how many.  A finished point's file is replaced, never
    rewritten, so a link stays the point it was."""
    points.mkdir(parents=True, exist_ok=True)
    n = 0
    for path in sorted(Path(source).glob("*.nc")):
        target = points / path.name
        if target.exists():
            continue
        try:
            os.link(path, target)
        except OSError:
            shutil.copy2(path, target)
        n += 1
    return n


def linear_main(args, passed: list[str], ap) -> int:
    """``--linear FIT_JSON``: the first-order moves of every chosen variation about the fit."""
    fit_path = Path(args.linear)
    try:
        fit_json = json.loads(fit_path.read_text())
        at = (float(fit_json["fitted"][SHEAR.name]["value"]),
              float(fit_json["fitted"][RATIO.name]["value"]))
        fit_argv = shlex.split(fit_json["command"])[3:]
    except (OSError, ValueError, KeyError, TypeError) as err:
        ap.error(f"--linear: {fit_path} is not a fit's fit.json ({err})")
    if not all(math.isfinite(x) for x in at):
        ap.error(f"--linear: the fit in {fit_path} has no fitted values ({fit_json['error']})")
    if fit_json["model_version"] != model_version():
        ap.error(f"--linear: the fit in {fit_path} is of model version "
                 f"{fit_json['model_version']}, this solver is {model_version()}: fit again")
    try:
        steps = _floats(args.steps)
    except ValueError as err:
        ap.error(f"--steps: {err}")
    if len(steps) != 2 or min(steps) <= 0:
        ap.error(f"--steps: two positive steps G_t,g, got {args.steps}")
    out = args.out
    own = ["--out", str(out / "linear"), "--points", str(args.points or out / "points")]
    baseline = fit_clinical.fit_setup([*fit_argv, *passed, *own])
    ccts = baseline.ccts
    every = variations(fit_json["resolution"], ccts, baseline.reference_cct)
    chosen, skipped = choose(every, fit_json["instrument"], args, ap)
    checks = {w.strip() for w in args.check.split(",")} if args.check else set()
    unknown = sorted(checks - {v.name for v in chosen})
    if unknown:
        ap.error(f"--check: {unknown[0]!r} is not a chosen variation (--list shows them)")
    setups = {v.name: fit_clinical.fit_setup([*fit_argv, *passed, *v.argv, *own])
              for v in chosen}

    out.mkdir(parents=True, exist_ok=True)
    points = args.points or out / "points"
    fit_points = fit_path.parent / "points"
    seeded = seed_points(fit_points, points) if fit_points.is_dir() else 0
    log = FitLog(out / "evaluations.jsonl")
    t0 = time.perf_counter()
    targets = (baseline.slope_target.value, baseline.ch_target.value)
    rows = []
    with fit_clinical.point_runner(points, baseline.workers, baseline.warm_params(),
                                   log.run) as runner:
        base_responses = baseline.responses(runner, log)
        jac = measure_jacobian(evaluate_responses(base_responses, "jacobian"), at, steps)
        J = jac.central
        for v in chosen:
            setup = setups[v.name]
            print(f"== {v.name}: {v.moved}", flush=True)
            responses = base_responses if v.name == BASELINE else setup.responses(runner, log)
            evaluate = evaluate_responses(responses, v.name)
            value = jac.centre if v.name == BASELINE else evaluate(*at)
            dF = value - jac.centre
            dT = np.array([setup.slope_target.value, setup.ch_target.value]) - targets
            one_sided = [np.linalg.solve(Jk, dT - dF) for Jk in (jac.forward, jac.backward)]
            row = {**{k: (list(x) if isinstance(x, tuple) else x) for k, x in asdict(v).items()},
                   "variation": v.name, "slope_at_fit": float(value[0]),
                   "CH_at_fit": float(value[1]), "dslope": float(dF[0]), "dCH": float(dF[1]),
                   "dslope_target": float(dT[0]), "dCH_target": float(dT[1]),
                   "calibration_max_error_mmHg": calibration_error(responses, at),
                   **first_order_move(J, at, dF, dT, targets),
                   "dG_t_one_sided": [float(d[0]) for d in one_sided],
                   "dg_one_sided": [float(d[1]) for d in one_sided]}
            if v.name in checks:
                row["check"] = second_order_check(evaluate, J, row, jac.centre + dT)
            rows.append(row)
    summary = {
        "title": "First-order sensitivity of the clinical fit to its choices"
                 + (" (about a DEVELOPMENT fit)" if fit_json["mode"] == "development" else ""),
        "command": "python -m studies.fit_sensitivity "
                   + " ".join(shlex.quote(a) for a in args.argv),
        "fit": str(fit_path), "fit_command": fit_json["command"],
        "model_version": model_version(), "resolution": fit_json["resolution"],
        "instrument": fit_json["instrument"], "at": {"G_t": at[0], "g": at[1]},
        "fit_reached": {"slope": fit_json["fitted"][SHEAR.name]["reached"],
                        "CH": fit_json["fitted"][RATIO.name]["reached"]},
        "fit_sensitivities": fit_json.get("sensitivities") or {},
        "jacobian": {"steps": list(jac.steps), "centre": jac.centre.tolist(),
                     "plus": jac.plus.tolist(), "minus": jac.minus.tolist(),
                     "central": J.tolist(), "forward": jac.forward.tolist(),
                     "backward": jac.backward.tolist(), "curvature": jac.curvature.tolist()},
        "ranges": {"G_t": [SHEAR.low, SHEAR.high], "g": [RATIO.low, RATIO.high]},
        "skipped": skipped, "runs_computed": sum(1 for r in log.runs if r["computed"]),
        "runs_seeded": seeded, "wall_s": time.perf_counter() - t0, "rows": rows}
    text = json.dumps(summary, indent=1, default=_json_default)
    atomic_write(out / "linear.json", lambda tmp: tmp.write_text(text + "\n"))
    table = linear_markdown(summary)
    atomic_write(out / "linear.md", lambda tmp: tmp.write_text(table))
    print(table)
    return 0


def calibration_error(responses: fit_clinical.Responses, at: tuple[float, float]) -> float:
    """The largest |IOPg_cal - IOP| of the calibration made at ``at`` on its reference sweep
    [mmHg] (NaN for raw readings)."""
    made = [e for e in responses.evaluations if e["response"] == "calibration_slope"
            and (e[SHEAR.name], e[RATIO.name]) == at]
    return float(made[-1]["max_error_mmHg"]) if made else math.nan


def second_order_check(evaluate, J: np.ndarray, row: dict, aim: np.ndarray) -> dict:
    """The variation's responses at its first-order values, against ``aim`` (the baseline's
    responses at the fit plus the target's move): the residual, and the Newton step from there
    (J^-1 times the residual, the linearisation's error to second order)."""
    theta = (row["G_t"], row["g"])
    value = np.asarray(evaluate(*theta), dtype=float)
    residual = value - aim
    newton = -np.linalg.solve(J, residual)
    return {"at": list(theta), "slope": float(value[0]), "CH": float(value[1]),
            "residual": residual.tolist(), "newton_dG_t": float(newton[0]),
            "newton_dg": float(newton[1])}


def linear_markdown(summary: dict) -> str:
    jac = summary["jacobian"]
    J, (hG, hg) = jac["central"], jac["steps"]
    fwd, bwd = jac["forward"], jac["backward"]
    at = summary["at"]
    lines = [f"# {summary['title']}", "", f"Command: `{summary['command']}`  ",
             f"About the fit `{summary['fit_command']}` (model version "
             f"{summary['model_version']}, {summary['resolution']} resolution, "
             f"{summary['instrument']}): G_t {at['G_t']:.4f} kPa, g {at['g']:.4f}; "
             f"{summary['runs_computed']} runs computed ({summary['runs_seeded']} of the fit's "
             f"stored runs linked in), {summary['wall_s']:.0f} s.", "",
             f"Jacobian by central differences (steps {hG:g} kPa, {hg:g}): dslope/dG_t "
             f"{J[0][0]:+.4f}, dslope/dg {J[0][1]:+.3f} [mmHg per 100 um]; dCH/dG_t {J[1][0]:+.4f}, "
             f"dCH/dg {J[1][1]:+.3f} [mmHg]. Forward / backward differences: "
             f"{fwd[0][0]:+.4f}/{bwd[0][0]:+.4f}, {fwd[0][1]:+.3f}/{bwd[0][1]:+.3f}, "
             f"{fwd[1][0]:+.4f}/{bwd[1][0]:+.4f}, {fwd[1][1]:+.3f}/{bwd[1][1]:+.3f}; the moves "
             f"in brackets are those with the forward and with the backward differences, "
             f"unclipped: how far the answer depends on where F is linearised."]
    sens = summary["fit_sensitivities"]
    if sens:
        lines[-1] += (f" The fit's own planes through its nearest evaluations: "
                      f"{sens['dslope_dG_t']:+.4f}, {sens['dslope_dg']:+.3f}, "
                      f"{sens['dCH_dG_t']:+.4f}, {sens['dCH_dg']:+.3f}.")
    lines += ["", "| variation | group | moved | source | slope, CH at the fit (change) | "
              "calibration max error [mmHg] | dG_t [kPa] (one-sided J) | dg (one-sided J) | "
              "G_t, g (first order, clipped) | in range |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for r in summary["rows"]:
        target = (f"; target {r['dslope_target']:+g}, {r['dCH_target']:+g}"
                  if r["dslope_target"] or r["dCH_target"] else "")
        inside = "yes" if r["in_range"] else (f"NO: {r['G_t_status']}, {r['g_status']}")
        (fG, bG), (fg, bg) = r["dG_t_one_sided"], r["dg_one_sided"]
        lines.append(
            f"| {r['variation']} | {r['group']} | {r['moved']} | {r['source']} | "
            f"{r['slope_at_fit']:.3f}, {r['CH_at_fit']:.3f} ({r['dslope']:+.3f}, "
            f"{r['dCH']:+.3f}{target}) | {_fmt(r['calibration_max_error_mmHg'], '.3f')} | "
            f"{r['dG_t']:+.3f} ({fG:+.2f}, {bG:+.2f}) | {r['dg']:+.4f} ({fg:+.3f}, {bg:+.3f}) | "
            f"{r['G_t']:.3f}, {r['g']:.4f} | {inside} |")
    checks = [r for r in summary["rows"] if "check" in r]
    if checks:
        lines += ["", "Checks at the first-order values (the variation's responses there, their "
                  "residual against the baseline's plus the target's move, the Newton step "
                  "from there):", ""]
        for r in checks:
            c = r["check"]
            lines.append(f"- {r['variation']}: at G_t {c['at'][0]:.4f}, g {c['at'][1]:.4f}: slope "
                         f"{c['slope']:.3f}, CH {c['CH']:.3f} (residual {c['residual'][0]:+.3f}, "
                         f"{c['residual'][1]:+.3f}); Newton step {c['newton_dG_t']:+.3f} kPa, "
                         f"{c['newton_dg']:+.4f}")
    if summary["skipped"]:
        lines += ["", "Not run: " + ", ".join(summary["skipped"])]
    return "\n".join(lines) + "\n"


# -- the command ----------------------------------------------------------------------------------
def parse_args(argv):
    from api.cli.common import OneLineParser

    ap = OneLineParser(prog="fit_sensitivity", description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="folder of the fits and their runs")
    ap.add_argument("--resolution", default=None, choices=CHOICES["resolution"],
                    help="(default paper; with --linear the fit's own)")
    ap.add_argument("--instrument", default=None, choices=("ora", "paper"),
                    help="(default ora; with --linear the fit's own)")
    ap.add_argument("--cct", default=None,
                    help="CCTs of the slope [mm] (the CCT variations shift them; default "
                         f"{','.join(f'{c:g}' for c in CCT_POINTS)}; with --linear the fit's own)")
    ap.add_argument("--only", default=None, metavar="NAMES",
                    help="only these variations (comma-separated; the baseline always runs)")
    ap.add_argument("--skip", default=None, metavar="NAMES",
                    help="not these variations (comma-separated)")
    ap.add_argument("--list", action="store_true", help="print the variations and stop")
    ap.add_argument("--linear", default=None, metavar="FIT_JSON",
                    help="no fits: the first-order moves about the fit of FIT_JSON (its "
                         "fit.json), one evaluation of the responses per variation")
    ap.add_argument("--steps", default=",".join(f"{h:g}" for h in JACOBIAN_STEPS),
                    metavar="H_GT,H_G", help="--linear: the Jacobian's central-difference "
                    "steps in G_t [kPa] and g")
    ap.add_argument("--check", default=None, metavar="NAMES",
                    help="--linear: evaluate these variations again at their first-order values")
    ap.add_argument("--points", type=Path, default=None,
                    help="--linear: folder of the runs (default <out>/points; the fit's stored "
                         "runs are linked in)")
    return ap.parse_known_args(argv) + (ap,)


def _names(text: str | None) -> set[str]:
    return {w.strip() for w in text.split(",")} if text else set()


def choose(every: list[Variation], instrument: str, args, ap) -> tuple[list[Variation], list[str]]:
    """The variations of ``instrument`` that ``--only`` and ``--skip`` leave (the baseline
    always), and the names of another instrument's."""
    chosen = [v for v in every if v.instrument in (None, instrument)]
    skipped = [v.name for v in every if v not in chosen]
    names = {v.name for v in every}
    for option, wanted in (("--only", _names(args.only)), ("--skip", _names(args.skip))):
        unknown = sorted(wanted - names)
        if unknown:
            ap.error(f"{option}: {unknown[0]!r} is not a variation (--list shows them)")
    if args.only:
        chosen = [v for v in chosen if v.name == BASELINE or v.name in _names(args.only)]
    chosen = [v for v in chosen if v.name == BASELINE or v.name not in _names(args.skip)]
    return chosen, skipped


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args, passed, ap = parse_args(argv)
    args.argv = argv
    if "--out" in passed:
        ap.error("--out: set by this study per variation")
    if args.linear:
        given = [o for o in ("resolution", "instrument", "cct") if getattr(args, o) is not None]
        if given:
            ap.error(f"--{given[0]}: with --linear the fit's own (its fit.json)")
        return linear_main(args, passed, ap)
    if args.points or args.check:
        ap.error(f"--{'points' if args.points else 'check'}: with --linear only (the fits' runs "
                 f"are stored in <out>/points)")
    resolution, instrument = args.resolution or "paper", args.instrument or "ora"
    cct_text = args.cct or ",".join(f"{c:g}" for c in CCT_POINTS)
    try:
        ccts = _floats(cct_text)
    except ValueError as err:
        ap.error(f"--cct: {err}")
    if REFERENCE_CCT not in ccts:
        ap.error(f"--cct: the reference CCT {REFERENCE_CCT:g} mm must be among them, got "
                 f"{cct_text}")
    every = variations(resolution, ccts)
    if args.list:
        for v in every:
            print(f"{v.name:18s} {v.group:14s} {v.moved}  [{v.source}]")
        return 0
    chosen, skipped = choose(every, instrument, args, ap)
    common = ["--resolution", resolution, "--instrument", instrument, "--cct", cct_text, *passed]
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    results, meta = {}, {}
    for v in chosen:
        folder = out / v.name
        print(f"== {v.name}: {v.moved}", flush=True)
        fit_argv = [*common, *v.argv, "--out", str(folder), "--points", str(out / "points")]
        code = fit_clinical.main(fit_argv)
        results[v.name] = fit_result(json.loads((folder / "fit.json").read_text()))
        results[v.name]["exit_code"] = code
        meta[v.name] = {k: (list(val) if isinstance(val, tuple) else val)
                        for k, val in asdict(v).items()}
    rows = [{**meta[r["variation"]], **r} for r in moves(results)]
    summary = {"title": "Sensitivity of the clinical fit to its choices"
               + (" (DEVELOPMENT fits)" if results[BASELINE]["mode"] == "development" else ""),
               "command": "python -m studies.fit_sensitivity "
               + " ".join(shlex.quote(a) for a in argv),
               "model_version": model_version(), "fit_options": common, "skipped": skipped,
               "wall_s": time.perf_counter() - t0, "rows": rows}
    text = json.dumps(summary, indent=1, default=lambda x: None)
    atomic_write(out / "sensitivity.json", lambda tmp: tmp.write_text(text + "\n"))
    table = markdown(summary)
    atomic_write(out / "sensitivity.md", lambda tmp: tmp.write_text(table))
    print(table)
    return 0 if all(r["exit_code"] == 0 for r in results.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
