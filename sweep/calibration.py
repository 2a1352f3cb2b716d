"""Making an instrument's calibration (``airpuff calibrate``): the reference eye's IOP sweep run
through the sweep engine (or in this process), the fit of ``airpuff_core.calibration``, the
calibration file, and the check of the calibrated IOPg against CCT and E0 at IOP 16.

The reference sweep is an ordinary sweep (``sweep.runner.run_sweep``: points stored, resumed,
combined into ``sweep.nc``) over IOP at the reference eye (``REFERENCE_EYE``), with the
instrument's and the model's options; the check (``check=True``) adds two sweeps at IOP 16, over
CCT (0.45-0.65 mm) and over E0 (0.3-0.9 MPa), and records the raw and calibrated IOPg's slopes
and the calibrated IOPg's error at the reference eye at IOP 16 (a point the fit did not see).
docs/calibration.md describes the method and the shipped calibrations.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import numpy as np

from airpuff_core.atomic import atomic_write
from airpuff_core.calibration import (FORMAT, REFERENCE_EYE, apply_coefficients,
                                      calibration_dir, file_name, fit_coefficients, make_command)
from airpuff_core.params import CHOICES, ParameterError, RunParams
from airpuff_core.provenance import model_version
from airpuff_core.version import __version__

from .grid import SweepSpec

# the IOP sweep of the reference eye [mmHg] (``airpuff calibrate --IOP``): 10 to 30 in 2.5
DEFAULT_IOP = [10.0 + 2.5 * i for i in range(9)]
# the check at IOP 16: CCT [mm] (0.52, the reference eye, among them) and E0 [MPa]
CHECK_IOP = 16.0
CHECK_THICKNESS = [0.45, 0.50, 0.52, 0.55, 0.60, 0.65]
CHECK_E0 = [0.3, 0.5, 0.7, 0.9]
# the calibrated IOPg at the reference eye must read the true IOP within this [mmHg]
TOLERANCE_MMHG = 0.3


@dataclass
class SweepReadings:
    """The raw readings of a sweep's points, in the order of ``spec.points()``."""

    params: list[RunParams]
    P1: np.ndarray
    P2: np.ndarray
    failed: list[str]  # one line per point without both readings

    def axis(self, name: str) -> np.ndarray:
        return np.array([getattr(p, name) for p in self.params], float)


Runner = Callable[[SweepSpec, Path], SweepReadings]


def reference_options(instrument: str, options: dict[str, Any]) -> dict[str, Any]:
    """The run options of the reference sweep: ``options`` (model, resolution, ...) and the
    instrument; raises ParameterError for an instrument this installation does not have."""
    options = dict(options)
    choices = CHOICES.get("instrument", ("paper",))
    if instrument not in choices:
        raise ParameterError("instrument", instrument, "one of " + ", ".join(choices))
    if "instrument" in CHOICES:
        options["instrument"] = instrument
    return options


def reference_spec(instrument: str, iop: list[float], options: dict[str, Any],
                   eye: dict[str, float] | None = None, pmax: float | None = None) -> SweepSpec:
    """The reference sweep: IOP values at the reference eye (``REFERENCE_EYE`` updated by
    ``eye``: thickness, E0, R, ...) with the instrument's pulse (``pmax`` [kPa], default the
    parameter's) and ``options``, validated."""
    eye = {**REFERENCE_EYE, **(eye or {})}
    if len(iop) < 2:
        raise ParameterError("IOP", ",".join(f"{v:g}" for v in iop),
                             "at least two distinct values (e.g. 10:30:9)")
    options = reference_options(instrument, options)
    options.update({k: v for k, v in eye.items() if k not in ("E0", "thickness")})
    axes = {"E0": [eye["E0"]], "IOP": list(iop), "thickness": [eye["thickness"]]}
    if pmax is not None:
        axes["pmax"] = [pmax]
    return SweepSpec(**axes, options=options).validate()


def check_specs(reference: SweepSpec) -> dict[str, SweepSpec]:
    """The check's sweeps about the reference eye at IOP 16: over CCT and over E0."""
    base = dict(E0=reference.E0, IOP=[CHECK_IOP], thickness=reference.thickness,
                pmax=reference.pmax, options=dict(reference.options))
    return {"thickness": SweepSpec(**{**base, "thickness": CHECK_THICKNESS}).validate(),
            "E0": SweepSpec(**{**base, "E0": CHECK_E0}).validate()}


def readings_of(params: list[RunParams], metrics: list[dict | None],
                messages: list[str]) -> SweepReadings:
    p1 = np.array([np.nan if m is None or m.get("P1") is None else m["P1"] for m in metrics])
    p2 = np.array([np.nan if m is None or m.get("P2") is None else m["P2"] for m in metrics])
    failed = [f"IOP {p.IOP:g}, E0 {p.E0:g}, thickness {p.thickness:g}: {msg}"
              for p, a, b, msg in zip(params, p1, p2, messages)
              if not (math.isfinite(a) and math.isfinite(b))]
    return SweepReadings(params, p1, p2, failed)


def run_on_dask(workers: int = 2, scheduler: str | None = None, progress=None) -> Runner:
    """A runner computing a sweep with ``sweep.runner.run_sweep`` (stored, resumable: the
    points in ``<out_dir>/../points``, the combined file in ``out_dir``)."""
    from .runner import run_sweep

    def run(spec: SweepSpec, out_dir: Path) -> SweepReadings:
        # the sweeps of one calibration share their points (the check's E0 and CCT sweeps
        # both hold the reference eye at IOP 16)
        outcome = run_sweep(spec, out_dir, workers=workers, scheduler=scheduler,
                            progress=progress, points_dir=Path(out_dir).parent / "points")
        recs = outcome.records
        return readings_of(spec.points(), [r.metrics if r is not None else None for r in recs],
                           [(r.message if r is not None else "not run") or "no applanation"
                            for r in recs])
    return run


def run_in_process(spec: SweepSpec, out_dir: Path) -> SweepReadings:
    """A runner computing a sweep's points one after the other in this process (no files)."""
    from airpuff_core import SimulationError, simulate

    params, metrics, messages = spec.validated_points(), [], []
    for p in params:
        try:
            metrics.append(simulate(p).metrics)
            messages.append("no applanation")
        except SimulationError as err:
            metrics.append(None)
            messages.append(str(err))
    return readings_of(params, metrics, messages)


def _slope(x, y) -> float:
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(y)
    return float(np.polyfit(x[ok], y[ok], 1)[0]) if ok.sum() >= 2 else math.nan


def make_calibration(instrument: str, spec: SweepSpec, readings: SweepReadings,
                     command: str) -> dict[str, Any]:
    """The calibration file's object from the reference sweep's readings (every point must have
    both applanations: a calibration is not fitted on part of its sweep)."""
    if readings.failed:
        raise ValueError("the reference sweep has points without both applanations: "
                         + "; ".join(readings.failed))
    iop = readings.axis("IOP")
    coef = fit_coefficients(iop, readings.P1, readings.P2)
    cal = apply_coefficients(coef, readings.P1, readings.P2)
    reference = readings.params[0].to_dict()
    run_options = {k: v for k, v in reference.items() if k != "IOP"}
    error = {name: np.asarray(cal[name]) - iop for name in ("IOPg_cal", "IOPcc_ora_cal",
                                                            "IOPnc_cal")}
    return {
        "format": FORMAT,
        "instrument": instrument,
        "model_version": model_version(),
        "resolution": reference["resolution"],
        "model": reference["model"],
        "airpuff_version": __version__,
        "created": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": command,
        "reference_eye": {k: reference[k] for k in ("E0", "thickness", "R")},
        "run_options": run_options,
        "coefficients": coef,
        "formulas": {
            "P_cal": "pressure_offset + pressure_slope * P_raw (P1 and P2)",
            "CRF_cal": "P1_cal - 0.70 P2_cal + crf_constant",
            "IOPcc_ora_cal": "iopcc_ora_scale * (P2_cal - 0.43 P1_cal) + iopcc_ora_constant",
            "IOPnc_cal": "iopnc_offset + iopnc_slope * P1_raw",
        },
        "reference_sweep": {
            "IOP": iop.tolist(), "P1_raw": readings.P1.tolist(), "P2_raw": readings.P2.tolist(),
            **{name: np.asarray(cal[name]).tolist() for name in
               ("IOPg_cal", "CH_cal", "CRF_cal", "IOPcc_ora_cal", "IOPnc_cal")},
        },
        "fit": {f"{name}_max_abs_error": float(np.max(np.abs(e))) for name, e in error.items()}
               | {f"{name}_rms_error": float(np.sqrt(np.mean(e ** 2)))
                  for name, e in error.items()},
    }


def check_calibration(data: dict[str, Any], readings: dict[str, SweepReadings]) -> dict:
    """The check of a calibration (``data``, from ``make_calibration``) on the sweeps of
    ``check_specs``: raw and calibrated IOPg against CCT [mmHg per 100 um] and against E0
    [mmHg per 0.1 MPa] at IOP 16, and the calibrated readings' error at the reference eye."""
    coef = data["coefficients"]
    out: dict[str, Any] = {"IOP": CHECK_IOP}
    for axis, per, unit in (("thickness", 0.1, "mmHg per 100 um"),
                            ("E0", 0.1, "mmHg per 0.1 MPa")):
        r = readings[axis]
        x = r.axis(axis)
        cal = apply_coefficients(coef, r.P1, r.P2)
        raw_iopg = 0.5 * (r.P1 + r.P2)
        out[axis] = {"values": x.tolist(), "IOPg_raw": raw_iopg.tolist(),
                     "IOPg_cal": np.asarray(cal["IOPg_cal"]).tolist(),
                     "IOPcc_ora_cal": np.asarray(cal["IOPcc_ora_cal"]).tolist(),
                     "IOPnc_cal": np.asarray(cal["IOPnc_cal"]).tolist(),
                     "CH_cal": np.asarray(cal["CH_cal"]).tolist(),
                     "slope_unit": unit,
                     "IOPg_raw_slope": _slope(x, raw_iopg) * per,
                     "IOPg_cal_slope": _slope(x, cal["IOPg_cal"]) * per,
                     "IOPcc_ora_cal_slope": _slope(x, cal["IOPcc_ora_cal"]) * per,
                     "IOPnc_cal_slope": _slope(x, cal["IOPnc_cal"]) * per,
                     "failed": r.failed}
        ref = data["reference_eye"][axis]
        at_ref = np.isclose(x, ref)
        if at_ref.any() and axis == "thickness":
            i = int(np.argmax(at_ref))
            out["at_reference_eye"] = {name: float(np.asarray(cal[name])[i]) - CHECK_IOP
                                       for name in ("IOPg_cal", "IOPcc_ora_cal", "IOPnc_cal")}
    return out


def write_calibration(data: dict[str, Any], directory: str | Path | None = None) -> Path:
    """Write ``data`` to ``directory`` (default ``calibration_dir()``) as
    ``<instrument>_<model>_<resolution>_<model version>.json``, atomically."""
    directory = Path(directory) if directory is not None else calibration_dir()
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / file_name(data["instrument"], data["model"], data["resolution"],
                                 data["model_version"])
    text = json.dumps(data, indent=1, sort_keys=False) + "\n"
    return atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))


def command_line(spec: SweepSpec, check: bool) -> str:
    """The one line that makes the calibration of the reference sweep ``spec`` again: the
    instrument, resolution, model and the options that differ from the preset's
    (``make_command``), the IOP values, and the reference eye where it is not
    ``REFERENCE_EYE`` (where the sweeps' files go does not change the calibration)."""
    params = spec.points()[0].to_dict()
    words = [make_command(params), "--IOP", ",".join(f"{v:g}" for v in spec.IOP)]
    for name, default in REFERENCE_EYE.items():
        if params[name] != default:
            words += [f"--{name}", f"{params[name]:g}"]
    if check:
        words.append("--check")
    return " ".join(words)
