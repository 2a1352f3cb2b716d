"""The routes of the HTTP API, on one ``APIRouter`` (``api.app`` mounts it).

Every handler only reads the job database (``api.db``), except ``POST /sweeps``, which stores a
new job, and ``DELETE /sweeps/{id}``, which cancels a job or removes an ended one; the job runner (``api.runner``)
does the work.  The handlers find the service's ``Settings`` and runner on ``request.app.state``.
``POST /sweeps`` validates its body once, at this edge (the request model of ``api.schemas``,
generated from the parameter table, then the grid as a whole by ``SweepSpec.validated_points``), and
computes each point's key once; the rest of the system takes both as given.
"""

# No `from __future__ import annotations`: FastAPI reads the handlers' annotations, and the body
# model of POST /sweeps is a local of make_submit, which a string annotation could not resolve.
import json
import shutil
import sqlite3
import uuid
from typing import Any, Iterator, Optional

from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, JSONResponse

from airpuff_core import __version__
from airpuff_core.params import SWEPT, ParameterError
from airpuff_core.result import METRICS
from sweep.grid import GRID_FIELD, SweepSpec, check_grid_size
from sweep.identification import MEASURABLE, IdentifyError, SweepTable, identify
from sweep.storage import point_key

from . import db, schemas
from .settings import Settings
from .status import ACTIVE_JOB_STATUSES


def problem_422(loc: list, field: str, msg: str,
                typ: str = "value_error") -> RequestValidationError:
    """A 422 whose detail names the offending ``field`` (rendered by ``api.app``)."""
    return RequestValidationError([{"loc": loc, "field": field, "msg": msg, "type": typ}])


def get_db(request: Request) -> Iterator[sqlite3.Connection]:
    """A connection to the job database for the length of one request."""
    con = db.connect(request.app.state.settings.db_path)
    try:
        yield con
    finally:
        con.close()


def job_or_404(con, job_id: str) -> sqlite3.Row:
    row = db.get_job(con, job_id)
    if row is None:
        raise HTTPException(404, f"no sweep job with id {job_id!r}")
    return row


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


# -- routes ---------------------------------------------------------------------------------------

def health(request: Request):
    runner = request.app.state.runner
    if runner is None:
        return {"status": "ok", "version": __version__, "runner": "disabled"}
    return {"status": "ok", "version": __version__, "runner": runner.state,
            "runner_error": runner.error, "workers": runner.n_workers}


def create_job(con: sqlite3.Connection, settings: Settings,
               values: dict[str, Any]) -> tuple[str, int]:
    """Store a queued job for the request ``values`` (a ``SweepRequest`` validated by the schema,
    as a dict); returns (job id, number of points).  Raises a 422 if the grid is larger than
    ``settings.max_points`` or the solver rejects a combination of parameters.  ``POST /sweeps``
    and the pages' sweep form (``api.pages``) both submit through here."""
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
    db.insert_job(con, job_id, spec.to_dict(), rows, retry_failed)
    return job_id, len(rows)


def make_submit(SweepRequest):  # noqa: N803 - a model class
    """The handler of ``POST /sweeps`` for the body model ``SweepRequest``."""

    def submit(body: SweepRequest, response: Response, request: Request,  # type: ignore[valid-type]
               con: sqlite3.Connection = Depends(get_db)):
        job_id, n_points = create_job(con, request.app.state.settings, body.model_dump())
        runner = request.app.state.runner
        if runner is not None:
            runner.wake()
        response.headers["Location"] = f"/sweeps/{job_id}"
        return {"id": job_id, "status": "queued", "points_total": n_points}

    return submit


def list_sweeps(limit: int = Query(100, ge=1, le=1000, description="jobs per page"),
                offset: int = Query(0, ge=0, le=2**62, description="jobs to skip"),
                status_: Optional[schemas.JobStatusName] = Query(
                    None, alias="status", description="only jobs with this status"),
                con: sqlite3.Connection = Depends(get_db)):
    rows = db.list_jobs(con, limit, offset, status_)
    return {"jobs": [job_info(r) for r in rows], "total": db.count_jobs(con, status_)}


def get_sweep(job_id: str, con: sqlite3.Connection = Depends(get_db)):
    return job_info(job_or_404(con, job_id))


def point_records(con: sqlite3.Connection, job_id: str) -> list[dict[str, Any]]:
    """The points of a job as ``GET /sweeps/{id}/metrics`` reports them (``schemas.PointRecord``):
    index, key, the four swept values, status, message, reused and every metric (None where
    missing).  The pages (``api.pages``) show the same records; ``POST /identify``
    interpolates in them."""
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


def get_metrics(job_id: str, con: sqlite3.Connection = Depends(get_db)):
    row = job_or_404(con, job_id)
    return {"id": job_id, "status": row["status"], "units": schemas.units(),
            "points": point_records(con, job_id)}


def get_dataset(job_id: str, request: Request, con: sqlite3.Connection = Depends(get_db)):
    settings = request.app.state.settings
    row = job_or_404(con, job_id)
    if row["status"] != "done":
        raise HTTPException(409, f"job {job_id} is {row['status']}; its dataset exists once "
                                 "it is done")
    # The path comes from the job's own id as stored in the database, never from the request,
    # and must lie inside this job's folder.
    path = settings.job_dataset(row["id"]).resolve()
    job_dir = (settings.jobs_dir / row["id"]).resolve()
    if job_dir not in path.parents or not path.is_file():
        raise HTTPException(404, f"the dataset of job {job_id} is missing on the server")
    return FileResponse(path, media_type="application/x-netcdf",
                        filename=f"airpuff-sweep-{row['id']}.nc")


def cancel_or_delete(job_id: str, request: Request, con: sqlite3.Connection = Depends(get_db)):
    """A queued or running job is cancelled (200, the job); an ended one (done, failed,
    cancelled) is removed with its folder, its combined dataset (204).  The point files stay:
    they are shared by all jobs."""
    settings = request.app.state.settings
    row = job_or_404(con, job_id)
    if row["status"] in ACTIVE_JOB_STATUSES:
        cancelled = db.cancel_job(con, job_id)
        runner = request.app.state.runner
        if runner is not None:
            runner.wake()
        row = job_or_404(con, job_id)
        if cancelled:
            return job_info(row)
        raise HTTPException(409, f"job {job_id} ended ({row['status']}) while it was being "
                                 "cancelled; DELETE it again to remove it")
    if not db.delete_job(con, row["id"]):  # removed by a DELETE at the same moment
        raise HTTPException(404, f"no sweep job with id {job_id!r}")
    # The folder comes from the job's own id as stored in the database, never from the request.
    shutil.rmtree(settings.jobs_dir / row["id"], ignore_errors=True)
    return Response(status_code=204)


def identify_endpoint(body: schemas.IdentifyRequest, con: sqlite3.Connection = Depends(get_db)):
    # Interpolation only (milliseconds): the metrics come from the job database, so this
    # handler never opens a netCDF file and never runs the solver.
    if body.refine:
        raise problem_422(["body", "refine"], "refine",
                          "refine: solver refinement is not offered over HTTP; accepted: "
                          "false (use `airpuff identify --refine` on the downloaded dataset)")
    row = job_or_404(con, body.job_id)
    if row["status"] != "done":
        raise HTTPException(409, f"job {body.job_id} is {row['status']}; identification "
                                 "needs a finished (done) sweep")
    measurement = {k: (v["value"], v["sigma"])
                   for k, v in body.measurement.model_dump().items() if v is not None}
    try:
        table = SweepTable.from_records(json.loads(row["spec_json"]),
                                        point_records(con, body.job_id))
        est = identify(table, measurement, body.thickness, body.pmax)
    except IdentifyError as err:
        loc = ["body", "measurement", err.field] if err.field in MEASURABLE \
            else ["body", err.field]
        raise problem_422(loc, err.field, f"{err.field}: {err}",
                          "out_of_range" if "outside" in str(err) else "value_error") from None
    return {"job_id": body.job_id, **est.to_dict()}


# -- schema and docs (open without the token) -------------------------------------------------------

def openapi_json(request: Request):
    return JSONResponse(request.app.openapi())


def docs():
    return get_swagger_ui_html(openapi_url="/openapi.json", title="airpuff API")


def build_router(settings: Settings, SweepRequest, auth) -> APIRouter:  # noqa: N803 - a model
    """The API's routes for ``settings``: ``SweepRequest`` is the body model of ``POST /sweeps``
    (its list lengths depend on ``settings.max_points``); ``auth`` the token dependency or None."""
    deps = [auth] if auth is not None else []
    router = APIRouter()
    not_found = {404: {"model": schemas.Problem, "description": "no job with this id"}}
    unauthorized = {401: {"model": schemas.Problem, "description": "missing or wrong token"}} \
        if settings.token else {}
    invalid = {422: {"model": schemas.ValidationProblem,
                     "description": "invalid input; `loc`/`field` name the offending field"},
               415: {"model": schemas.ValidationProblem,
                     "description": "the body is not JSON (content-type)"}}

    # Each route: path, handler, method, then how it is documented (/docs, /openapi.json).
    add = router.add_api_route
    add("/health", health, methods=["GET"], response_model=schemas.Health, tags=["service"],
        summary="Liveness of the API and state of the job runner (no token needed)")
    add("/sweeps", make_submit(SweepRequest), methods=["POST"], status_code=202,
        response_model=schemas.Submitted, tags=["sweeps"], dependencies=deps,
        responses={**invalid, **unauthorized},
        summary="Submit a sweep; answers 202 with the job id and a Location header")
    add("/sweeps", list_sweeps, methods=["GET"], response_model=schemas.JobList, tags=["sweeps"],
        dependencies=deps, responses={**invalid, **unauthorized},
        summary="List jobs, newest first")
    add("/sweeps/{job_id}", get_sweep, methods=["GET"], response_model=schemas.JobInfo,
        tags=["sweeps"], dependencies=deps, responses={**not_found, **unauthorized},
        summary="Status of a job: points total, done and failed, timestamps, error")
    add("/sweeps/{job_id}/metrics", get_metrics, methods=["GET"], response_model=schemas.Metrics,
        tags=["sweeps"], dependencies=deps, responses={**not_found, **unauthorized},
        summary="ORA and Corvis-style metrics of every point (null where missing)")
    add("/sweeps/{job_id}/dataset", get_dataset, methods=["GET"], tags=["sweeps"],
        dependencies=deps, response_class=FileResponse,
        responses={200: {"content": {"application/x-netcdf": {}},
                         "description": "the combined netCDF of the sweep (CF-1.10)"},
                   409: {"model": schemas.Problem, "description": "the job is not done"},
                   **not_found, **unauthorized},
        summary="Download the combined netCDF of a finished job")
    add("/sweeps/{job_id}", cancel_or_delete, methods=["DELETE"], response_model=schemas.JobInfo,
        tags=["sweeps"], dependencies=deps,
        responses={204: {"description": "the ended job was removed, with its dataset"},
                   409: {"model": schemas.Problem,
                         "description": "the job ended while it was being cancelled"},
                   **not_found, **unauthorized},
        summary="Cancel a queued or running job (200; points already finished are kept), or "
                "remove an ended one and its dataset (204)")
    add("/identify", identify_endpoint, methods=["POST"], response_model=schemas.IdentifyResult,
        tags=["identify"], dependencies=deps,
        responses={409: {"model": schemas.Problem, "description": "the job is not done"},
                   **not_found, **invalid, **unauthorized},
        summary="Estimate IOP and E0 from a measurement, by interpolation on a finished sweep job")
    # the schema and docs, open without the token (api.app.PUBLIC_PATHS: the docs page loads the
    # schema from the browser, which sends no token)
    add("/openapi.json", openapi_json, methods=["GET"], include_in_schema=False)
    add("/docs", docs, methods=["GET"], include_in_schema=False)
    return router
