"""The results pages: server-rendered HTML on the same app as the JSON API.

    GET  /                              the jobs, newest first, with their progress
    GET  /jobs/{id}[?point=N]           a job: request, progress, figures, the readings raw and
                                        calibrated, metrics, failures
    GET  /jobs/{id}/figures/{name}.png  a figure drawn by the server (api.figures)
    GET  /new, POST /new                the sweep form (validated by the POST /sweeps schema)
    GET  /login, POST /login, POST /logout   the token, when AIRPUFF_API_TOKEN is set

The pages read and submit jobs through the jobs layer (``api.jobs``) that the JSON endpoints use,
and link to the JSON endpoints for the data.  With a token set, every page needs the session
cookie of ``POST /login`` (see ``api.auth``); without it a page redirects to the login form.
``api.app.RequestGuard`` checks that, before a body is read, for the paths ``is_page`` names.
"""

from __future__ import annotations

import sqlite3
from contextlib import closing
from typing import Any, Callable
from urllib.parse import parse_qsl, quote

from fastapi import APIRouter, Depends, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool

from airpuff_core.calibration import CALIBRATED
from airpuff_core.params import CHOICES, INT_PARAMETERS, PARAMETERS, SWEPT
from airpuff_core.result import METRICS, RAW_READINGS

from . import auth, corrections, db, figures, jobs, sweep_form
from .html import badge, esc, number, page, progress, table, watch_state, when
from .settings import Settings
from .status import ACTIVE_JOB_STATUSES

LIST_LIMIT = 100  # jobs on the front page
TABLE_LIMIT = 1000  # point rows on a job's page (the metrics JSON has them all)


# The paths of the pages, by which ``api.app.RequestGuard`` tells them from the API's: with a
# token set, the pages need the session cookie (a request without it is sent to the login form),
# except the login and logout forms, which make their own checks; the forms' POST bodies are
# application/x-www-form-urlencoded, not JSON.
OPEN_PATHS = ("/login", "/logout")
FORM_PATHS = ("/new", "/login", "/logout")


def is_page(path: str) -> bool:
    """True if ``path`` is one of this module's pages (see ``router``)."""
    return path in ("/", "/new") or path in OPEN_PATHS or path.startswith("/jobs/")


def login_redirect(request: Request) -> RedirectResponse:
    """The answer to a page asked for without the session cookie: the login form, which comes
    back to the page afterwards."""
    here = request.url.path + (f"?{request.url.query}" if request.url.query else "")
    return RedirectResponse("/login?next=" + quote(here, safe=""), 303)


def _safe_next(target: str | None) -> str:
    """A local path to return to after logging in (never another site)."""
    if not target or not target.startswith("/") or target.startswith("//") or "\\" in target:
        return "/"
    return target


def router(settings: Settings, SweepRequest, describe: Callable[[dict], dict]  # noqa: N803
           ) -> APIRouter:
    """The pages of the service in ``settings``; ``api.app`` includes this router.
    ``SweepRequest`` is the body model of ``POST /sweeps`` (``api.app`` builds it once for both),
    which validates the sweep form too; ``describe`` turns a validation error into the API's
    ``{"loc", "field", "msg", "type"}`` (the messages of a 422), so the form shows the same
    words."""
    token = settings.token

    r = APIRouter(include_in_schema=False)

    def connect() -> closing[sqlite3.Connection]:
        return closing(db.connect(settings.db_path))

    def html(title: str, body: str, status_code: int = 200,
             watch: tuple[str, tuple[str, str]] | None = None) -> HTMLResponse:
        return HTMLResponse(page(title, body, watch=watch, logout=bool(token)), status_code,
                            headers={"Cache-Control": "no-store"})

    def not_found(job_id: str) -> HTMLResponse:
        return html("not found", f"<h1>No such job</h1><p>There is no sweep job with id "
                                 f"<code>{esc(job_id)}</code>. <a href=\"/\">All jobs</a></p>", 404)

    # -- login -----------------------------------------------------------------------------------

    def login_form(next_path: str, error: str = "") -> str:
        message = f'<p class="error" id="login-error">{esc(error)}</p>' if error else ""
        return (f"<h1>Log in</h1><p>This server needs its API token "
                f"(<code>AIRPUFF_API_TOKEN</code>).</p>{message}"
                f'<form class="sweep" method="post" action="/login">'
                f'<label for="f-token">token</label>'
                f'<input type="password" id="f-token" name="token" autocomplete="current-password">'
                f'<input type="hidden" name="next" value="{esc(next_path)}">'
                f'<div><button type="submit" id="login">log in</button></div></form>')

    @r.get("/login")
    def login_page(next: str = "/"):
        if not token:
            return RedirectResponse("/", 303)
        return HTMLResponse(page("log in", login_form(_safe_next(next))),
                            headers={"Cache-Control": "no-store"})

    @r.post("/login")
    async def login(request: Request):
        form = dict(parse_qsl((await request.body()).decode("utf-8", "replace")))
        target = _safe_next(form.get("next"))
        if not token:
            return RedirectResponse(target, 303)
        if not auth.same_origin(request):
            return HTMLResponse(page("log in", login_form(target, "request from another site "
                                                                  "refused")), 403)
        if not auth.token_matches(form.get("token", ""), token):
            return HTMLResponse(page("log in", login_form(target, "wrong token")), 401,
                                headers={"Cache-Control": "no-store"})
        response = RedirectResponse(target, 303)
        response.set_cookie(auth.SESSION_COOKIE, auth.session_value(token), httponly=True,
                            samesite="strict", secure=request.url.scheme == "https", path="/")
        return response

    @r.post("/logout")
    def logout():
        response = RedirectResponse("/login" if token else "/", 303)
        response.delete_cookie(auth.SESSION_COOKIE, path="/")
        return response

    # -- jobs ------------------------------------------------------------------------------------

    @r.get("/", response_class=HTMLResponse)
    def job_list(con: sqlite3.Connection = Depends(jobs.get_db)):
        rows = db.list_jobs(con, LIST_LIMIT, 0)
        total = db.count_jobs(con)
        infos = [jobs.job_info(row) for row in rows]
        cells = []
        for job in infos:
            base = f"/sweeps/{job['id']}"
            links = [f'<a href="{esc(base)}" title="status (JSON)">status</a>',
                     f'<a href="{esc(base)}/metrics" title="metrics of every point (JSON)">'
                     "metrics</a>"]
            if job["status"] == "done":
                links.append(f'<a href="{esc(base)}/dataset" title="combined results">netCDF</a>')
            grid = " &times; ".join(str(len(job["request"][n])) for n in SWEPT)
            cells.append([f'<a href="/jobs/{esc(job["id"])}" title="{esc(job["id"])}">'
                          f"{esc(job['id'][:8])}</a>", badge(job["status"]), progress(job),
                          grid, when(job["created_at"]), when(job["finished_at"]),
                          " &middot; ".join(links)])
        shown = (f"<p class=\"muted\">{len(infos)} newest of {total} jobs.</p>"
                 if total > len(infos) else "")
        body = ("<h1>Sweep jobs</h1>" + (table(["job", "status", "progress",
                                                '<span title="E0 &times; IOP &times; thickness '
                                                '&times; pmax">grid</span>', "submitted",
                                                "finished", "JSON, netCDF"], cells, nowrap=True)
                                         if cells else '<p>No jobs yet. <a href="/new">Submit a '
                                                       'sweep</a>.</p>') + shown)
        active = any(job["status"] in ACTIVE_JOB_STATUSES for job in infos)
        watch = (f"/sweeps?limit={LIST_LIMIT}", watch_state(infos)) if active else None
        return html("jobs", body, watch=watch)

    def load(con: sqlite3.Connection, job_id: str
             ) -> tuple[dict[str, Any], list[dict[str, Any]]] | None:
        """(job info, point records) of a job, or None if there is no such job."""
        row = db.get_job(con, job_id)
        if row is None:
            return None
        return jobs.job_info(row), jobs.point_records(con, row)

    @r.get("/jobs/{job_id}", response_class=HTMLResponse)
    def job_page(job_id: str, point: int | None = None,
                 con: sqlite3.Connection = Depends(jobs.get_db)):
        loaded = load(con, job_id)
        if loaded is None:
            return not_found(job_id)
        job, records = loaded
        body = (_job_header(job) + _figures(job, records, point)
                + corrections.page_section(settings, con, db.get_job(con, job_id))
                + _metrics_table(records) + _failures(records) + _request_table(job["request"]))
        active = job["status"] in ACTIVE_JOB_STATUSES
        watch = (f"/sweeps/{job['id']}", watch_state([job])) if active else None
        return html(f"job {job['id'][:8]}", body, watch=watch)

    @r.get("/jobs/{job_id}/figures/{name}.png")
    def job_figure(job_id: str, name: str, con: sqlite3.Connection = Depends(jobs.get_db)):
        loaded = load(con, job_id)
        if loaded is None:
            return not_found(job_id)
        job, records = loaded
        try:
            data, final = figures.job_figure(settings, job, records, name)
        except figures.FigureUnavailable as why:
            reason = f"<p>{esc(why)}</p>" if str(why) != name else ""
            return html("not found", f"<h1>No figure {esc(name)} for this job</h1>{reason}", 404)
        cache = "private, max-age=86400" if final else "no-store"
        return Response(data, media_type="image/png", headers={"Cache-Control": cache})

    # -- the sweep form --------------------------------------------------------------------------

    @r.get("/new", response_class=HTMLResponse)
    def new_sweep():
        return html("new sweep", "<h1>New sweep</h1>"
                    + sweep_form.render(sweep_form.defaults(), {}, settings.max_points))

    @r.post("/new", response_class=HTMLResponse)
    async def submit_sweep(request: Request):
        if not auth.same_origin(request):
            return html("new sweep", "<h1>Refused</h1><p>The form was sent from another site."
                                     "</p>", 403)
        raw = (await request.body()).decode("utf-8", "replace")
        form = {k: v for k, v in parse_qsl(raw, keep_blank_values=True)}
        outcome = await run_in_threadpool(_submit, form,
                                          request.client.host if request.client else None)
        if isinstance(outcome, str):
            runner = request.app.state.runner
            if runner is not None:
                runner.wake()
            return RedirectResponse(f"/jobs/{outcome}", 303)
        values = {**sweep_form.defaults(), **form}
        return html("new sweep", "<h1>New sweep</h1>"
                    + sweep_form.render(values, outcome, settings.max_points), 422)

    def _submit(form: dict[str, str], owner: str | None) -> str | dict[str, list[str]]:
        """The new job's id, or the errors by field (the messages of POST /sweeps)."""
        # Axes with a syntax error are left out of the body (they take their defaults there), so
        # that the schema still reports every other field at once.
        body, errors = sweep_form.request_from_form(form, settings.max_points)
        problems: list[dict] = []
        try:
            values = SweepRequest.model_validate(body).model_dump()
        except ValidationError as exc:
            problems = [describe({**e, "loc": ("body", *e["loc"])}) for e in exc.errors()]
        else:
            if not errors:
                try:
                    with connect() as con:
                        return jobs.create_job(con, settings, values, owner)[0]
                except RequestValidationError as exc:
                    problems = [describe(e) for e in exc.errors()]
                except jobs.QueueFull as exc:
                    errors.setdefault(sweep_form.GENERAL, []).append(str(exc))
        for p in problems:
            field = p["field"] if p["field"] in SweepRequest.model_fields else sweep_form.GENERAL
            errors.setdefault(field, []).append(p["msg"])
        return errors

    def _job_header(job: dict[str, Any]) -> str:
        base = f"/sweeps/{job['id']}"
        links = [f'<a href="{esc(base)}">status JSON</a>',
                 f'<a href="{esc(base)}/metrics" id="metrics-link">metrics JSON</a>']
        if job["status"] == "done":
            links.append(f'<a href="{esc(base)}/dataset" id="dataset-link">netCDF</a>')
        times = table(["submitted", "started", "finished"],
                      [[when(job["created_at"]), when(job["started_at"]),
                        when(job["finished_at"])]])
        error = (f'<p class="error" id="job-error">{esc(job["error"])}</p>'
                 if job["error"] else "")
        return (f'<h1>Job <code>{esc(job["id"])}</code> <span id="status">'
                f'{badge(job["status"])}</span></h1>'
                f'<p id="progress">{progress(job)}</p>{error}{times}'
                f'<p>{" &middot; ".join(links)}</p>')

    return r


# -- parts of a job's page (pure functions of the job's records) ---------------------------------

def _describe_parameter(name: str) -> tuple[str, str]:
    """(unit, description) of a request field."""
    if name in PARAMETERS:
        spec = PARAMETERS[name]
        return sweep_form.unit_text(name) or "1", spec.description
    if name in CHOICES:
        from airpuff_core.params import CHOICE_DESCRIPTIONS

        return "", CHOICE_DESCRIPTIONS[name]
    if name in INT_PARAMETERS:
        return "1", INT_PARAMETERS[name][3]
    return "", ""


def _request_table(request: dict[str, Any]) -> str:
    order = list(SWEPT) + list(sweep_form.MAIN_CHOICES) + sweep_form.option_names()
    rows = []
    for name in order + sorted(set(request) - set(order)):
        if name not in request:
            continue
        value = request[name]
        text = ", ".join(f"{v:g}" for v in value) if isinstance(value, list) else (
            f"{value:g}" if isinstance(value, float) else str(value))
        unit, description = _describe_parameter(name)
        rows.append([f"<code>{esc(name)}</code>", esc(text), esc(unit), esc(description)])
    return ('<h2>Request</h2><details open><summary>every parameter, with its unit</summary>'
            + table(["parameter", "value", "unit", "meaning"], rows) + "</details>")


def _figures(job: dict[str, Any], records: list[dict[str, Any]], point: int | None) -> str:
    names = figures.available(records)
    if not names:
        return ("<h2>Figures</h2><p class=\"muted\">The figures appear when the first point "
                "has finished.</p>")
    base = f"/jobs/{job['id']}/figures"
    thickness, pmax = figures.grid_slice(records)
    imgs = "".join(f'<img src="{esc(base)}/{esc(n)}.png" alt="{esc(n)}" width="400" '
                   f'height="300">' for n in names)
    chosen = figures.history_point(records, point)
    history = ""
    if chosen is not None:
        history = (f'<h2>History of point {chosen["index"]}</h2><p class="muted">E0 '
                   f'{chosen["E0"]:g} MPa, IOP {chosen["IOP"]:g} mmHg, thickness '
                   f'{chosen["thickness"]:g} mm, pmax {chosen["pmax"]:g} kPa; choose another in '
                   f'the table below.</p><div class="figures"><img src="{esc(base)}/history-'
                   f'{chosen["index"]}.png" alt="apex displacement and jet pressure against time" '
                   f'width="700" height="420"></div>')
    return (f'<h2 id="figures">Figures</h2><p class="muted">At thickness {thickness:g} mm and pmax '
            f'{pmax:g} kPa; failed points are marked with a red x on the IOP axis.</p>'
            f'<div class="figures">{imgs}</div>{history}')


def metric_columns() -> list[str]:
    """The metrics table's columns: every raw metric, each calibrated reading (``<name>_cal``)
    right after its raw one, and those without a raw column of their name (``IOPnc_cal``, from
    P1) after the last calibrated one."""
    columns = []
    for name in METRICS:
        columns.append(name)
        if f"{name}_cal" in CALIBRATED:
            columns.append(f"{name}_cal")
    last = max(i for i, name in enumerate(columns) if name in CALIBRATED)
    rest = [name for name in CALIBRATED if name not in columns]
    return columns[:last + 1] + rest + columns[last + 1:]


def _metric_header(name: str) -> str:
    if name in CALIBRATED:
        unit, long = CALIBRATED[name]
        return (f'<span class="cal" title="Goldmann-equivalent: {esc(long)}">{esc(name)} '
                f"[{esc(unit)}]</span>")
    unit, long = METRICS[name]
    return f'<span title="{esc(long)}">{esc(name)} [{esc(unit)}]</span>'


def _reason_html(reason: str) -> str:
    """A reason of ``airpuff_core.calibration.find_calibration``, its command as code."""
    before, sep, command = reason.partition("make one with: ")
    return esc(before) + (f"make one with: <code>{esc(command)}</code>" if sep else "")


def _calibration_section(records: list[dict[str, Any]]) -> str:
    """What the ``_cal`` columns are, the calibration applied and why a point has none."""
    ok = [r for r in records if r["status"] == "ok"]
    raw = ", ".join(n for n in RAW_READINGS)
    intro = (f'<h2 id="calibration">Readings: raw and on Goldmann\'s scale</h2><p>{esc(raw)} '
             "are <b>raw</b>: computed from the instrument's pressure at the apex at the two "
             "applanations, which includes the cornea's resistance (so raw IOPg reads above the "
             "true IOP). The "
             'columns named <span class="cal">&hellip;_cal</span> are the <b>Goldmann-equivalent'
             "</b> readings [mmHg]: the raw ones mapped by the instrument's calibration for the "
             "point's instrument, resolution and model version, fitted on the model's IOP sweep "
             "at a reference eye (IOPnc_cal is the Corvis-style IOP from P1 alone; "
             "docs/calibration.md).</p>")
    if not ok:
        return intro + '<p class="muted">They appear when the first point has finished.</p>'
    used: dict[str, int] = {}
    missing: dict[str, int] = {}
    for r in ok:
        if r["calibration"]:
            used[r["calibration"]] = used.get(r["calibration"], 0) + 1
        if r["calibration_missing"]:
            missing[r["calibration_missing"]] = missing.get(r["calibration_missing"], 0) + 1
    items = [f"<li>{n} point{'s' if n > 1 else ''} calibrated with <code>{esc(label)}</code>"
             "</li>" for label, n in used.items()]
    items += [f'<li class="error">{n} point{"s" if n > 1 else ""} without calibrated readings: '
              f"{_reason_html(reason)}</li>" for reason, n in missing.items()]
    return intro + f'<ul id="calibration-status">{"".join(items)}</ul>'


def _metrics_table(records: list[dict[str, Any]]) -> str:
    columns = metric_columns()
    headers = (["#"] + [f"{n} [{PARAMETERS[n].unit}]" for n in SWEPT] + ["status"]
               + [_metric_header(n) for n in columns])
    rows = []
    for rec in records[:TABLE_LIMIT]:
        index = (f'<a href="?point={rec["index"]}#figures" title="show its history">'
                 f'{rec["index"]}</a>' if rec["status"] == "ok" else str(rec["index"]))
        status = esc(rec["status"]) + (" (reused)" if rec["reused"] else "")
        rows.append([index] + [number(rec[n], 6) for n in SWEPT] + [status]
                    + [number(rec[n]) for n in columns])
    numeric = set(range(1, 1 + len(SWEPT))) | set(range(2 + len(SWEPT), 2 + len(SWEPT)
                                                      + len(columns)))
    more = (f'<p class="muted">First {TABLE_LIMIT} of {len(records)} points; the metrics JSON '
            f"has them all.</p>" if len(records) > TABLE_LIMIT else "")
    return (_calibration_section(records) + '<h2 id="metrics">Metrics of the points</h2>'
            '<div class="points" style="overflow-x:auto">'
            + table(headers, rows, numeric, nowrap=True) + "</div>" + more)


def _failures(records: list[dict[str, Any]]) -> str:
    failed = [r for r in records if r["status"] == "failed"]
    if not failed:
        return ""
    rows = [[str(r["index"])] + [number(r[n], 6) for n in SWEPT] + [esc(r["message"])]
            for r in failed]
    return ('<h2 id="failures">Failed points</h2>'
            + table(["#"] + [f"{n} [{PARAMETERS[n].unit}]" for n in SWEPT] + ["reason"], rows))

