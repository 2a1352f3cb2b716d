"""The routes of the HTTP API, on one ``APIRouter`` (``api.app`` mounts it).

Every handler only reads the job database (``api.db``), except ``POST /sweeps``, which stores a
new job, and ``DELETE /sweeps/{id}``, which cancels a job or removes an ended one, both through
the jobs layer (``api.jobs``, which the pages use too); the job runner (``api.runner``) does the
work.  The handlers find the service's ``Settings`` and runner on ``request.app.state``.
``POST /sweeps`` validates its body once, at this edge (the request model of ``api.schemas``,
generated from the parameter table, then the grid as a whole by ``SweepSpec.validated_points``), and
computes each point's key once; the rest of the system takes both as given.
"""

# No `from __future__ import annotations`: FastAPI reads the handlers' annotations, and the body
# model of POST /sweeps is a local of make_submit, which a string annotation could not resolve.
import json
import sqlite3
from typing import Optional

from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, JSONResponse

from airpuff_core import __version__
from sweep.identification import MEASURABLE, IdentifyError, SweepTable, identify

from . import auth, db, jobs, schemas
from .jobs import create_job, get_db, job_info, point_records, problem_422
from .settings import Settings


def job_or_404(con, job_id: str) -> sqlite3.Row:
    row = db.get_job(con, job_id)
    if row is None:
        raise HTTPException(404, f"no sweep job with id {job_id!r}")
    return row


# -- routes ---------------------------------------------------------------------------------------

def health(request: Request):
    """Open to all; the runner's error and workers (which may name the scheduler's address)
    only with the token, when one is set."""
    runner = request.app.state.runner
    if runner is None:
        return {"status": "ok", "version": __version__, "runner": "disabled"}
    token = request.app.state.settings.token
    if token and not (auth.bearer_ok(request, token) or auth.session_ok(request, token)):
        return {"status": "ok", "version": __version__, "runner": runner.state}
    return {"status": "ok", "version": __version__, "runner": runner.state,
            "runner_error": runner.error, "workers": runner.n_workers}


def make_submit(SweepRequest):  # noqa: N803 - a model class
    """The handler of ``POST /sweeps`` for the body model ``SweepRequest``."""

    def submit(body: SweepRequest, response: Response, request: Request,  # type: ignore[valid-type]
               con: sqlite3.Connection = Depends(get_db)):
        owner = request.client.host if request.client else None
        try:
            job_id, n_points = create_job(con, request.app.state.settings, body.model_dump(),
                                          owner)
        except jobs.QueueFull as err:
            return JSONResponse({"detail": str(err), "limits": err.limits}, err.status_code,
                                headers={"Retry-After": "30"})
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


def get_metrics(job_id: str, con: sqlite3.Connection = Depends(get_db)):
    row = job_or_404(con, job_id)
    return {"id": job_id, "status": row["status"], "units": schemas.units(),
            "points": point_records(con, row)}


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
    cancelled) is removed with its folder, its combined dataset (204)."""
    row = job_or_404(con, job_id)
    try:
        cancelled = jobs.cancel_or_remove(con, request.app.state.settings, row)
    except jobs.JobEnded:
        raise HTTPException(409, f"job {job_id} ended ({job_or_404(con, job_id)['status']}) "
                                 "while it was being cancelled; DELETE it again to remove "
                                 "it") from None
    except KeyError:
        raise HTTPException(404, f"no sweep job with id {job_id!r}") from None
    if not cancelled:
        return Response(status_code=204)
    runner = request.app.state.runner
    if runner is not None:
        runner.wake()
    return job_info(job_or_404(con, job_id))


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
                                        point_records(con, row))
        est = identify(table, measurement, body.thickness, body.pmax, body.instrument)
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
        response_model_exclude_unset=True,
        summary="Liveness of the API and state of the job runner (no token needed; its error "
                "and workers only with the token, when one is set)")
    add("/sweeps", make_submit(SweepRequest), methods=["POST"], status_code=202,
        response_model=schemas.Submitted, tags=["sweeps"], dependencies=deps,
        responses={**invalid, **unauthorized,
                   429: {"model": schemas.QueueProblem,
                         "description": "this client has too many points waiting"},
                   503: {"model": schemas.QueueProblem,
                         "description": "the server has too many points waiting"}},
        summary="Submit a sweep; answers 202 with the job id and a Location header")
    add("/sweeps", list_sweeps, methods=["GET"], response_model=schemas.JobList, tags=["sweeps"],
        dependencies=deps, responses={**invalid, **unauthorized},
        summary="List jobs, newest first")
    add("/sweeps/{job_id}", get_sweep, methods=["GET"], response_model=schemas.JobInfo,
        tags=["sweeps"], dependencies=deps, responses={**not_found, **unauthorized},
        summary="Status of a job: points total, done and failed, timestamps, error")
    add("/sweeps/{job_id}/metrics", get_metrics, methods=["GET"], response_model=schemas.Metrics,
        tags=["sweeps"], dependencies=deps, responses={**not_found, **unauthorized},
        summary="ORA and Corvis-style metrics of every point, the raw readings (P1, IOPg, ...) "
                "beside their Goldmann-equivalent calibrated forms (P1_cal, IOPg_cal, ...; null "
                "where missing, calibration_missing says why)")
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
