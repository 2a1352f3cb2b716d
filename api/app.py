"""The FastAPI application: settings, lifespan (the job runner), auth, body limit, error format.

The routes are in ``api.routes``, the browser pages in ``api.pages``.

Long work never runs here.  ``POST /sweeps`` writes a job row (and its grid) to SQLite and answers
202 with a Location; the job runner (``api.runner``, a thread that owns the Dask client) picks the
job up.  Every other endpoint only reads the database, or serves the job's combined netCDF file as
it lies on disk; the API process never opens a netCDF file itself (netCDF4 is not thread-safe and
only the runner thread uses it).
"""


import logging
import sqlite3
from contextlib import asynccontextmanager
from typing import Optional

from fastapi import Depends, FastAPI, HTTPException, Request, status
from fastapi.encoders import jsonable_encoder
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.exceptions import HTTPException as StarletteHTTPException

from airpuff_core import __version__
from airpuff_core.params import PARAMETERS

from . import auth, db, pages, routes, schemas
from .settings import Settings

log = logging.getLogger("airpuff.api")

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

    token_dependency = _auth_dependency(settings)
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

    app.include_router(routes.build_router(settings, SweepRequest, token_dependency))
    app.include_router(pages.router(settings, _describe))
    return app
