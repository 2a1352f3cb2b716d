"""The FastAPI application: validate, persist the job, report status and metrics, serve netCDF.

Long work never runs here.  ``POST /sweeps`` writes a job row (and its grid) to SQLite and answers
202 with a Location; the job runner (``api.runner``, a thread that owns the Dask client) picks the
job up.  Every other endpoint only reads the database, or serves the job's combined netCDF file as
it lies on disk; the API process never opens a netCDF file itself (netCDF4 is not thread-safe and
only the runner thread uses it).
"""


import json
import logging
import sqlite3
from contextlib import asynccontextmanager
from typing import Iterator, Optional

from fastapi import Depends, FastAPI, HTTPException, Query, Request, Response, status
from fastapi.encoders import jsonable_encoder
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.exceptions import HTTPException as StarletteHTTPException

from airpuff_core import __version__
from airpuff_core.params import PARAMETERS, SWEPT

from . import auth, db, jobs, pages, schemas
from .jobs import problem_422 as _problem_422
from .settings import Settings

log = logging.getLogger("airpuff.api")

JOB_STATUSES = ("queued", "running", "done", "failed", "cancelled")


# -- validation errors --------------------------------------------------------------------------

def _field_name(loc: list) -> str:
    """``["body", "E0", 1]`` -> ``"E0[1]"``; ``["query", "limit"]`` -> ``"limit"``."""
    parts = [p for p in loc[1:]] if loc and loc[0] in ("body", "query", "path", "header") else loc
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or (str(loc[0]) if loc else "request")


def _describe(err: dict) -> dict:
    """A validation error whose message names the field and, for parameters, the accepted range."""
    if "field" in err:  # raised by this module, already complete
        return {k: err[k] for k in ("loc", "field", "msg", "type")}
    loc = list(err.get("loc", ()))
    field = _field_name(loc)
    msg = str(err.get("msg", "invalid value"))
    typ = str(err.get("type", "value_error"))
    top = loc[1] if len(loc) > 1 and loc[0] == "body" else None
    if typ == "extra_forbidden":
        msg = "unknown parameter; accepted keys are " + ", ".join(_request_keys())
    elif isinstance(top, str) and top in PARAMETERS and typ not in ("list_type", "too_short",
                                                                    "too_long", "missing"):
        msg = f"{msg}; accepted: {PARAMETERS[top].accepted()}"
    return {"loc": loc, "field": top if isinstance(top, str) else field,
            "msg": f"{field}: {msg}", "type": typ}


_REQUEST_KEYS: list[str] = []


def _request_keys() -> list[str]:
    return _REQUEST_KEYS


# -- auth -----------------------------------------------------------------------------------------

def _auth_dependency(settings: Settings):
    if not settings.token:
        return None
    bearer = HTTPBearer(auto_error=False, description="the value of AIRPUFF_API_TOKEN")
    token = settings.token

    def require_token(request: Request,
                      cred: Optional[HTTPAuthorizationCredentials] = Depends(bearer)) -> None:
        ok = cred is not None and cred.scheme.lower() == "bearer" and auth.token_matches(
            cred.credentials, token)
        # The pages' session cookie opens the read-only endpoints (their links and the progress
        # refresh); changing state through the API needs the bearer header (see api.auth).
        ok = ok or (request.method in auth.SAFE_METHODS and auth.session_ok(request, token))
        if not ok:
            raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing or wrong bearer token",
                                headers={"WWW-Authenticate": "Bearer"})

    return Depends(require_token)


# -- body size limit (plain ASGI middleware) -----------------------------------------------------

class BodyLimit:
    """Refuse request bodies above ``limit`` bytes with 413 before anything parses them."""

    def __init__(self, app, limit: int):
        self.app, self.limit = app, limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        length = dict(scope.get("headers") or []).get(b"content-length")
        too_big = False
        if length is not None:
            try:
                too_big = int(length) > self.limit
            except ValueError:
                too_big = True
        if too_big:
            resp = JSONResponse({"detail": f"request body above {self.limit} bytes"}, 413)
            return await resp(scope, receive, send)
        received = 0

        async def limited_receive():
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.limit:
                    raise HTTPException(413, f"request body above {self.limit} bytes")
            return message

        return await self.app(scope, limited_receive, send)


# -- the app --------------------------------------------------------------------------------------

def create_app(settings: Settings) -> FastAPI:
    """The API for ``settings.data_dir``.  With ``settings.run_jobs`` its lifespan also starts and
    stops the job runner (a thread owning the Dask client)."""
    SweepRequest = schemas.sweep_request_model(settings.max_points)
    _REQUEST_KEYS[:] = list(SweepRequest.model_fields)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        db.init(settings.db_path)
        settings.points_dir.mkdir(parents=True, exist_ok=True)
        settings.jobs_dir.mkdir(parents=True, exist_ok=True)
        runner = None
        if settings.run_jobs:
            from .runner import Runner

            runner = Runner(settings)
            runner.start()
        app.state.runner = runner
        try:
            yield
        finally:
            if runner is not None:
                import anyio

                await anyio.to_thread.run_sync(runner.stop)

    auth = _auth_dependency(settings)
    deps = [auth] if auth is not None else []
    app = FastAPI(
        title="airpuff",
        version=__version__,
        summary="Parameter sweeps of the corneal air-puff simulation (ORA / Corvis metrics).",
        description=(
            "Submit a sweep over E0 [MPa] x IOP [mmHg] x thickness [mm] x pmax [kPa]; the job runs "
            "on a Dask cluster. Follow it at /sweeps/{id}, read its metrics at "
            "/sweeps/{id}/metrics and download the combined netCDF at /sweeps/{id}/dataset. "
            "Units and accepted ranges of every parameter are given in the request schema. "
            + ("Every endpoint except /health needs `Authorization: Bearer <token>`."
               if settings.token else "")),
        lifespan=lifespan, openapi_url=None, docs_url=None, redoc_url=None)
    app.state.settings = settings
    app.state.runner = None
    app.add_middleware(BodyLimit, limit=settings.max_body_bytes)

    @app.exception_handler(RequestValidationError)
    async def on_validation_error(request: Request, exc: RequestValidationError):
        return JSONResponse({"detail": jsonable_encoder([_describe(e) for e in exc.errors()])}, 422)

    @app.exception_handler(StarletteHTTPException)
    async def on_http_error(request: Request, exc: StarletteHTTPException):
        if exc.status_code == 400 and request.method == "POST":
            # FastAPI's answer to a body it cannot even decode (e.g. invalid UTF-8): report it
            # like any other invalid body.
            return JSONResponse({"detail": [{"loc": ["body"], "field": "body",
                                             "msg": f"body: {exc.detail}; accepted: a JSON "
                                                    "object in UTF-8", "type": "json_invalid"}]},
                                422)
        return await http_exception_handler(request, exc)

    @app.exception_handler(sqlite3.OperationalError)
    async def on_db_busy(request: Request, exc: sqlite3.OperationalError):
        log.error("database error: %s", exc)
        return JSONResponse({"detail": "the job database is busy; retry shortly"}, 503,
                            headers={"Retry-After": "2"})

    def get_db() -> Iterator[sqlite3.Connection]:
        con = db.connect(settings.db_path)
        try:
            yield con
        finally:
            con.close()

    not_found = {404: {"model": schemas.Problem, "description": "no job with this id"}}
    unauthorized = {401: {"model": schemas.Problem, "description": "missing or wrong token"}} \
        if settings.token else {}
    invalid = {422: {"model": schemas.ValidationProblem,
                     "description": "invalid input; `loc`/`field` name the offending field"}}

    def job_or_404(con, job_id: str) -> sqlite3.Row:
        row = db.get_job(con, job_id)
        if row is None:
            raise HTTPException(404, f"no sweep job with id {job_id!r}")
        return row

    # -- routes ------------------------------------------------------------------------------

    @app.get("/health", response_model=schemas.Health, tags=["service"],
             summary="Liveness of the API and state of the job runner (no token needed)")
    def health(request: Request):
        runner = request.app.state.runner
        if runner is None:
            return {"status": "ok", "version": __version__, "runner": "disabled"}
        return {"status": "ok", "version": __version__, "runner": runner.state,
                "runner_error": runner.error, "workers": runner.n_workers}

    @app.post("/sweeps", status_code=202, response_model=schemas.Submitted, tags=["sweeps"],
              dependencies=deps, responses={**invalid, **unauthorized},
              summary="Submit a sweep; answers 202 with the job id and a Location header")
    def submit(body: SweepRequest, response: Response, request: Request,  # type: ignore[valid-type]
               con: sqlite3.Connection = Depends(get_db)):
        job_id, n_points = jobs.create_job(con, settings, body.model_dump())
        runner = request.app.state.runner
        if runner is not None:
            runner.wake()
        response.headers["Location"] = f"/sweeps/{job_id}"
        return {"id": job_id, "status": "queued", "points_total": n_points}

    @app.get("/sweeps", response_model=schemas.JobList, tags=["sweeps"], dependencies=deps,
             responses={**invalid, **unauthorized}, summary="List jobs, newest first")
    def list_sweeps(limit: int = Query(100, ge=1, le=1000, description="jobs per page"),
                    offset: int = Query(0, ge=0, le=2**62, description="jobs to skip"),
                    status_: Optional[schemas.JobStatusName] = Query(
                        None, alias="status", description="only jobs with this status"),
                    con: sqlite3.Connection = Depends(get_db)):
        rows = db.list_jobs(con, limit, offset, status_)
        return {"jobs": [jobs.job_info(r) for r in rows], "total": db.count_jobs(con, status_)}

    @app.get("/sweeps/{job_id}", response_model=schemas.JobInfo, tags=["sweeps"],
             dependencies=deps, responses={**not_found, **unauthorized},
             summary="Status of a job: points total, done and failed, timestamps, error")
    def get_sweep(job_id: str, con: sqlite3.Connection = Depends(get_db)):
        return jobs.job_info(job_or_404(con, job_id))

    @app.get("/sweeps/{job_id}/metrics", response_model=schemas.Metrics, tags=["sweeps"],
             dependencies=deps, responses={**not_found, **unauthorized},
             summary="ORA and Corvis-style metrics of every point (null where missing)")
    def get_metrics(job_id: str, con: sqlite3.Connection = Depends(get_db)):
        row = job_or_404(con, job_id)
        points = jobs.point_records(con, job_id)
        return {"id": job_id, "status": row["status"], "units": schemas.units(), "points": points}

    @app.get("/sweeps/{job_id}/dataset", tags=["sweeps"], dependencies=deps,
             response_class=FileResponse,
             responses={200: {"content": {"application/x-netcdf": {}},
                              "description": "the combined netCDF of the sweep (CF-1.10)"},
                        409: {"model": schemas.Problem, "description": "the job is not done"},
                        **not_found, **unauthorized},
             summary="Download the combined netCDF of a finished job")
    def get_dataset(job_id: str, con: sqlite3.Connection = Depends(get_db)):
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

    @app.delete("/sweeps/{job_id}", response_model=schemas.JobInfo, tags=["sweeps"],
                dependencies=deps,
                responses={409: {"model": schemas.Problem, "description": "the job already ended"},
                           **not_found, **unauthorized},
                summary="Cancel a queued or running job (points already finished are kept)")
    def cancel(job_id: str, request: Request, con: sqlite3.Connection = Depends(get_db)):
        row = job_or_404(con, job_id)
        if row["status"] in ("queued", "running"):
            db.cancel_job(con, job_id)
            runner = request.app.state.runner
            if runner is not None:
                runner.wake()
            row = job_or_404(con, job_id)
        if row["status"] in ("done", "failed"):
            raise HTTPException(409, f"job {job_id} already ended ({row['status']})")
        return jobs.job_info(row)

    @app.post("/identify", response_model=schemas.IdentifyResult, tags=["identify"],
              dependencies=deps,
              responses={409: {"model": schemas.Problem, "description": "the job is not done"},
                         **not_found, **invalid, **unauthorized},
              summary="Estimate IOP and E0 from a measurement, by interpolation on a finished "
                      "sweep job")
    def identify_endpoint(body: schemas.IdentifyRequest, con: sqlite3.Connection = Depends(get_db)):
        # Interpolation only (milliseconds): the metrics come from the job database, so this
        # handler never opens a netCDF file and never runs the solver.
        from sweep.identify import IdentifyError, SweepTable, identify

        if body.refine:
            raise _problem_422(["body", "refine"], "refine",
                               "refine: solver refinement is not offered over HTTP; accepted: "
                               "false (use `airpuff identify --refine` on the downloaded dataset)")
        row = job_or_404(con, body.job_id)
        if row["status"] != "done":
            raise HTTPException(409, f"job {body.job_id} is {row['status']}; identification "
                                     "needs a finished (done) sweep")
        records = []
        for p in db.job_points(con, body.job_id):
            rec = {name: p[name] for name in SWEPT}
            rec["status"] = p["status"]
            rec.update(db.loads(p["metrics_json"]) or {} if p["status"] == "ok" else {})
            records.append(rec)
        measurement = {k: (v["value"], v["sigma"])
                       for k, v in body.measurement.model_dump().items() if v is not None}
        try:
            table = SweepTable.from_records(json.loads(row["spec_json"]), records)
            est = identify(table, measurement, body.thickness, body.pmax)
        except IdentifyError as err:
            loc = ["body", "measurement", err.field] if err.field in schemas.MEASURABLE_UNITS \
                else ["body", err.field]
            raise _problem_422(loc, err.field, f"{err.field}: {err}",
                               "out_of_range" if "outside" in str(err) else "value_error") from None
        return {"job_id": body.job_id, **est.to_dict()}

    app.include_router(pages.router(settings, _describe))

    # -- schema and docs (behind the token too, when one is set) -------------------------------

    @app.get("/openapi.json", include_in_schema=False, dependencies=deps)
    def openapi_json():
        return JSONResponse(app.openapi())

    @app.get("/docs", include_in_schema=False, dependencies=deps)
    def docs():
        return get_swagger_ui_html(openapi_url="/openapi.json", title="airpuff API")

    return app
