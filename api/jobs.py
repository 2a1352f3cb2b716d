"""Sweep jobs as the API and the pages see them: create, read, cancel, remove.

The one place where a request becomes a stored job (``create_job``: the grid validated as a whole
by ``SweepSpec.validated_points``, each point's key computed once) and where a job's rows become
what clients read (``job_info``, ``point_records``).  The JSON routes (``api.routes``) and the
browser pages (``api.pages``) both call these functions; the job runner (``api.runner``) does the
work.  Every SQL statement is ``api.db``'s.
"""

from __future__ import annotations

import json
import math
import shutil
import sqlite3
import uuid
from typing import Any, Iterator

from fastapi import Request
from fastapi.exceptions import RequestValidationError

from airpuff_core.calibration import (Calibration, apply_coefficients, find_calibration,
                                      load_calibrations, nan_readings)
from airpuff_core.params import SWEPT, ParameterError
from airpuff_core.provenance import model_version
from airpuff_core.result import METRICS
from sweep.grid import GRID_FIELD, SweepSpec, check_grid_size
from sweep.storage import point_key

from . import db
from .settings import Settings
from .status import ACTIVE_JOB_STATUSES


class JobEnded(Exception):
    """A job ended (done, failed) while it was being cancelled."""


def problem_422(loc: list, field: str, msg: str,
                typ: str = "value_error") -> RequestValidationError:
    """A 422 whose detail names the offending ``field`` (rendered by ``api.app``)."""
    return RequestValidationError([{"loc": loc, "field": field, "msg": msg, "type": typ}])


def get_db(request: Request) -> Iterator[sqlite3.Connection]:
    """A connection to the job database for the length of one request (a FastAPI dependency)."""
    con = db.connect(request.app.state.settings.db_path)
    try:
        yield con
    finally:
        con.close()


class QueueFull(Exception):
    """A job refused because too many points wait: ``status_code`` 429 (this client's limit)
    or 503 (the server's); ``str()`` says the counts and the limits."""

    def __init__(self, err: db.PendingLimit, settings: Settings):
        self.status_code = 429 if err.scope == "client" else 503
        self.limits = {"max_pending_points": settings.max_pending_points,
                       "max_pending_per_client": settings.max_pending_per_client,
                       "pending": err.pending, "asked": err.asked}
        whose = "from this client" if err.scope == "client" else "in all"
        option = "--max-pending-per-client" if err.scope == "client" else "--max-pending-points"
        super().__init__(
            f"too many points waiting: {err.pending} {whose} and this job asks for {err.asked}; "
            f"the limit is {err.limit} ({option}; per client "
            f"{settings.max_pending_per_client}, in all {settings.max_pending_points}); retry "
            "when earlier jobs have progressed, or cancel some")


def create_job(con: sqlite3.Connection, settings: Settings, values: dict[str, Any],
               owner: str | None = None) -> tuple[str, int]:
    """Store a queued job for the request ``values`` (a ``SweepRequest`` validated by the schema,
    as a dict) of the client ``owner`` (its address); returns (job id, number of points).
    Raises a 422 if the grid is larger than ``settings.max_points`` or the solver rejects a
    combination of parameters, ``QueueFull`` if the points waiting would exceed
    ``settings.max_pending_points`` or, for this owner, ``settings.max_pending_per_client``."""
    values = dict(values)
    retry_failed = values.pop("retry_failed", False)
    axes = {name: values.pop(name) for name in SWEPT}
    try:
        check_grid_size({name: len(axes[name]) for name in SWEPT}, settings.max_points)
    except ParameterError as err:
        raise problem_422(["body"], GRID_FIELD, str(err), "grid_too_large") from None
    try:
        spec = SweepSpec(**axes, options=values)
        points = spec.validated_points()
    except ParameterError as err:
        raise problem_422(["body", err.name], err.name, str(err)) from None
    job_id = uuid.uuid4().hex
    rows = [(point_key(p), p.E0, p.IOP, p.thickness, p.pmax) for p in points]
    try:
        db.insert_job(con, job_id, spec.to_dict(), rows, retry_failed, owner,
                      settings.max_pending_points, settings.max_pending_per_client)
    except db.PendingLimit as err:
        raise QueueFull(err, settings) from None
    return job_id, len(rows)


def job_info(row: sqlite3.Row) -> dict[str, Any]:
    """A job row as ``GET /sweeps/{id}`` reports it (``schemas.JobInfo``)."""
    spec = json.loads(row["spec_json"])
    request = {name: spec[name] for name in SWEPT}
    request.update(spec.get("options", {}))
    base = f"/sweeps/{row['id']}"
    return {
        "id": row["id"], "status": row["status"], "points_total": row["n_points"],
        "points_done": row["n_ok"], "points_failed": row["n_failed"],
        "points_reused": row["n_reused"],
        "created_at": db.iso(row["created_at"]), "started_at": db.iso(row["started_at"]),
        "finished_at": db.iso(row["finished_at"]), "error": row["error"],
        "retry_failed": bool(row["retry_failed"]), "request": request,
        "links": {"self": base, "metrics": base + "/metrics", "dataset": base + "/dataset"},
    }


def point_records(con: sqlite3.Connection, job: sqlite3.Row) -> list[dict[str, Any]]:
    """The points of the job row ``job`` as ``GET /sweeps/{id}/metrics`` reports them
    (``schemas.PointRecord``): index, key, the four swept values, status, message, reused, every
    raw metric (None where missing), the model version that computed the point, and the
    calibrated readings beside the raw ones (``calibrated_readings``).  The pages show the same
    records; ``POST /identify`` interpolates in them."""
    spec = SweepSpec.from_dict(json.loads(job["spec_json"]), validate=False)
    points = []
    for p in db.job_points(con, job["id"]):
        rec: dict[str, Any] = {"index": p["idx"], "key": p["key"]}
        for name in SWEPT:
            rec[name] = p[name]
        rec["status"] = p["status"]
        rec["message"] = p["message"]
        rec["reused"] = bool(p["reused"])
        ok = p["status"] == "ok"
        m = db.loads(p["metrics_json"]) if ok else None
        for name in METRICS:
            rec[name] = (m or {}).get(name)
        rec["model_version"] = (p["model_version"] or _version_from_key(spec, p["idx"], p["key"])
                                if ok else None)
        points.append(rec)
    calibrated_readings(spec, points)
    return points


def _version_from_key(spec: SweepSpec, index: int, key: str) -> str | None:
    """The model version of a point whose row does not record it (stored before schema version
    5): this server's if the point's key is the one this version gives its parameters (the key
    hashes the parameters and the model version, ``sweep.storage.point_key``), else unknown."""
    try:
        return model_version() if point_key(spec.point(index)) == key else None
    except ParameterError:  # a stored job's parameters this version no longer takes
        return None


def calibrated_readings(spec: SweepSpec, records: list[dict[str, Any]]) -> None:
    """Add to each point record the calibrated readings ``<name>_cal`` of
    ``airpuff_core.calibration.CALIBRATED`` (None where missing), ``calibration`` (the
    calibration applied, or None) and ``calibration_missing`` (why none applies to an ok point:
    the core's reason, naming the ``airpuff calibrate`` command that makes one; else None).

    As in the combined netCDF (``sweep.combine``), they are computed now from the raw P1 and P2
    with this installation's calibrations, for the model version that computed the point; the
    points of a job share every option but the eye's (one calibration) and pmax (the pulse: one
    calibration each), so one look-up per (pmax, model version)."""
    calibrations = load_calibrations()
    found: dict[tuple[float, str | None], tuple[Calibration | None, str]] = {}
    for rec in records:
        cal, reason = None, ""
        values = nan_readings()
        if rec["status"] == "ok":
            version = rec["model_version"]
            group = (rec["pmax"], version)
            if group not in found:
                found[group] = _look_up(spec, rec["index"], version, calibrations)
            cal, reason = found[group]
            if cal is not None:
                values = apply_coefficients(cal.coefficients(), _nan(rec["P1"]), _nan(rec["P2"]))
        for name, value in values.items():
            rec[name] = value if math.isfinite(value) else None
        rec["calibration"] = cal.label if cal is not None else None
        rec["calibration_missing"] = reason or None


def _look_up(spec: SweepSpec, index: int, version: str | None,
             calibrations: list[Calibration]) -> tuple[Calibration | None, str]:
    """``find_calibration`` for the point at ``index`` computed by model version ``version``."""
    if not version:
        return None, ("the job database does not record the model version that computed this "
                      f"point, which is not this server's ({model_version()}): no calibration is "
                      "applied (the job's netCDF dataset names the point's model version)")
    try:
        params = spec.point(index).to_dict()
    except ParameterError as err:
        return None, f"this server cannot read the point's parameters: {err}"
    return find_calibration(params, version, calibrations)


def _nan(value: float | None) -> float:
    return math.nan if value is None else value


def cancel_or_remove(con: sqlite3.Connection, settings: Settings, row: sqlite3.Row) -> bool:
    """Cancel a queued or running job (True), or remove an ended one with its folder and its
    combined dataset (False; the point files stay: they are shared by all jobs).  Raises
    ``JobEnded`` if the job ended while it was being cancelled, ``KeyError`` if it was removed
    meanwhile."""
    if row["status"] in ACTIVE_JOB_STATUSES:
        if db.cancel_job(con, row["id"]):
            return True
        raise JobEnded(row["id"])
    if not db.delete_job(con, row["id"]):  # removed by a DELETE at the same moment
        raise KeyError(row["id"])
    # The folder comes from the job's own id as stored in the database, never from the request.
    shutil.rmtree(settings.jobs_dir / row["id"], ignore_errors=True)
    return False
