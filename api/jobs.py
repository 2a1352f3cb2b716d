"""Jobs as the API and the pages show them: create a job from a validated request, describe a job
and its points.  Both ``api.app`` (JSON) and ``api.pages`` (HTML) call these, so a job reads the
same in both."""

from __future__ import annotations

import json
import sqlite3
import uuid
from typing import Any

from fastapi.exceptions import RequestValidationError

from airpuff_core.params import SWEPT, ParameterError
from airpuff_core.result import METRICS

from . import db
from .settings import Settings


def problem_422(loc: list, field: str, msg: str, typ: str = "value_error") -> RequestValidationError:
    """A 422 whose one entry is complete already (``msg`` names the field and what is accepted)."""
    return RequestValidationError([{"loc": loc, "field": field, "msg": msg, "type": typ}])


def create_job(con: sqlite3.Connection, settings: Settings, values: dict[str, Any]) -> tuple[str, int]:
    """Store a queued job for the request ``values`` (a ``SweepRequest`` already validated by the
    schema, as a dict); returns (job id, number of points).  Raises a 422 if the grid is larger
    than ``settings.max_points`` or the solver rejects a combination of parameters."""
    from sweep.grid import SweepSpec
    from sweep.store import point_key

    values = dict(values)
    axes = {name: values.pop(name) for name in SWEPT}
    n = 1
    for name in SWEPT:
        n *= len(axes[name])
    if n > settings.max_points:
        shape = " x ".join(str(len(axes[k])) for k in SWEPT)
        raise problem_422(
            ["body"], "E0 x IOP x thickness x pmax",
            f"E0 x IOP x thickness x pmax: the grid has {shape} = {n} points; "
            f"accepted: at most {settings.max_points} points", "grid_too_large")
    try:
        spec = SweepSpec(**axes, options=values).validate()
        points = spec.points()
    except ParameterError as err:
        raise problem_422(["body", err.name], err.name, str(err)) from None
    job_id = uuid.uuid4().hex
    rows = [(point_key(p), p.E0, p.IOP, p.thickness, p.pmax) for p in points]
    db.insert_job(con, job_id, spec.to_dict(), rows)
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
        "request": request,
        "links": {"self": base, "metrics": base + "/metrics", "dataset": base + "/dataset"},
    }


def point_records(con: sqlite3.Connection, job_id: str) -> list[dict[str, Any]]:
    """The points of a job as ``GET /sweeps/{id}/metrics`` reports them (``schemas.PointRecord``):
    index, key, the four swept values, status, message, reused and every metric (None where
    missing)."""
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
