"""Sweep jobs as the API and the pages see them: create, read, cancel, remove.

The one place where a request becomes a stored job (``create_job``: the grid validated as a whole
by ``SweepSpec.validated_points``, each point's key computed once) and where a job's rows become
what clients read (``job_info``, ``point_records``).  The JSON routes (``api.routes``) and the
browser pages (``api.pages``) both call these functions; the job runner (``api.runner``) does the
work.  Every SQL statement is ``api.db``'s.
"""

from __future__ import annotations

import json
import shutil
import sqlite3
import uuid
from typing import Any, Iterator

from fastapi import Request
from fastapi.exceptions import RequestValidationError

from airpuff_core.params import SWEPT, ParameterError
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


def point_records(con: sqlite3.Connection, job_id: str) -> list[dict[str, Any]]:
    """The points of a job as ``GET /sweeps/{id}/metrics`` reports them (``schemas.PointRecord``):
    index, key, the four swept values, status, message, reused and every metric (None where
    missing).  The pages show the same records; ``POST /identify`` interpolates in them."""
    points = []
    for p in db.job_points(con, job_id):
        rec: dict[str, Any] = {"index": p["idx"], "key": p["key"]}
        for name in SWEPT:
            rec[name] = p[name]
        rec["status"] = p["status"]
        rec["message"] = p["message"]
        rec["reused"] = bool(p["reused"])
        m = db.loads(p["metrics_json"]) if p["status"] == "ok" else None
        for name in METRICS:
            rec[name] = (m or {}).get(name)
        points.append(rec)
    return points


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
