"""The instruments' calibration: the raw applanation pressures mapped to a Goldmann-equivalent
scale, fitted on the model's own IOP sweep at a reference eye (docs/calibration.md).

The model's P1 and P2 are the instrument's pressure at the apex at the two applanations: raw
readings, which include the cornea's resistance (IOPg reads about 24 mmHg for a true IOP of 16
on the clinical preset).  The ORA and the Corvis ST are calibrated so that their readings equal
Goldmann's; here, so that at the reference eye (``REFERENCE_EYE``: the thickness Goldmann's
tonometer was designed for) the calibrated IOPg equals the true IOP.  One linear map for both
applanations, as the ORA stores one slope and intercept per device (``m_ABC``, ``b_ABC``,
docs/sources.md section 2):

    P_cal = a + b P_raw,   (a, b) by least squares of  a + b (P1 + P2)/2 = IOP  over the sweep

and from P1_cal, P2_cal the readings of ``metrics.applanation_readings`` with the ORA's fixed
coefficients 0.43 and 0.70 (docs/sources.md section 2) and constants re-derived on the sweep:

    CRF_cal       = P1_cal - 0.70 P2_cal + k_CRF,   k_CRF: mean CRF_cal = mean CH_cal over the sweep
                    (the device's -3.08 puts the CRF mean near the CH mean)
    IOPcc_ora_cal = s (P2_cal - 0.43 P1_cal) + k_cc,  (s, k_cc) by least squares to the true IOP
                    (the device's 1.51 and 13.87 make it read the IOPg mean)
    IOPnc_cal     = a_nc + b_nc P1_raw,  by least squares to the true IOP (the Corvis ST's
                    non-contact IOP from the first applanation alone)

A calibration belongs to one model version (``provenance.model_version``), one instrument, one
resolution and the instrument's and the numerics' options: it applies to a run whose parameters
other than the eye's (``EYE_PARAMETERS``) are those of its reference sweep.  A run without such
a calibration gets NaN calibrated readings with the reason and the command that makes one: a
calibration of another model version is never applied.  The calibrated readings are computed
from the raw ones whenever a dataset is made (a run's file, ``sweep.nc``), never stored as
inputs, so a calibration made after a run still reaches its sweep file.

The files live in ``CALIBRATION_DIR`` (the package's ``calibrations/``), one JSON object each
(``FORMAT``), written by ``airpuff calibrate`` (``sweep/calibration.py``).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .metrics import CRF_COEF, IOPCC_COEF, applanation_readings

FORMAT = "airpuff-calibration/1"
CALIBRATION_DIR = Path(__file__).resolve().parent / "calibrations"
COMMAND = "airpuff calibrate"

# The reference eye: Goldmann's tonometer was designed for a central corneal thickness of
# 0.52 mm (Duane's Ophthalmology, ch. 46, fig. 8; Ehlers, Bramsen and Sperling, Acta Ophthalmol.
# 53 (1975) 34: readings and manometric pressure coincide at normal thickness); E0 and the
# radius are the model's defaults, the normal eye of docs/validation.md.
REFERENCE_EYE = {"thickness": 0.52, "E0": 0.5, "R": 7.0}

# The parameters of the eye, across which a calibration applies (the patient's tissue, pressure
# and geometry, and the whole eye's motion in the orbit, which does not act back on P1 and P2:
# docs/model.md section 14); every other parameter (the instrument's pulse, the model, the
# numerics) must be the reference sweep's.
EYE_PARAMETERS = ("E0", "IOP", "thickness", "R", "r_post", "alpha0", "rho_cornea", "rho_fluid",
                  "mu", "nu", "fung_k", "ve_g", "ve_tau", "transverse_shear_modulus",
                  "ocular_rigidity", "eye_motion", "eye_mass", "eye_spring", "eye_damper")

# calibrated reading -> (unit, long name); the raw reading of each is the name without "_cal"
# (IOPnc_cal's raw reading is P1)
CALIBRATED: dict[str, tuple[str, str]] = {
    "P1_cal": ("mmHg", "first applanation pressure, calibrated: a + b P1"),
    "P2_cal": ("mmHg", "second applanation pressure, calibrated: a + b P2"),
    "CH_cal": ("mmHg", "corneal hysteresis, calibrated: P1_cal - P2_cal"),
    "IOPg_cal": ("mmHg", "Goldmann-equivalent IOP, calibrated: (P1_cal + P2_cal)/2"),
    "IOPcc_cal": ("mmHg", "corneal-compensated IOP of the paper, calibrated: P1_cal - 0.43 "
                          "P2_cal"),
    "CRF_cal": ("mmHg", "corneal resistance factor (ORA), calibrated: P1_cal - 0.70 P2_cal + "
                        "k_CRF"),
    "IOPcc_ora_cal": ("mmHg", "corneal-compensated IOP (ORA), calibrated: s (P2_cal - 0.43 "
                              "P1_cal) + k_cc"),
    "IOPnc_cal": ("mmHg", "non-contact IOP from the first applanation alone (Corvis ST), "
                          "calibrated: a_nc + b_nc P1"),
}


@dataclass(frozen=True)
class Calibration:
    """One calibration: its key (instrument, model version, resolution, the reference sweep's
    run options without IOP) and its coefficients [mmHg, 1]."""

    instrument: str
    model_version: str
    resolution: str
    run_options: dict[str, Any]
    pressure_offset: float  # a
    pressure_slope: float  # b
    crf_constant: float  # k_CRF
    iopcc_ora_scale: float  # s
    iopcc_ora_constant: float  # k_cc
    iopnc_offset: float  # a_nc
    iopnc_slope: float  # b_nc
    name: str = ""  # the file's name
    extra: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @property
    def label(self) -> str:
        """What the calibrated variables' ``calibration`` attribute says."""
        return (f"{self.name or 'calibration'} (instrument {self.instrument}, model version "
                f"{self.model_version}, {self.resolution} resolution)")

    def coefficients(self) -> dict[str, float]:
        return {"pressure_offset": self.pressure_offset, "pressure_slope": self.pressure_slope,
                "crf_constant": self.crf_constant, "iopcc_ora_scale": self.iopcc_ora_scale,
                "iopcc_ora_constant": self.iopcc_ora_constant,
                "iopnc_offset": self.iopnc_offset, "iopnc_slope": self.iopnc_slope}


# -- the fit --------------------------------------------------------------------------------------
def _line(x, y) -> tuple[float, float]:
    """(offset, slope) of the least-squares line y = offset + slope x."""
    x = np.asarray(x, float)
    design = np.column_stack([np.ones_like(x), x])
    (offset, slope), *_ = np.linalg.lstsq(design, np.asarray(y, float), rcond=None)
    return float(offset), float(slope)


def fit_coefficients(true_iop, p1_raw, p2_raw) -> dict[str, float]:
    """The coefficients of the module docstring from a reference sweep: true IOP [mmHg] and the
    raw P1, P2 [mmHg] of each point (at least two points with distinct raw IOPg)."""
    iop, p1, p2 = (np.asarray(v, float) for v in (true_iop, p1_raw, p2_raw))
    if iop.size < 2 or not (iop.shape == p1.shape == p2.shape):
        raise ValueError("a calibration needs the true IOP, P1 and P2 of at least two points")
    if not np.all(np.isfinite(iop) & np.isfinite(p1) & np.isfinite(p2)):
        raise ValueError("a calibration needs finite P1 and P2 at every point")
    if np.ptp(0.5 * (p1 + p2)) == 0.0 or np.ptp(p1) == 0.0:
        raise ValueError("a calibration needs points with distinct readings")
    a, b = _line(0.5 * (p1 + p2), iop)
    p1c, p2c = a + b * p1, a + b * p2
    readings = applanation_readings(p1c, p2c)
    k_crf = float(np.mean(readings["CH"]) - np.mean(readings["CRF"]))
    k_cc, s = _line(readings["IOPcc_ora"], iop)
    a_nc, b_nc = _line(p1, iop)
    return {"pressure_offset": a, "pressure_slope": b, "crf_constant": k_crf,
            "iopcc_ora_scale": s, "iopcc_ora_constant": k_cc, "iopnc_offset": a_nc,
            "iopnc_slope": b_nc}


# -- applying it ----------------------------------------------------------------------------------
def apply_coefficients(coef: Mapping[str, float], p1_raw, p2_raw) -> dict[str, Any]:
    """The calibrated readings (``CALIBRATED``) of raw P1, P2 [mmHg] (floats or arrays; NaN in,
    NaN out) with coefficients ``coef`` (``Calibration.coefficients()``)."""
    p1 = np.asarray(p1_raw, float)
    p2 = np.asarray(p2_raw, float)
    a, b = coef["pressure_offset"], coef["pressure_slope"]
    p1c, p2c = a + b * p1, a + b * p2
    r = applanation_readings(p1c, p2c)
    out = {"P1_cal": p1c, "P2_cal": p2c, "CH_cal": r["CH"], "IOPg_cal": r["IOPg"],
           "IOPcc_cal": r["IOPcc"], "CRF_cal": r["CRF"] + coef["crf_constant"],
           "IOPcc_ora_cal": coef["iopcc_ora_scale"] * r["IOPcc_ora"] + coef["iopcc_ora_constant"],
           "IOPnc_cal": coef["iopnc_offset"] + coef["iopnc_slope"] * p1}
    if np.ndim(p1) == 0 and np.ndim(p2) == 0:
        return {k: float(v) for k, v in out.items()}
    return out


def nan_readings(shape=()) -> dict[str, Any]:
    """NaN for every calibrated reading (a float, or arrays of ``shape``)."""
    if shape == ():
        return {name: math.nan for name in CALIBRATED}
    return {name: np.full(shape, np.nan) for name in CALIBRATED}


# -- the files ------------------------------------------------------------------------------------
def calibration_dir() -> Path:
    """Where calibrations are looked for: ``AIRPUFF_CALIBRATION_DIR`` if set (a study's or a
    test's own folder), else the package's ``calibrations/``."""
    env = os.environ.get("AIRPUFF_CALIBRATION_DIR")
    return Path(env) if env else CALIBRATION_DIR


def file_name(instrument: str, model: str, resolution: str, model_version: str) -> str:
    return f"{instrument}_{model}_{resolution}_{model_version}.json"


def calibration_from_dict(data: Mapping[str, Any], name: str = "") -> Calibration:
    """A ``Calibration`` from its JSON object (``FORMAT``); raises ValueError on another
    format or a missing field."""
    if data.get("format") != FORMAT:
        raise ValueError(f"not an {FORMAT} file (format {data.get('format')!r})")
    try:
        coef = data["coefficients"]
        return Calibration(
            instrument=str(data["instrument"]), model_version=str(data["model_version"]),
            resolution=str(data["resolution"]), run_options=dict(data["run_options"]),
            **{k: float(coef[k]) for k in ("pressure_offset", "pressure_slope", "crf_constant",
                                           "iopcc_ora_scale", "iopcc_ora_constant",
                                           "iopnc_offset", "iopnc_slope")},
            name=name, extra=dict(data))
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"incomplete calibration {name or ''}: {err!r}") from None


def load_calibrations(directory: str | os.PathLike | None = None) -> list[Calibration]:
    """Every readable calibration file in ``directory`` (default ``calibration_dir()``); a
    file that is not one is skipped (it cannot be applied)."""
    directory = Path(directory) if directory is not None else calibration_dir()
    out = []
    for path in sorted(directory.glob("*.json")) if directory.is_dir() else []:
        try:
            out.append(calibration_from_dict(json.loads(path.read_text(encoding="utf-8")),
                                             path.name))
        except (OSError, ValueError):
            continue
    return out


def instrument_of(params: Mapping[str, Any]) -> str:
    """The run's instrument (``paper``, the paper's jet, for parameter sets without one)."""
    return str(params.get("instrument", "paper"))


def make_command(params: Mapping[str, Any]) -> str:
    """The ``airpuff calibrate`` command line that makes a calibration for runs like
    ``params``: the instrument, resolution and model, and every other non-eye option that
    differs from the model preset's default."""
    from .params import RunParams  # only here: params imports the cornea registry

    base = {"model": params.get("model", "paper"), "resolution": params.get("resolution")}
    if "instrument" in params:
        base["instrument"] = params["instrument"]
    default = RunParams.from_dict(base).to_dict()
    words = [COMMAND, "--instrument", instrument_of(params), "--resolution",
             str(params.get("resolution")), "--model", str(base["model"])]
    for name, value in params.items():
        if name in EYE_PARAMETERS or name in ("instrument", "resolution", "model"):
            continue
        if default.get(name) != value and value is not None:
            text = f"{value:g}" if isinstance(value, float) else str(value)
            words += ["--" + name.replace("_", "-"), text]
    return " ".join(words)


def _differences(cal: Calibration, params: Mapping[str, Any]) -> list[str]:
    """The non-eye options in which ``params`` differ from the calibration's reference sweep."""
    out = []
    for name in sorted(set(cal.run_options) | set(params)):
        if name in EYE_PARAMETERS:
            continue
        ours, theirs = params.get(name), cal.run_options.get(name)
        if ours != theirs:
            out.append(f"{name} {theirs} (this run {ours})")
    return out


def find_calibration(params: Mapping[str, Any], model_version: str,
                     calibrations: list[Calibration]) -> tuple[Calibration | None, str]:
    """The calibration that applies to a run of ``params`` (``RunParams.to_dict()``) computed by
    ``model_version``, and ``""``; or None and the reason, naming the command that makes one."""
    instrument = instrument_of(params)
    resolution = params.get("resolution")
    same = [c for c in calibrations if c.instrument == instrument and c.resolution == resolution]
    current = [c for c in same if c.model_version == model_version]
    for cal in current:
        if not _differences(cal, params):
            return cal, ""
    make = f"make one with: {make_command(params)}"
    if current:
        diffs = "; ".join(_differences(current[0], params)[:4])
        return None, (f"no calibration of instrument {instrument} at {resolution} resolution "
                      f"for these options at model version {model_version} ({current[0].name} "
                      f"was fitted with {diffs}); {make}")
    stale = sorted({c.model_version for c in same})
    why = (f" (the calibrations found are for model version {', '.join(stale)}: the model has "
           "changed since, so they are not applied)") if stale else ""
    return None, (f"no calibration of instrument {instrument} at {resolution} resolution for "
                  f"model version {model_version}{why}; {make}")


def calibrate_metrics(params: Mapping[str, Any], metrics: Mapping[str, float],
                      model_version: str, calibrations: list[Calibration] | None = None
                      ) -> tuple[dict[str, float], Calibration | None, str]:
    """(calibrated readings, the calibration used or None, why none applies) of one run's raw
    ``metrics``; ``calibrations`` default: ``load_calibrations()``."""
    if calibrations is None:
        calibrations = load_calibrations()
    cal, reason = find_calibration(params, model_version, calibrations)
    if cal is None:
        return nan_readings(), None, reason
    values = apply_coefficients(cal.coefficients(), metrics.get("P1", math.nan),
                                metrics.get("P2", math.nan))
    return values, cal, ""


def variable_attrs(name: str, cal: Calibration | None, reason: str) -> dict[str, str]:
    """The netCDF attributes of calibrated reading ``name``: units, long name, the calibration
    it used (or ``none``) and, without one, the reason in ``comment``."""
    unit, long_name = CALIBRATED[name]
    attrs = {"units": unit, "long_name": long_name,
             "calibration": cal.label if cal is not None else "none"}
    if cal is None:
        attrs["comment"] = reason
    return attrs
