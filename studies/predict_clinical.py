"""The clinical model's predictions beside the clinic (issue 27, item 2): quantities the fit does
not use.

The fit (``studies/fit_clinical.py``) sets two tissue values on two population means: the
calibrated IOPg's slope against CCT and the mean CH.  Every row here is another quantity, the
model's value computed by the solver and set against a published clinical number with its
source and spread (docs/sources.md sections 4, 7 and 9):

* under the ORA's pulse, calibrated readings: CH against CCT and against IOP, CRF against CCT
  and IOP, IOPg against E0 (stiffer reads higher), the ORA's IOPcc against CCT (designed to be
  independent of it);
* under the Corvis ST's pulse (the eye on Kling's orbit, as ``studies/corvis_outputs.py``): A1T,
  A2T, HC time, DA and the deflection amplitude of the normal eye, and DA's slope against IOP.

**The runs.**  The normal eye is the fit's reference eye (IOP 16 mmHg, E0 0.5 MPa, CCT 0.54 mm);
each slope row moves one of CCT (``--cct``), IOP (``--iop``, ``--corvis-iop``) or E0 (``--e0``)
about it, everything else fixed, and takes the least-squares slope over the points.  The tissue
values are the clinical preset's, or given (``--set transverse_shear_modulus=12.46 --set
ve_g=0.4``: the fitted ones).  Every run is a point of the sweep's storage (``<out>/points``,
the fit's ``PointRunner``: a rerun reuses what is stored; ``--workers N`` on a local Dask
cluster).

**Calibration.**  The ORA rows read the calibrated readings (``*_cal``,
``airpuff_core/calibration.py``).  ``--calibration shipped`` (default) applies the calibration
file of the runs' model version and resolution, if one exists; otherwise the row is NaN and its
note gives the reason and the command that makes one (never a stale calibration).
``--calibration refit`` makes the calibration on its reference sweep with these tissue values, as
the fit does at every trial (``fit_clinical.Responses.calibration``): the choice for fitted
values that no shipped file belongs to.

**Agreement.**  Each row's clinic has a criterion: ``sd`` (a mean and SD: agrees if the model
lies within one SD), ``range`` (published values or a derived band: agrees inside it), ``sign``
(only a direction is published: agrees if the slope has that sign) or ``none`` (no clinical
number: no verdict).  Nothing here is fitted: no parameter may be tuned to these rows.

    python -m studies.predict_clinical --out /tmp/predict_coarse --resolution coarse
    python -m studies.predict_clinical --out predict_fit --resolution paper --calibration refit \\
        --set transverse_shear_modulus=12.46 --set ve_g=0.4035 --workers 2

Outputs: ``<out>/predictions.json`` (every row with its points, the runs' keys and the
calibration used) and ``<out>/predictions.md`` (the table).
"""

from __future__ import annotations

import json
import math
import shlex
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from airpuff_core.atomic import atomic_write
from airpuff_core.calibration import apply_coefficients, calibrate_metrics
from airpuff_core.params import CHOICES, ParameterError, RunParams
from airpuff_core.provenance import model_version

from .fit_clinical import (CCT_POINTS, RATIO, REFERENCE, REFERENCE_CCT, SHEAR, FitError,
                           Responses, _floats, _number, point_runner)

# the swept coordinate of a slope row -> (run parameter, the unit its slope is given per, the
# factor from "per run-parameter unit" to that unit)
AGAINST = {"CCT": ("thickness", "100 um", 0.1), "IOP": ("IOP", "mmHg", 1.0),
           "E0": ("E0", "0.1 MPa", 0.1)}
IOP_POINTS = (12.0, 16.0, 20.0, 24.0)
E0_POINTS = (0.3, 0.5, 0.7)
CORVIS_IOP_POINTS = (10.0, 13.0, 16.0, 20.0, 25.0)
# the Corvis rows' eye sits on Kling's orbit, as in studies/corvis_outputs.py: the instrument's
# DA includes the whole eye's movement
CORVIS_OPTIONS = {"eye_motion": "spring_damper"}
# what the grid sets; --set may not
GRID_PARAMETERS = ("model", "resolution", "instrument", "thickness", "IOP", "E0")


@dataclass(frozen=True)
class Clinic:
    """A published clinical number and how a model value is judged against it.

    ``criterion``: ``sd`` (agrees if |model - value| <= spread), ``range`` (agrees if low <=
    model <= high), ``sign`` (agrees if the model's sign is that of ``value``, +1 or -1),
    ``none`` (no clinical number: no verdict)."""

    text: str
    criterion: str
    source: str
    value: float = math.nan
    spread: float = math.nan
    low: float = math.nan
    high: float = math.nan


@dataclass(frozen=True)
class Row:
    """One prediction: ``reading`` (a run metric; ``*_cal`` a calibrated reading) under
    ``instrument``, at the normal eye (``against`` None) or its least-squares slope against
    ``against`` (a key of ``AGAINST``)."""

    name: str
    instrument: str
    reading: str
    against: str | None
    unit: str
    clinic: Clinic

    @property
    def calibrated(self) -> bool:
        return self.reading.endswith("_cal")


# docs/sources.md: section 7 (ORA), section 4 (Corvis), section 9 (the rows)
ROWS = (
    Row("CH against CCT", "ora", "CH_cal", "CCT", "mmHg per 100 um", Clinic(
        "rises: +0.4 (univariate, 1,561 eyes) to +2.2 (multivariate, 86 eyes); r 0.21-0.42",
        "range", "Madrid, Int Glaucoma Rev abstract 108445; PubMed 18546008; TwinsUK; "
        "Kotecha et al. BMC Ophthalmol 14 (2014) 11 (CCT +0.62 scaled)", low=0.4, high=2.2)),
    Row("CH against IOP", "ora", "CH_cal", "IOP", "mmHg per mmHg", Clinic(
        "about none: TwinsUK r 0.04 n.s. (+0.02 per mmHg, D), -0.12 per mmHg (multivariate); "
        "Kotecha 2014: no IOP term", "range",
        "TwinsUK ARVO abstract (IOVS 2362078); PubMed 18546008; Kotecha et al. 2014",
        low=-0.12, high=0.02)),
    Row("CRF against CCT", "ora", "CRF_cal", "CCT", "mmHg per 100 um", Clinic(
        "rises (Kotecha 2014 scaled +0.89; Sharifipour r 0.26); slope not found", "sign",
        "Kotecha et al. 2014; Sharifipour et al. J Curr Ophthalmol 28 (2016) 117", value=1.0)),
    Row("CRF against IOP", "ora", "CRF_cal", "IOP", "mmHg per mmHg", Clinic(
        "rises (Kotecha 2014 scaled +0.46, DCT IOP; Sharifipour r 0.60); slope not found",
        "sign", "Kotecha et al. 2014; Sharifipour et al. 2016", value=1.0)),
    Row("IOPg against E0", "ora", "IOPg_cal", "E0", "mmHg per 0.1 MPa", Clinic(
        "stiffer reads higher; no clinical slope (a model's: Orssengo-Pye +2.3 per 0.1 MPa)",
        "sign", "finite-element studies (Elsheikh et al. Ann Biomed Eng 34 (2006) 1628; Kwon "
        "et al. J Refract Surg 26 (2010)); PubMed 18521022 (the model's slope)", value=1.0)),
    Row("IOPcc (ORA) against CCT", "ora", "IOPcc_ora_cal", "CCT", "mmHg per 100 um", Clinic(
        "none: r 0.06 n.s. (within +-0.6 per 100 um, D); thin and thick corneas alike",
        "range", "Sharifipour et al. 2016; Clin Optom (2019) 127", low=-0.6, high=0.6)),
    Row("A1T", "corvis", "t_A1", None, "ms", Clinic(
        "7.36 +- 0.39 (1,304 eyes; 8.32 +- 0.33 in 90 eyes)", "sd",
        "PMC7001013; Valbon et al. J Refract Surg 30 (2014) 468", value=7.36, spread=0.39)),
    Row("A2T", "corvis", "t_A2", None, "ms", Clinic(
        "20.13 +- 0.48 (1,304 eyes; 22.18 +- 0.52 and 23.80 +- 0.44 in other cohorts)", "sd",
        "PMC7001013; J Ophthalmol 2014, 147516; Valbon et al. 2014", value=20.13,
        spread=0.48)),
    Row("HC time", "corvis", "t_HC", None, "ms", Clinic(
        "16.84 +- 0.64 (1,304 eyes; 18.38 +- 0.93 in 90 eyes)", "sd",
        "PMC7001013; Valbon et al. 2014", value=16.84, spread=0.64)),
    Row("DA", "corvis", "DA", None, "mm", Clinic(
        "1.05 +- 0.10 (1,304 eyes; 1.05 +- 0.08 in 90 eyes)", "sd",
        "PMC7001013; Valbon et al. 2014", value=1.05, spread=0.10)),
    Row("deflection amplitude", "corvis", "deflection_amplitude", None, "mm", Clinic(
        "not found (Vinciguerra 2016's normative tables not readable here)", "none",
        "Vinciguerra et al. J Refract Surg 32 (2016) 550")),
    Row("DA against IOP", "corvis", "DA", "IOP", "mm per mmHg", Clinic(
        "falls (DA-IOPcc r -0.36: about -0.012 mm per mmHg, D); slope not found", "sign",
        "1,262-eye ORA and Corvis study (2014); Asaoka et al. PLoS ONE 10 (2015) e0140385; "
        "Yonsei Med J 59 (2018) 1115", value=-1.0)),
)


# -- the computations ---------------------------------------------------------------------------
def least_squares_slope(x, y) -> float:
    """The slope of the least-squares line through the points (x, y) (NaN if fewer than two
    finite points with distinct x)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 2 or np.unique(x[ok]).size < 2:
        return math.nan
    return float(np.polyfit(x[ok], y[ok], 1)[0])


def row_value(row: Row, points: list[tuple[float, float]], normal_x: float | None = None
              ) -> float:
    """The model's value of ``row`` from its points (x, reading): the slope in the row's unit
    (``AGAINST``), or, for a row at the normal eye, the reading at ``normal_x`` (or the only
    point)."""
    if row.against is None:
        values = [y for x, y in points if normal_x is None or x == normal_x]
        return float(values[0]) if values else math.nan
    return least_squares_slope(*zip(*points)) * AGAINST[row.against][2] if points else math.nan


def agreement(value: float, clinic: Clinic) -> str:
    """``yes``, ``no``, ``no model value`` or ``no clinical number``, by the clinic's
    criterion (:class:`Clinic`)."""
    if clinic.criterion == "none":
        return "no clinical number"
    if not math.isfinite(value):
        return "no model value"
    if clinic.criterion == "sd":
        ok = abs(value - clinic.value) <= clinic.spread
    elif clinic.criterion == "range":
        ok = clinic.low <= value <= clinic.high
    elif clinic.criterion == "sign":
        ok = value != 0 and math.copysign(1.0, value) == math.copysign(1.0, clinic.value)
    else:
        raise ValueError(f"unknown criterion {clinic.criterion!r}")
    return "yes" if ok else "no"


def off_by(value: float, clinic: Clinic) -> str:
    """How far the model lies from the clinic, in the clinic's SDs (``sd`` rows only)."""
    if clinic.criterion != "sd" or not math.isfinite(value):
        return ""
    return f"{(value - clinic.value) / clinic.spread:+.1f} SD"


# -- the runs -----------------------------------------------------------------------------------
@dataclass
class Grid:
    """The runs of the rows: the normal eye and each row's points, per instrument."""

    base: dict  # run parameters common to every run (tissue values, resolution, model)
    cct: tuple[float, ...] = CCT_POINTS
    iop: tuple[float, ...] = IOP_POINTS
    e0: tuple[float, ...] = E0_POINTS
    corvis_iop: tuple[float, ...] = CORVIS_IOP_POINTS
    normal: dict = field(default_factory=lambda: {**REFERENCE, "thickness": REFERENCE_CCT})

    def instrument_base(self, instrument: str) -> dict:
        extra = CORVIS_OPTIONS if instrument == "corvis" else {}
        return {**self.base, "instrument": instrument, **extra}

    def xs(self, row: Row) -> tuple[float, ...]:
        if row.against is None:
            return (self.normal[AGAINST["IOP"][0]],)  # the normal eye, indexed by its IOP
        if row.against == "IOP":
            return self.corvis_iop if row.instrument == "corvis" else self.iop
        return {"CCT": self.cct, "E0": self.e0}[row.against]

    def params(self, row: Row, x: float) -> RunParams:
        name = AGAINST[row.against or "IOP"][0]
        return RunParams.from_dict({**self.instrument_base(row.instrument), **self.normal,
                                    name: x})


def tissue_values(params: RunParams) -> tuple[float, float]:
    return (params.transverse_shear_modulus, params.ve_g)


class Readings:
    """The readings of the rows' runs, calibrated where a row asks for it.

    ``calibration``: ``shipped`` (the calibration file of the run's model version, resolution
    and options, ``airpuff_core.calibration.calibrate_metrics``) or ``refit`` (made on its
    reference sweep with the run's tissue values, ``fit_clinical.Responses.calibration``, the
    sweep's IOPs ``calibration_iops``)."""

    def __init__(self, runner, grid: Grid, calibration: str = "shipped",
                 calibration_iops: tuple[float, ...] | None = None):
        self.runner, self.grid = runner, grid
        self.calibration = calibration
        self.calibration_iops = calibration_iops
        self.used: dict[str, str] = {}  # instrument -> the calibration used, or why none
        self._responses: dict[str, Responses] = {}

    def points(self, row: Row) -> tuple[list[tuple[float, float]], list[str], str]:
        """(the row's points (x, reading), the runs' keys, a note: why a value is missing)."""
        xs = self.grid.xs(row)
        params = [self.grid.params(row, x) for x in xs]
        records = self.runner.run(params)
        failed = [f"{AGAINST[row.against or 'IOP'][0]} {x:g}: {r.message}"
                  for x, r in zip(xs, records) if not r.ok]
        values, notes = [], failed[:]
        for p, r in zip(params, records):
            if not r.ok:
                values.append(math.nan)
                continue
            value, note = self.reading(row, p, r)
            values.append(value)
            if note and note not in notes:
                notes.append(note)
        return list(zip(xs, values)), [r.key for r in records], "; ".join(notes)

    def reading(self, row: Row, params: RunParams, record) -> tuple[float, str]:
        metrics = record.metrics
        if not row.calibrated:
            value = metrics.get(row.reading)
            return (math.nan, f"{row.reading} missing") if value is None else (float(value), "")
        if self.calibration == "shipped":
            values, cal, reason = calibrate_metrics(params.to_dict(), metrics,
                                                    record.model_version or model_version())
            self.used[row.instrument] = cal.label if cal is not None else f"none: {reason}"
            return float(values[row.reading]), reason
        coefficients, reason = self._refit(row.instrument, params)
        if coefficients is None:
            return math.nan, reason
        values = apply_coefficients(coefficients, _number(metrics.get("P1")),
                                    _number(metrics.get("P2")))
        return float(values[row.reading]), ""

    def _refit(self, instrument: str, params: RunParams) -> tuple[dict | None, str]:
        if instrument not in self._responses:
            self._responses[instrument] = Responses(
                self.runner, self.grid.instrument_base(instrument),
                calibration_iops=self.calibration_iops, log=lambda entry: None)
        responses = self._responses[instrument]
        try:
            coefficients = responses.calibration(*tissue_values(params))
        except FitError as err:
            self.used[instrument] = f"none: {err}"
            return None, str(err)
        iops = ", ".join(f"{i:g}" for i in self.calibration_iops)
        self.used[instrument] = (f"refit on IOP {iops} mmHg at the reference eye: P_cal = "
                                 f"{coefficients['pressure_offset']:.3f} + "
                                 f"{coefficients['pressure_slope']:.4f} P")
        return coefficients, ""


def predict(readings: Readings, rows=ROWS) -> list[dict]:
    """Every row's model value, verdict and the points and runs it came from."""
    out = []
    for row in rows:
        points, keys, note = readings.points(row)
        normal_x = readings.grid.normal["IOP"] if row.against is None else None
        value = row_value(row, points, normal_x)
        out.append({"row": row.name, "instrument": row.instrument, "reading": row.reading,
                    "against": row.against or "", "unit": row.unit, "model": value,
                    "agrees": agreement(value, row.clinic), "off_by": off_by(value, row.clinic),
                    "note": note, "points": [[x, y] for x, y in points], "keys": keys,
                    "clinic": asdict(row.clinic)})
    return out


# -- the outputs --------------------------------------------------------------------------------
def markdown(summary: dict) -> str:
    """The prediction table: model against clinic, the criterion and the verdict per row."""
    lines = [f"# {summary['title']}", "", f"Command: `{summary['command']}`  ",
             f"Model version {summary['model_version']}, resolution {summary['resolution']}, "
             f"G_t {summary['tissue']['transverse_shear_modulus']:g} kPa, g "
             f"{summary['tissue']['ve_g']:g}, tau {summary['tissue']['ve_tau']:g} ms; "
             f"{summary['runs']} runs ({summary['runs_computed']} computed), "
             f"{summary['wall_s']:.0f} s.", "",
             "Calibration: " + "; ".join(f"{k}: {v}" for k, v in summary["calibration"].items())
             if summary["calibration"] else "Calibration: none used.", "",
             "| row | instrument, reading | model | clinic | criterion | agrees | source | note |",
             "|---|---|---|---|---|---|---|---|"]
    for r in summary["rows"]:
        model = "NaN" if not math.isfinite(r["model"]) else f"{r['model']:+.3g}" \
            if r["against"] else f"{r['model']:.3g}"
        verdict = r["agrees"] + (f" ({r['off_by']})" if r["off_by"] else "")
        lines.append(f"| {r['row']} [{r['unit']}] | {r['instrument']}, `{r['reading']}` | "
                     f"{model} | {r['clinic']['text']} | {r['clinic']['criterion']} | "
                     f"{verdict} | {r['clinic']['source']} | {r['note']} |")
    return "\n".join(lines) + "\n"


def _json_safe(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_json_safe(v) for v in value]
    return value


# -- the command --------------------------------------------------------------------------------
def parse_args(argv):
    from api.cli.common import OneLineParser

    ap = OneLineParser(prog="predict_clinical", description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="folder of the table and the runs")
    ap.add_argument("--resolution", default="coarse", choices=CHOICES["resolution"])
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="a tissue value or other run parameter of every run (e.g. the fitted "
                         "transverse_shear_modulus=12.46, ve_g=0.40)")
    ap.add_argument("--calibration", default="shipped", choices=("shipped", "refit"),
                    help="the ORA rows' calibration: the file of the model version (shipped) or "
                         "made with these tissue values (refit)")
    ap.add_argument("--calibration-iop", default=None, metavar="IOPS",
                    help="IOPs [mmHg] of the refit calibration's reference sweep (default that "
                         "of airpuff calibrate)")
    ap.add_argument("--cct", default=",".join(f"{c:g}" for c in CCT_POINTS),
                    help="CCTs [mm] of the slopes against CCT")
    ap.add_argument("--iop", default=",".join(f"{c:g}" for c in IOP_POINTS),
                    help="IOPs [mmHg] of the ORA's slopes against IOP")
    ap.add_argument("--e0", default=",".join(f"{c:g}" for c in E0_POINTS),
                    help="E0s [MPa] of the slope against E0")
    ap.add_argument("--corvis-iop", default=",".join(f"{c:g}" for c in CORVIS_IOP_POINTS),
                    help="IOPs [mmHg] of DA's slope against IOP (Corvis)")
    ap.add_argument("--rows", default=None, metavar="NAMES",
                    help="only these rows (comma-separated names, e.g. 'A1T,DA against IOP')")
    ap.add_argument("--workers", default="0",
                    help="Dask worker processes for the runs (0: in this process)")
    return ap.parse_args(argv), ap


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args, ap = parse_args(argv)
    if "ora" not in CHOICES.get("instrument", ()) or "corvis" not in CHOICES["instrument"]:
        ap.error("instrument: this version of the solver lacks the ORA's or the Corvis's pulse")
    try:
        grids = {name: _floats(getattr(args, name)) for name in ("cct", "iop", "e0", "corvis_iop")}
        workers = int(args.workers)
        calibration_iops = None
        if args.calibration == "refit":
            from sweep.calibration import DEFAULT_IOP

            calibration_iops = (_floats(args.calibration_iop) if args.calibration_iop
                                else tuple(DEFAULT_IOP))
    except ValueError as err:
        ap.error(str(err))
    for name, values in grids.items():
        if len(set(values)) < 2:
            ap.error(f"--{name.replace('_', '-')}: at least two distinct values, got "
                     f"{getattr(args, name)}")
    if args.calibration_iop and args.calibration != "refit":
        ap.error("--calibration-iop: only with --calibration refit")
    if calibration_iops is not None and len(set(calibration_iops)) < 2:
        ap.error(f"--calibration-iop: at least two distinct IOPs, got {args.calibration_iop}")
    if workers < 0:
        ap.error(f"--workers: 0 or more, got {workers}")
    rows = ROWS
    if args.rows:
        wanted = [w.strip() for w in args.rows.split(",")]
        unknown = [w for w in wanted if w not in {r.name for r in ROWS}]
        if unknown:
            ap.error(f"--rows: {unknown[0]!r} is not a row (the rows: "
                     f"{', '.join(r.name for r in ROWS)})")
        rows = tuple(r for r in ROWS if r.name in wanted)
    base = {"model": "clinical", "resolution": args.resolution}
    for item in args.set:
        name, _, value = item.partition("=")
        if name in GRID_PARAMETERS:
            ap.error(f"--set {name}: set by the rows' grid (use --resolution, --cct, --iop, "
                     f"--e0, --corvis-iop)")
        base[name] = value
    grid = Grid(base, grids["cct"], grids["iop"], grids["e0"], grids["corvis_iop"])
    try:
        for row in rows:
            for x in grid.xs(row):
                grid.params(row, x)
    except ParameterError as err:
        ap.error(str(err))

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    computed = {}

    def log(record, params):
        computed[record.key] = computed.get(record.key, False) or bool(record.computed)
        if record.computed:
            print(f"  run {params.instrument} CCT {params.thickness:g} IOP {params.IOP:g} E0 "
                  f"{params.E0:g}: {record.status}", flush=True)

    t0 = time.perf_counter()
    warm = grid.params(rows[0], grid.xs(rows[0])[0])
    with point_runner(out / "points", workers, warm, log) as runner:
        readings = Readings(runner, grid, args.calibration, calibration_iops)
        results = predict(readings, rows)
    tissue = RunParams.from_dict({**base, "instrument": "ora"})
    summary = {
        "title": f"Predictions of the clinical model ({args.resolution} resolution), not used "
                 f"in the fit",
        "command": "python -m studies.predict_clinical " + " ".join(shlex.quote(a) for a in argv),
        "model_version": model_version(), "resolution": args.resolution,
        "tissue": {SHEAR.name: tissue.transverse_shear_modulus, RATIO.name: tissue.ve_g,
                   "ve_tau": tissue.ve_tau, "ocular_rigidity": tissue.ocular_rigidity},
        "set": args.set, "calibration_mode": args.calibration, "calibration": readings.used,
        "normal_eye": grid.normal, "runs": len(computed),
        "runs_computed": sum(computed.values()), "wall_s": time.perf_counter() - t0,
        "rows": results}
    text = json.dumps(_json_safe(summary), indent=1)
    atomic_write(out / "predictions.json", lambda tmp: tmp.write_text(text + "\n"))
    table = markdown(summary)
    atomic_write(out / "predictions.md", lambda tmp: tmp.write_text(table))
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
