"""The FastAPI application: settings, lifespan (the job runner), the checks before any route runs
(Host, token, body size, content type, encoding, unknown keys: ``RequestGuard``), error format.

The routes are in ``api.routes``, the browser pages in ``api.pages``.

Long work never runs here.  ``POST /sweeps`` writes a job row (and its grid) to SQLite and answers
202 with a Location; the job runner (``api.runner``, a thread that owns the Dask client) picks the
job up.  Every other endpoint only reads the database, or serves the job's combined netCDF file as
it lies on disk; the API process never opens a netCDF file itself (netCDF4 is not thread-safe and
only the runner thread uses it).
"""


import json
import logging
import re
import sqlite3
from contextlib import asynccontextmanager

import anyio

from fastapi import Depends, FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from fastapi.security import HTTPBearer
from pydantic import BaseModel, ValidationError
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import compile_path

from airpuff_core import __version__
from airpuff_core.params import PARAMETERS
from airpuff_core.provenance import model_version
from sweep.storage import NO_SPACE, disk_full

from . import auth, corrections, db, pages, routes, schemas
from .hosts import HostAllowList
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


# A 422 lists at most this many errors, then one line saying how many more there are: a body of
# 60,000 unknown keys would otherwise get 60,000 entries (30 MB).
MAX_ERRORS = 20


def validation_problem(errors: list[dict], total: int | None = None) -> JSONResponse:
    """The 422 of a request with ``errors`` (pydantic's or this module's), the first
    ``MAX_ERRORS`` described (``_describe``) and the rest counted: ``total`` errors in all
    (default ``len(errors)``)."""
    total = len(errors) if total is None else total
    detail = [_describe(e) for e in errors[:MAX_ERRORS]]
    if total > len(detail):
        detail.append({"loc": ["body"], "field": "body", "type": "too_many_errors",
                       "msg": f"body: {total - len(detail)} more errors not listed ({total} in "
                              f"all; the first {len(detail)} are above)"})
    return JSONResponse({"detail": jsonable_encoder(detail)}, 422)


def _unknown_key_error(key: str, model: type[BaseModel]) -> dict:
    return {"loc": ["body", key[:80]], "field": key[:80], "type": "extra_forbidden",
            "msg": f"{key[:80]}: unknown parameter; accepted keys are "
                   + ", ".join(model.model_fields)}


def check_json_body(model: type[BaseModel], body: bytes) -> JSONResponse | None:
    """The 422 of a JSON body that ``model`` refuses, or None (the route then parses and
    validates the body itself, and reports malformed JSON with its line and column).

    Unknown top-level keys are refused before pydantic sees the body (it would build one error
    per key).  Run in a worker thread (``RequestGuard``): a body of up to ``max_body_bytes`` can
    take a second to validate, which must not stop the event loop from answering others."""
    try:
        data = json.loads(body)
    except (ValueError, RecursionError):
        return None
    if not isinstance(data, dict):
        return None
    accepted = model.model_fields.keys()  # a property: built once here, not once per key
    unknown = [key for key in data if key not in accepted]
    if unknown:
        return validation_problem([_unknown_key_error(k, model) for k in unknown[:MAX_ERRORS]],
                                  len(unknown))
    try:
        model.model_validate(data)
    except ValidationError as err:
        errors = err.errors(include_url=False)
        return validation_problem([{**e, "loc": ["body", *e["loc"]]} for e in errors],
                                  err.error_count())
    except RecursionError:
        return None
    return None


# -- checks before any route runs (plain ASGI middleware) ---------------------------------------

# Paths open without the token: liveness, and the API's description (/docs loads /openapi.json
# from the browser, which has no way to add a header to that request; the schema holds nothing
# secret -- the routes it describes still need the token).
PUBLIC_PATHS = ("/health", "/docs", "/openapi.json")

# Bodies of these media types are parsed by the API; any other is refused with 415.
JSON_MEDIA = re.compile(r"application/(?:[\w.+-]+\+)?json")

# The body of the pages' forms (a browser's default encoding of a form).
FORM_MEDIA = "application/x-www-form-urlencoded"

# First bytes of JSON in UTF-16 or UTF-32 (byte order marks); any NUL byte gives those away too,
# since JSON in UTF-8 has none.
WIDE_BOMS = (b"\xff\xfe", b"\xfe\xff")


def _problem(status_code: int, field: str, msg: str, typ: str,
             headers: dict | None = None) -> JSONResponse:
    """An error in the format of a 422 (``detail`` a list of ``loc``, ``field``, ``msg``,
    ``type``)."""
    loc = ["header", field] if field in ("content-type", "content-length") else [field]
    return JSONResponse({"detail": [{"loc": loc, "field": field, "msg": msg, "type": typ}]},
                        status_code, headers=headers)


# Sent with every answer: no other site may show the pages in a frame (clickjacking).
SECURITY_HEADERS = ((b"x-frame-options", b"DENY"),
                    (b"content-security-policy", b"frame-ancestors 'none'"),
                    (b"x-content-type-options", b"nosniff"))


class RequestGuard:
    """What is checked before a route or a body parser runs, in this order:

    0. the ``Host`` header, against the allow-list of ``api.hosts`` (DNS rebinding): else 400;
    1. the credentials, when a token is set (every path but ``PUBLIC_PATHS`` and the pages'
       ``pages.OPEN_PATHS``, the login and logout forms, which make their own checks):

       - the API: the bearer token; with ``GET``/``HEAD`` the pages' session cookie will do too
         (their links, images and refresh); else 401;
       - the pages (``pages.is_page``): the session cookie; else a redirect to the login form;

    2. the body size, from Content-Length and as the body arrives: 413;
    3. a body's content type: JSON for the API, ``application/x-www-form-urlencoded`` for the
       pages' forms (``pages.FORM_PATHS``); another one gets 415 naming ``content-type``;
    4. the encoding: a charset other than UTF-8 gets 415, a JSON body in UTF-16/32 422;
    5. a JSON body of a path in ``bodies`` (route path -> its request model): unknown keys, then
       the model, in a worker thread (``check_json_body``): else 422, at most ``MAX_ERRORS`` listed.

    The body is read here (at most ``limit`` bytes, after the credentials) and handed on unchanged.
    The token and cookie comparisons are ``api.auth``'s.  Every answer carries
    ``SECURITY_HEADERS``.
    """

    def __init__(self, app, limit: int, token: str | None, hosts: HostAllowList,
                 bodies: dict[str, type[BaseModel]]):
        self.app, self.limit = app, limit
        self.token = token or None
        self.hosts = hosts
        self.bodies = [(compile_path(path)[0], model) for path, model in bodies.items()]

    def _body_model(self, scope) -> type[BaseModel] | None:
        """The request model of a POST to this path, if it has one in ``bodies``."""
        if scope["method"] != "POST":
            return None
        return next((model for regex, model in self.bodies if regex.match(scope["path"])), None)

    def _refusal(self, scope) -> Response | None:
        """The answer to a request without the credentials its path needs; None if it may go on."""
        path = scope["path"]
        if self.token is None or path in PUBLIC_PATHS or path in pages.OPEN_PATHS:
            return None
        request = Request(scope)  # headers and cookies only: the body is not read
        if pages.is_page(path):
            return None if auth.session_ok(request, self.token) else pages.login_redirect(request)
        if auth.bearer_ok(request, self.token) or (scope["method"] in auth.SAFE_METHODS
                                                and auth.session_ok(request, self.token)):
            return None
        return JSONResponse({"detail": "missing or wrong bearer token"}, 401,
                            headers={"WWW-Authenticate": "Bearer"})

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", ()),
                                                   *SECURITY_HEADERS]}
            await send(message)

        return await self._guard(scope, receive, send_with_headers)

    async def _guard(self, scope, receive, send):
        headers = Headers(scope=scope)
        if not self.hosts.allows(headers.get("host")):
            return await _problem(
                400, "host", f"host: {headers.get('host', '')[:80]!r} is not a name of this "
                             f"server; accepted: {self.hosts.describe()} (more with `airpuff "
                             "serve --allowed-hosts`)", "host_not_allowed")(scope, receive, send)
        answer = self._refusal(scope)
        if answer is None and not self._length_ok(headers.get("content-length")):
            answer = self._too_big()
        if answer is not None:
            return await answer(scope, receive, send)
        if scope["method"] not in ("POST", "PUT", "PATCH"):
            return await self.app(scope, receive, send)

        body = bytearray()
        while True:
            message = await receive()
            if message["type"] != "http.request":  # the client went away
                return
            body += message.get("body", b"")
            if len(body) > self.limit:
                return await self._too_big()(scope, receive, send)
            if not message.get("more_body", False):
                break
        answer = self._check_body(headers, bytes(body), form=scope["path"] in pages.FORM_PATHS)
        model = self._body_model(scope)
        if answer is None and model is not None and body:
            answer = await anyio.to_thread.run_sync(check_json_body, model, bytes(body))
        if answer is not None:
            return await answer(scope, receive, send)
        sent = False

        async def replay():
            nonlocal sent
            if not sent:
                sent = True
                return {"type": "http.request", "body": bytes(body), "more_body": False}
            return await receive()

        return await self.app(scope, replay, send)

    def _length_ok(self, length: str | None) -> bool:
        if length is None:
            return True
        try:
            return int(length) <= self.limit
        except ValueError:
            return False

    def _too_big(self) -> JSONResponse:
        return JSONResponse({"detail": f"request body above {self.limit} bytes"}, 413)

    @staticmethod
    def _check_body(headers: Headers, body: bytes, form: bool) -> JSONResponse | None:
        """The content-type and encoding rules (3 and 4 above) for a non-empty body: JSON, or
        with ``form`` the urlencoded fields of a page's form."""
        if not body:
            return None
        content_type = headers.get("content-type", "")
        media, _, rest = content_type.partition(";")
        media = media.strip()
        accepted = FORM_MEDIA if form else "application/json (a JSON object in UTF-8)"
        if not (media.lower() == FORM_MEDIA if form else JSON_MEDIA.fullmatch(media.lower())):
            return _problem(415, "content-type",
                            f"content-type: {(media or 'none')[:80]!r} is not accepted; "
                            f"accepted: {accepted}", "content_type")
        charset = re.search(r"charset\s*=\s*\"?([\w.-]+)", rest, re.IGNORECASE)
        if charset and charset.group(1).lower() not in ("utf-8", "utf8"):
            return _problem(415, "content-type",
                            f"content-type: charset {charset.group(1)[:40]!r} is not accepted; "
                            "accepted: utf-8", "content_type")
        if not form and (body.startswith(WIDE_BOMS) or b"\x00" in body):
            return _problem(422, "body", "body: the JSON is not in UTF-8 (UTF-16 or UTF-32?); "
                                         "accepted: a JSON object in UTF-8", "json_invalid")
        return None


def _bearer_scheme(settings: Settings):
    """The bearer scheme as the OpenAPI schema documents it (``RequestGuard`` checks the token,
    before a body is read); None without a token."""
    if not settings.token:
        return None
    return Depends(HTTPBearer(auto_error=False, description="the value of AIRPUFF_API_TOKEN"))


def _json_error_position(exc: RequestValidationError) -> list[dict] | None:
    """The error of a body that is not JSON, with the line and column of the problem (FastAPI
    reports a character offset, which would read as a list index); None for other errors."""
    errors = exc.errors()
    if len(errors) != 1 or errors[0].get("type") != "json_invalid":
        return None
    loc = list(errors[0].get("loc", ()))
    doc = exc.body if isinstance(exc.body, str) else ""
    reason = (errors[0].get("ctx") or {}).get("error", "not valid JSON")
    where = ""
    if len(loc) == 2 and isinstance(loc[1], int):
        pos = loc[1]
        line = doc.count("\n", 0, pos) + 1
        column = pos - (doc.rfind("\n", 0, pos) + 1) + 1
        where = f" at line {line}, column {column}"
    return [{"loc": ["body"], "field": "body",
             "msg": f"body: invalid JSON{where}: {reason}; accepted: a JSON object in UTF-8",
             "type": "json_invalid"}]


# -- the app --------------------------------------------------------------------------------------

def _document_body_limit(app: FastAPI, limit: int) -> None:
    """Add the 413 that ``RequestGuard`` answers for a body above ``limit`` bytes to every
    operation of the OpenAPI schema that takes a body (the guard is a middleware, which FastAPI
    cannot see)."""
    generate = app.openapi

    def openapi():
        if app.openapi_schema is None:
            schema = generate()
            for operations in schema.get("paths", {}).values():
                for operation in operations.values():
                    if "requestBody" in operation:
                        operation.setdefault("responses", {}).setdefault(
                            "413", {"description": f"the request body is above {limit} bytes"})
        return app.openapi_schema

    app.openapi = openapi


def create_app(settings: Settings) -> FastAPI:
    """The API for ``settings.data_dir``.  With ``settings.run_jobs`` its lifespan also starts and
    stops the job runner (a thread owning the Dask client)."""
    SweepRequest = schemas.sweep_request_model(settings.max_points)
    _REQUEST_KEYS[:] = list(SweepRequest.model_fields)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if not settings.database_ready:
            db.init(settings.db_path)
        model_version()  # computed once, before any request needs a point key
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

    bearer_scheme = _bearer_scheme(settings)
    app = FastAPI(
        title="airpuff",
        version=__version__,
        summary="Parameter sweeps of the corneal air-puff simulation (ORA / Corvis metrics).",
        description=(
            "Submit a sweep over E0 [MPa] x IOP [mmHg] x thickness [mm] x pmax [kPa]; the job runs "
            "on a Dask cluster. Follow it at /sweeps/{id}, read its metrics at "
            "/sweeps/{id}/metrics and download the combined netCDF at /sweeps/{id}/dataset. "
            "Units and accepted ranges of every parameter are given in the request schema. "
            + ("Every endpoint except /health, /docs and /openapi.json needs "
               "`Authorization: Bearer <token>` (for GET, the session cookie of the results "
               "pages' login will do too)." if settings.token else "")),
        lifespan=lifespan, openapi_url=None, docs_url=None, redoc_url=None)
    app.state.settings = settings
    app.state.runner = None
    _document_body_limit(app, settings.max_body_bytes)
    app.add_middleware(RequestGuard, limit=settings.max_body_bytes, token=settings.token,
                       hosts=HostAllowList(settings.bind_address, settings.allowed_hosts),
                       bodies={"/sweeps": SweepRequest, "/identify": schemas.IdentifyRequest,
                               "/sweeps/{job_id}/corrections": corrections.CorrectionRequest,
                               "/sweeps/{job_id}/corrections/{cid}/apply":
                                   corrections.ApplyRequest})

    @app.exception_handler(RequestValidationError)
    async def on_validation_error(request: Request, exc: RequestValidationError):
        position = _json_error_position(exc)
        if position:
            return JSONResponse({"detail": jsonable_encoder(position)}, 422)
        return validation_problem(exc.errors())

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
        if disk_full(exc):
            return JSONResponse({"detail": f"{NO_SPACE} on the server: the job database cannot "
                                           "take the change; retry once space is freed in its "
                                           "data directory"}, 507,
                                headers={"Retry-After": "60"})
        return JSONResponse({"detail": "the job database is busy; retry shortly"}, 503,
                            headers={"Retry-After": "2"})

    app.include_router(routes.build_router(settings, SweepRequest, bearer_scheme))
    app.include_router(corrections.build_corrections_router(settings, bearer_scheme))
    app.include_router(pages.router(settings, SweepRequest, _describe))
    return app
