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
"""

from __future__ import annotations

import json
import math
import shlex
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from airpuff_core.atomic import atomic_write
from airpuff_core.params import CHOICES, PARAMETERS, RunParams
from airpuff_core.provenance import model_version

from . import fit_clinical
from .fit_clinical import CCT_POINTS, RATIO, REFERENCE, REFERENCE_CCT, SHEAR, _floats, _number

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


# -- the command ----------------------------------------------------------------------------------
def parse_args(argv):
    from api.cli.common import OneLineParser

    ap = OneLineParser(prog="fit_sensitivity", description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="folder of the fits and their runs")
    ap.add_argument("--resolution", default="paper", choices=CHOICES["resolution"])
    ap.add_argument("--instrument", default="ora", choices=("ora", "paper"))
    ap.add_argument("--cct", default=",".join(f"{c:g}" for c in CCT_POINTS),
                    help="CCTs of the slope [mm] (the CCT variations shift them)")
    ap.add_argument("--only", default=None, metavar="NAMES",
                    help="only these variations (comma-separated; the baseline always runs)")
    ap.add_argument("--list", action="store_true", help="print the variations and stop")
    return ap.parse_known_args(argv) + (ap,)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args, passed, ap = parse_args(argv)
    if "--out" in passed or "--points" in passed:
        ap.error("--out, --points: set by this study per variation")
    try:
        ccts = _floats(args.cct)
    except ValueError as err:
        ap.error(f"--cct: {err}")
    if REFERENCE_CCT not in ccts:
        ap.error(f"--cct: the reference CCT {REFERENCE_CCT:g} mm must be among them, got "
                 f"{args.cct}")
    every = variations(args.resolution, ccts)
    if args.list:
        for v in every:
            print(f"{v.name:18s} {v.group:14s} {v.moved}  [{v.source}]")
        return 0
    chosen = [v for v in every if v.instrument in (None, args.instrument)]
    skipped = [v.name for v in every if v not in chosen]
    if args.only:
        wanted = {w.strip() for w in args.only.split(",")}
        unknown = sorted(wanted - {v.name for v in every})
        if unknown:
            ap.error(f"--only: {unknown[0]!r} is not a variation (--list shows them)")
        chosen = [v for v in chosen if v.name == BASELINE or v.name in wanted]
    common = ["--resolution", args.resolution, "--instrument", args.instrument,
              "--cct", args.cct, *passed]
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
