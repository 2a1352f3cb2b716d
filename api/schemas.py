"""Pydantic models of the HTTP API, generated from ``airpuff_core.params``.

The units, defaults and accepted ranges of every run parameter are written once, in
``airpuff_core.params.PARAMETERS`` / ``CHOICES`` / ``INT_PARAMETERS``; the request model below is
built from them, so the OpenAPI schema (``/openapi.json``, ``/docs``) documents exactly what the
solver accepts.  Swept parameters (``SWEPT``) are non-empty lists; every other parameter is a
single value.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, Strict, create_model

from airpuff_core.params import (
    CHOICE_DEFAULTS,
    CHOICE_DESCRIPTIONS,
    CHOICES,
    INT_PARAMETERS,
    PARAMETERS,
    PRESET_PARAMETERS,
    SWEPT,
    ParamSpec,
    choice_default_text,
)
from airpuff_core.calibration import CALIBRATED
from airpuff_core.result import METRICS, RAW_READINGS
from sweep.identification import DEFAULT_SIGMA, MEASURABLE, SIGMA_RANGE, UNITS

from .status import JOB_STATUSES, POINT_STATUSES, JobStatusName, PointStatusName



def _bounds(spec: ParamSpec) -> dict[str, float]:
    b: dict[str, float] = {}
    b["ge" if spec.low_inclusive else "gt"] = spec.low
    b["le" if spec.high_inclusive else "lt"] = spec.high
    return b


def _unit_text(spec: ParamSpec) -> str:
    return "dimensionless" if spec.unit in ("", "1") else spec.unit


def _number(spec: ParamSpec) -> Any:
    """A strict JSON number (no strings, no booleans, finite) within the parameter's range."""
    return Annotated[float, Strict(), Field(allow_inf_nan=False, **_bounds(spec))]


def _swept_field(spec: ParamSpec, max_points: int) -> tuple[Any, Any]:
    desc = (f"{spec.description}. Values of the sweep axis in {_unit_text(spec)}; each "
            f"{spec.accepted()}. A non-empty list of distinct values; default "
            f"[{spec.default:g}].")
    return (list[_number(spec)], Field(  # type: ignore[valid-type]
        default_factory=lambda d=spec.default: [d], min_length=1, max_length=max_points,
        description=desc, json_schema_extra={"x-unit": spec.unit}))


def _option_field(spec: ParamSpec) -> tuple[Any, Any]:
    desc = f"{spec.description} [{_unit_text(spec)}], {spec.accepted()}"
    if spec.name in PRESET_PARAMETERS:  # omitted: the value of the ``model`` preset
        return (Optional[_number(spec)], Field(  # type: ignore[valid-type]
            default=None, description=desc + "; default: from the model preset",
            json_schema_extra={"x-unit": spec.unit}))
    return (_number(spec), Field(default=spec.default, description=desc,
                                 json_schema_extra={"x-unit": spec.unit}))


def _choice_field(name: str) -> tuple[Any, Any]:
    allowed = CHOICES[name]
    return (Literal[allowed], Field(default=CHOICE_DEFAULTS[name],  # type: ignore[valid-type]
                                    description=f"{CHOICE_DESCRIPTIONS[name]}; one of "
                                                + ", ".join(allowed)
                                                + f"; default {choice_default_text(name)}"))


def _int_field(name: str) -> tuple[Any, Any]:
    default, lo, hi, desc = INT_PARAMETERS[name]
    return (Annotated[int, Strict()], Field(default=default, ge=lo, le=hi,
                                            description=f"{desc}, an integer in [{lo}, {hi}]"))


def sweep_request_model(max_points: int) -> type[BaseModel]:
    """The body of ``POST /sweeps``; lists are at most ``max_points`` long (and so is the grid)."""
    fields: dict[str, Any] = {}
    for name in SWEPT:
        fields[name] = _swept_field(PARAMETERS[name], max_points)
    for name, spec in PARAMETERS.items():
        if name not in SWEPT:
            fields[name] = _option_field(spec)
    for name in CHOICES:
        fields[name] = _choice_field(name)
    for name in INT_PARAMETERS:
        fields[name] = _int_field(name)
    fields["retry_failed"] = (Annotated[bool, Strict()], Field(
        default=False, description="compute again the points stored as failed by the model (a "
                                   "blow-up, no convergence), which are otherwise reused; "
                                   "failures of the infrastructure are always computed again"))
    doc = (f"A sweep over the grid E0 x IOP x thickness x pmax (at most {max_points} points). "
           "All other parameters are single values shared by every point; omitted ones take "
           "their defaults. Unknown keys are rejected.")
    return create_model("SweepRequest", __config__=ConfigDict(
        extra="forbid", json_schema_extra={"examples": [{
            "E0": [0.4, 0.6], "IOP": [12.0, 16.0], "thickness": [0.5], "pmax": [10.0],
            "resolution": "coarse"}]}), __doc__=doc, **fields)


class Submitted(BaseModel):
    id: str = Field(description="job id (use it in /sweeps/{id})")
    status: JobStatusName = Field(description="status of the new job (queued)")
    points_total: int = Field(description="number of grid points")


class JobInfo(BaseModel):
    id: str = Field(description="job id")
    status: JobStatusName = Field(description=", ".join(JOB_STATUSES))
    points_total: int = Field(description="number of grid points")
    points_done: int = Field(description="points finished successfully (including reused ones)")
    points_failed: int = Field(description="points whose simulation failed")
    points_reused: int = Field(description="points whose result (ok, or failed by the model) "
                                           "was taken from an earlier computation, not "
                                           "computed for this job")
    created_at: str = Field(description="submission time, ISO 8601 UTC")
    started_at: Optional[str] = Field(description="time the runner started the job, ISO 8601 UTC")
    finished_at: Optional[str] = Field(description="time the job ended, ISO 8601 UTC")
    error: Optional[str] = Field(description="why the job failed or was cancelled, else null")
    retry_failed: bool = Field(description="whether points stored as failed by the model are "
                                           "computed again")
    request: dict[str, Any] = Field(description="the sweep as submitted, with defaults filled in")
    links: dict[str, str] = Field(description="URLs of the job, its metrics and its dataset")


class JobList(BaseModel):
    jobs: list[JobInfo] = Field(description="jobs, newest first")
    total: int = Field(description="number of jobs stored")


def _point_record_model() -> type[BaseModel]:
    fields: dict[str, Any] = {
        "index": (int, Field(description="position in C order over E0, IOP, thickness, pmax")),
        "key": (str, Field(description="content key of the point (hash of all its parameters)")),
    }
    for name in SWEPT:
        s = PARAMETERS[name]
        fields[name] = (float, Field(description=f"{s.description} [{_unit_text(s)}]"))
    fields["status"] = (PointStatusName, Field(description=", ".join(POINT_STATUSES)))
    fields["message"] = (Optional[str], Field(description="reason of a failure, else null"))
    fields["reused"] = (bool, Field(description="true if the result was computed earlier "
                                                "(by this or another job) and reused"))
    for name, (unit, long_name) in METRICS.items():
        raw = (f"; the raw reading, not on Goldmann's scale (calibrated: {name}_cal)"
               if name in RAW_READINGS else "")
        fields[name] = (Optional[float], Field(description=f"{long_name} [{unit}]{raw}; null "
                                                            "when missing or not computed",
                                               json_schema_extra={"x-unit": unit}))
    fields["model_version"] = (Optional[str], Field(
        description="model version (hash of the numerical source code) that computed the "
                    "point; null unless the point is ok and its version is known"))
    for name, (unit, long_name) in CALIBRATED.items():
        fields[name] = (Optional[float], Field(
            description=f"{long_name} [{unit}]: on the Goldmann-equivalent scale, the raw "
                        "readings mapped by the instrument's calibration for the point's "
                        "instrument, resolution and model version (docs/calibration.md); null "
                        "when the raw reading is missing or no calibration applies "
                        "(calibration_missing says why)", json_schema_extra={"x-unit": unit}))
    fields["calibration"] = (Optional[str], Field(
        description="the calibration applied to the point's readings (file, instrument, model "
                    "version, resolution); null if none applies"))
    fields["calibration_missing"] = (Optional[str], Field(
        description="why no calibration applies to this ok point (no calibration for its "
                    "instrument, resolution, options or model version), with the `airpuff "
                    "calibrate` command that makes one; null when calibrated or not ok"))
    return create_model("PointRecord", **fields)


PointRecord = _point_record_model()


class Metrics(BaseModel):
    id: str = Field(description="job id")
    status: JobStatusName = Field(description="job status")
    units: dict[str, str] = Field(description="unit of every numeric field of the point records "
                                              "(raw readings and their calibrated `_cal` forms)")
    points: list[PointRecord] = Field(description="one record per grid point, in index order")  # type: ignore[valid-type]


class Health(BaseModel):
    status: Literal["ok"] = Field(description="always ok when the API answers")
    version: str = Field(description="airpuff version")
    runner: str = Field(description="job runner: disabled, starting, connecting, ready, stopped "
                                    "or failed")
    runner_error: Optional[str] = Field(default=None, description="why the runner failed "
                                        "(left out without the token, when one is set)")
    workers: Optional[int] = Field(default=None, description="Dask workers connected (left "
                                   "out without the token, when one is set)")


class ValidationItem(BaseModel):
    loc: list[Any] = Field(description="where the error is, e.g. [\"body\", \"E0\", 1]")
    field: str = Field(description="the offending request field, e.g. \"E0\"")
    msg: str = Field(description="what is wrong and what is accepted, starting with the field")
    type: str = Field(description="error kind")


class ValidationProblem(BaseModel):
    detail: list[ValidationItem]


class Problem(BaseModel):
    detail: str = Field(description="what went wrong")


class QueueProblem(BaseModel):
    detail: str = Field(description="the points waiting, this job's and the limits")
    limits: dict[str, int] = Field(description="max_pending_points, max_pending_per_client, "
                                               "pending (of the limit hit) and asked")


def units() -> dict[str, str]:
    u = {name: PARAMETERS[name].unit for name in SWEPT}
    u.update({name: unit for name, (unit, _) in METRICS.items()})
    u.update({name: unit for name, (unit, _) in CALIBRATED.items()})
    return u


# -- POST /identify -------------------------------------------------------------------------------

class MeasuredValue(BaseModel):
    model_config = ConfigDict(extra="forbid")
    value: Annotated[float, Strict(), Field(allow_inf_nan=False, ge=-1e6, le=1e6)] = Field(
        description="measured value in the metric's unit (" + ", ".join(
            f"{name} {UNITS[name]}" for name in MEASURABLE) + ")")
    sigma: Optional[Annotated[float, Strict(), Field(allow_inf_nan=False, ge=SIGMA_RANGE[0],
                                                     le=SIGMA_RANGE[1])]] = Field(
        default=None, description="1-sigma uncertainty in the same unit; default " + ", ".join(
            f"{DEFAULT_SIGMA[name]:g} {UNITS[name]} ({name})" for name in MEASURABLE))


# Any subset of the measurable quantities of sweep.identification, each optional.
Measurement = create_model(
    "Measurement", __config__=ConfigDict(extra="forbid"),
    **{name: (Optional[MeasuredValue], Field(default=None,
                                             description=f"{(METRICS | CALIBRATED)[name][1]} "
                                                         f"[{UNITS[name]}]"))
       for name in MEASURABLE})


class IdentifyRequest(BaseModel):
    """Estimate IOP and E0 from a measurement by interpolation on a finished sweep job."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{
        "job_id": "0123456789abcdef0123456789abcdef", "thickness": 0.5, "pmax": 10.0,
        "measurement": {"P1": {"value": 17.5, "sigma": 0.5}, "DA": {"value": 1.0}}}]})
    job_id: Annotated[str, Strict(), Field(min_length=1, max_length=64)] = Field(
        description="id of a finished sweep job (POST /sweeps)")
    thickness: Optional[_number(PARAMETERS["thickness"])] = Field(  # type: ignore[valid-type]
        default=None, description="corneal thickness [mm]; needed if the sweep has several; "
                                  "between two grid values the metrics are interpolated linearly")
    pmax: Optional[_number(PARAMETERS["pmax"])] = Field(  # type: ignore[valid-type]
        default=None, description="peak jet pressure [kPa]; needed if the sweep has several")
    instrument: Optional[Literal[CHOICES["instrument"]]] = Field(  # type: ignore[valid-type]
        default=None, description="the instrument the measurement was taken with: it must be the "
                                  "one whose pulse the job was computed with (default: the job's)")
    measurement: Measurement = Field(  # type: ignore[valid-type]
        description="any non-empty subset of " + ", ".join(MEASURABLE) + ", with the pressures "
                    "on one scale: the raw P1, P2 or at most two of the calibrated P1_cal, "
                    "P2_cal, IOPg_cal, CH_cal (those need the job's points to have a calibration; "
                    "the result's `scale` says which was used)")
    refine: Annotated[bool, Strict()] = Field(
        default=False, description="must be false: refinement with solver runs is only offered "
                                   "by `airpuff identify --refine`")


class IdentifyResult(BaseModel):
    model_config = ConfigDict(extra="allow")
    job_id: str = Field(description="the sweep job used")
    IOP: float = Field(description="estimated IOP [mmHg]")
    E0: float = Field(description="estimated E0 [MPa]")
    IOP_interval: list[float] = Field(description="IOP extent of the 68 % region [mmHg]")
    E0_interval: list[float] = Field(description="E0 extent of the 68 % region [MPa]")
    IOP_identified: bool = Field(description="false if the IOP interval spans the whole sweep")
    E0_identified: bool = Field(description="false if the E0 interval spans the whole sweep")
    chi2_min: float = Field(description="chi^2 at the estimate")
    scale: str = Field(description="the scale of the measured pressures: `raw: ...` (P1, P2 "
                                   "against the sweep's raw readings) or `calibrated: ...` "
                                   "(P1_cal, P2_cal, IOPg_cal, CH_cal against the sweep's "
                                   "Goldmann-equivalent readings)")
    notes: list[str] = Field(description="caveats (unidentified parameter, failed points, ...)")
