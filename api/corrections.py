"""Corrections and sensitivity over HTTP, on their own ``APIRouter`` (``api.app`` includes it),
and their section of a job's results page.

    POST /sweeps/{id}/corrections                 fit a correction on a finished job (201)
    GET  /sweeps/{id}/corrections                 the job's corrections (summaries)
    GET  /sweeps/{id}/corrections/{cid}           one correction file (as `airpuff correct fit`)
    POST /sweeps/{id}/corrections/{cid}/apply     apply it to rows (JSON) or a CSV text
    GET  /sweeps/{id}/sensitivity                 Sobol indices of every metric over the job
    GET  /jobs/{id}/corrections/{cid}/residuals.png   held-out residuals against each reading

The method is ``sweep.correction`` and ``sweep.sensitivity`` (docs/correction.md).  The fit reads
the job's metrics from the job database (never a netCDF file: the runner thread writes those in
this process).  A correction is stored as ``DATA_DIR/jobs/<id>/corrections/<cid>.json``, and the
job's Sobol indices as ``DATA_DIR/jobs/<id>/sensitivity.json``: both go when the job is deleted.
"""

# No `from __future__ import annotations`: FastAPI reads the handlers' annotations.
import io
import json
import re
import sqlite3
import threading
import uuid
from typing import Annotated, Any, Optional

from fastapi import APIRouter, Depends, HTTPException, Response
from pydantic import BaseModel, ConfigDict, Field

from airpuff_core.atomic import atomic_write
from airpuff_core.result import METRICS
from sweep.correction import (FOLDS, INSTRUMENTS, MAX_DEGREE, SEED, Correction, CorrectionError,
                              accepted_columns, apply_rows, fit_correction, read_measurements,
                              sweep_sources)
from sweep.identification import MEASURABLE, SweepTable

from .html import esc
from .jobs import get_db, point_records, problem_422
from .routes import job_or_404
from .settings import Settings

CID_RE = re.compile(r"^[0-9a-f]{12}$")
MAX_ROWS = 10_000
# One fit or sensitivity analysis at a time per process: they are CPU-bound and short.
_compute_lock = threading.Lock()


class CorrectionRequest(BaseModel):
    """Fit a correction on a finished sweep job (docs/correction.md)."""

    model_config = ConfigDict(extra="forbid",
                              json_schema_extra={"examples": [{"instrument": "ora"}]})
    instrument: Annotated[str, Field(description="ora (P1, P2, CCT) or corvis (IOPnc, CCT, DA)",
                                     max_length=16)]
    pmax: Optional[float] = Field(default=None, description="the jet amplitude to fit at [kPa], "
                                                            "if the sweep has several")
    max_degree: int = Field(default=MAX_DEGREE, ge=1, le=4,
                            description="highest polynomial degree tried")
    folds: int = Field(default=FOLDS, ge=2, le=20, description="folds of the cross-validation")


class ApplyRequest(BaseModel):
    """Measurements: ``rows`` (objects keyed by the correction's column names, with optional
    ``<column>_sigma`` and ``id``) or ``csv`` (the text of a CSV file with a header row)."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [
        {"rows": [{"id": "OD-001", "P1": 21.3, "P2": 18.9, "CCT": 545, "P1_sigma": 0.5}]},
        {"csv": "id,P1,P2,CCT\nOD-001,21.3,18.9,545\n"}]})
    rows: Optional[list[dict[str, Any]]] = Field(default=None, max_length=MAX_ROWS)
    csv: Optional[str] = Field(default=None, max_length=2_000_000)


def corrections_dir(settings: Settings, job_id: str):
    return settings.jobs_dir / job_id / "corrections"


def _done_job(con, job_id: str):
    row = job_or_404(con, job_id)
    if row["status"] != "done":
        raise HTTPException(409, f"job {job_id} is {row['status']}; a correction needs a "
                                 "finished (done) sweep")
    return row


def _table(con, row, names) -> SweepTable:
    return SweepTable.from_records(json.loads(row["spec_json"]), point_records(con, row),
                                   names)


def _summary(cid: str, job_id: str, d: dict) -> dict[str, Any]:
    base = f"/sweeps/{job_id}/corrections/{cid}"
    return {"id": cid, "job_id": job_id, "instrument": d["instrument"],
            "calibration": d["calibration"], "model_version": d["model_version"],
            "used": d["sweep"]["used"], "excluded_failed": d["sweep"]["excluded_failed"],
            "excluded_no_reading": d["sweep"]["excluded_no_reading"],
            "targets": {t: {"unit": td["unit"], "degree": td["degree"],
                            "formula": td["formula"], "held_out_rms": td["held_out"]["rms"]}
                        for t, td in d["targets"].items()},
            "validation": d["validation"],
            "links": {"self": base, "apply": base + "/apply",
                      "residuals": f"/jobs/{job_id}/corrections/{cid}/residuals.png"}}


def _load(settings: Settings, job_id: str, cid: str) -> dict:
    path = corrections_dir(settings, job_id) / f"{cid}.json"
    if not CID_RE.fullmatch(cid) or not path.is_file():
        raise HTTPException(404, f"no correction {cid!r} of job {job_id}")
    return json.loads(path.read_text(encoding="utf-8"))


def _stored(settings: Settings, job_id: str) -> list[tuple[str, dict]]:
    folder = corrections_dir(settings, job_id)
    out = []
    for path in sorted(folder.glob("*.json"), key=lambda p: p.stat().st_mtime) \
            if folder.is_dir() else []:
        if CID_RE.fullmatch(path.stem):
            out.append((path.stem, json.loads(path.read_text(encoding="utf-8"))))
    return out


def job_sensitivity(settings: Settings, con, row) -> dict[str, Any]:
    """The job's Sobol indices (``sweep.sensitivity``), computed once for a done job and kept."""
    from sweep.sensitivity import sobol_indices

    path = settings.jobs_dir / row["id"] / "sensitivity.json"
    if path.is_file():
        return json.loads(path.read_text(encoding="utf-8"))
    with _compute_lock:
        result = sobol_indices(_table(con, row, tuple(METRICS)))
    atomic_write(path, lambda p: p.write_text(json.dumps(result), encoding="utf-8"))
    return result


def build_corrections_router(settings: Settings, auth) -> APIRouter:
    """The routes above for ``settings``; ``auth`` is the token dependency or None."""
    deps = [auth] if auth is not None else []
    router = APIRouter()

    def create(job_id: str, body: CorrectionRequest, response: Response,
               con: sqlite3.Connection = Depends(get_db)):
        row = _done_job(con, job_id)
        if body.instrument not in INSTRUMENTS:
            raise problem_422(["body", "instrument"], "instrument",
                              f"instrument: {body.instrument!r} is not accepted; accepted: "
                              + " or ".join(INSTRUMENTS))
        names = tuple(dict.fromkeys((*MEASURABLE, *sweep_sources(body.instrument))))
        try:
            with _compute_lock:
                d = fit_correction(_table(con, row, names), body.instrument, body.max_degree,
                                   body.folds, SEED, body.pmax, sweep_name=f"job {job_id}")
        except CorrectionError as err:
            raise problem_422(["body", err.field], err.field, f"{err.field}: {err}") from None
        cid = uuid.uuid4().hex[:12]
        atomic_write(corrections_dir(settings, row["id"]) / f"{cid}.json",
                     lambda p: p.write_text(json.dumps(d, indent=1), encoding="utf-8"))
        try:  # the job page shows the Sobol indices beside the formula
            job_sensitivity(settings, con, row)
        except CorrectionError:
            pass  # a grid on which nothing varies: the page says so when asked
        response.status_code = 201
        response.headers["Location"] = f"/sweeps/{job_id}/corrections/{cid}"
        return _summary(cid, job_id, d)

    def list_corrections(job_id: str, con: sqlite3.Connection = Depends(get_db)):
        row = job_or_404(con, job_id)
        return {"job_id": job_id,
                "corrections": [_summary(c, job_id, d) for c, d in _stored(settings, row["id"])]}

    def get_correction(job_id: str, cid: str, con: sqlite3.Connection = Depends(get_db)):
        row = job_or_404(con, job_id)
        return {"id": cid, **_load(settings, row["id"], cid)}

    def apply(job_id: str, cid: str, body: ApplyRequest,
              con: sqlite3.Connection = Depends(get_db)):
        row = job_or_404(con, job_id)
        correction = Correction.from_dict(_load(settings, row["id"], cid))
        if (body.rows is None) == (body.csv is None):
            raise problem_422(["body"], "body", "body: give either rows (a list of objects) or "
                                                "csv (the text of a CSV file), not both")
        try:
            if body.csv is not None:
                rows = read_measurements(body.csv, correction)
            else:
                if not body.rows:
                    raise CorrectionError("rows", "no rows given")
                rows = [{"row": i, "id": r.get("id"), "values": r,
                         "sigmas": {k[:-6]: v for k, v in r.items()
                                    if isinstance(k, str) and k.lower().endswith("_sigma")}}
                        for i, r in enumerate(body.rows)]
        except CorrectionError as err:
            field = "csv" if body.csv is not None else "rows"
            raise problem_422(["body", field], field, f"{field}: {err}") from None
        results = apply_rows(correction, rows)
        return {"job_id": job_id, "correction": cid, "instrument": correction.data["instrument"],
                "calibration": correction.data["calibration"],
                "units": {"IOP": "mmHg", "E0": "MPa"},
                "accepted_columns": accepted_columns(correction), "rows": results,
                "n_rows": len(results),
                "n_error": sum(r["status"] == "error" for r in results),
                "n_outside": sum(r["status"] == "outside" for r in results)}

    def sensitivity(job_id: str, con: sqlite3.Connection = Depends(get_db)):
        row = _done_job(con, job_id)
        try:
            return {"job_id": job_id, **job_sensitivity(settings, con, row)}
        except CorrectionError as err:
            raise HTTPException(409, f"no sensitivity for this job: {err}") from None

    def residuals_png(job_id: str, cid: str, con: sqlite3.Connection = Depends(get_db)):
        row = job_or_404(con, job_id)
        data = residual_figure(_load(settings, row["id"], cid))
        return Response(data, media_type="image/png",
                        headers={"Cache-Control": "private, max-age=86400"})

    missing = {404: {"description": "no such job or correction"},
               409: {"description": "the job is not done"}}
    add = router.add_api_route
    add("/sweeps/{job_id}/corrections", create, methods=["POST"], status_code=201,
        tags=["corrections"], dependencies=deps, responses=missing,
        summary="Fit a corrected IOP and a stiffness index on a finished job (docs/correction.md)")
    add("/sweeps/{job_id}/corrections", list_corrections, methods=["GET"], tags=["corrections"],
        dependencies=deps, responses=missing, summary="The job's corrections")
    add("/sweeps/{job_id}/corrections/{cid}", get_correction, methods=["GET"],
        tags=["corrections"], dependencies=deps, responses=missing,
        summary="One correction file: formula, ranges, held-out error, points")
    add("/sweeps/{job_id}/corrections/{cid}/apply", apply, methods=["POST"],
        tags=["corrections"], dependencies=deps, responses=missing,
        summary="Corrected IOP and stiffness index of each row, with uncertainty and flags")
    add("/sweeps/{job_id}/sensitivity", sensitivity, methods=["GET"], tags=["corrections"],
        dependencies=deps, responses=missing,
        summary="First-order and total Sobol indices of every metric (polynomial surrogate, "
                "SALib)")
    add("/jobs/{job_id}/corrections/{cid}/residuals.png", residuals_png, methods=["GET"],
        include_in_schema=False)
    return router


# -- figure and page section ---------------------------------------------------------------------

def residual_figure(d: dict) -> bytes:
    """PNG: the held-out residual of each target against each reading (one row per target)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from .figures import DPI, _draw_lock

    pts = d["points"]
    readings, targets = d["readings"], list(d["targets"])
    with _draw_lock:
        fig = Figure(figsize=(3.2 * len(readings), 2.6 * len(targets)), dpi=DPI)
        axes = fig.subplots(len(targets), len(readings), squeeze=False)
        for i, t in enumerate(targets):
            unit = d["targets"][t]["unit"]
            resid = [p - y for p, y in zip(pts[f"{t}_held_out"], pts[t])]
            for j, r in enumerate(readings):
                ax = axes[i][j]
                ax.axhline(0.0, color="0.6", lw=0.8)
                ax.plot(pts[r["name"]], resid, "o", ms=3)
                ax.set_xlabel(f"{r['name']} [{r['unit']}]")
                if j == 0:
                    ax.set_ylabel(f"{t} held-out residual [{unit}]")
        fig.suptitle(f"{d['instrument']} correction: held-out residuals ({d['calibration']} "
                     "readings)")
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
    return buf.getvalue()


def page_section(settings: Settings, con, row) -> str:
    """The job page's section: each correction's formulas, held-out errors and residual figure,
    and the Sobol indices of every metric once computed (by ``GET /sweeps/{id}/sensitivity`` or
    a correction's fit)."""
    if row["status"] != "done":
        return ""
    job_id = row["id"]
    parts = ['<h2 id="corrections">Corrections</h2>']
    stored = _stored(settings, job_id)
    if not stored:
        parts.append(f'<p class="muted">None yet: <code>POST /sweeps/{esc(job_id)}/corrections'
                     '</code> with <code>{"instrument": "ora"}</code> fits one '
                     '(docs/correction.md).</p>')
    for cid, d in stored:
        rows = "".join(
            f"<tr><td>{esc(t)} [{esc(td['unit'])}]</td><td>{td['degree']}</td>"
            f"<td>{td['held_out']['rms']:.3g}</td><td><code>{esc(td['formula'])}</code></td></tr>"
            for t, td in d["targets"].items())
        scaling = "; ".join(f"z({esc(r['name'])}) = ({esc(r['name'])} - "
                            f"{d['targets']['IOP']['scaling'][r['name']]['center']:.6g}) / "
                            f"{d['targets']['IOP']['scaling'][r['name']]['half_range']:.6g} "
                            f"[{esc(r['unit'])}], valid {r['range'][0]:.4g} to {r['range'][1]:.4g}"
                            for r in d["readings"])
        parts.append(
            f'<h3>{esc(d["instrument"])} correction <code>{esc(cid)}</code> '
            f'({esc(d["calibration"])} readings)</h3>'
            f'<p class="muted">{d["sweep"]["used"]} points used; left out: '
            f'{d["sweep"]["excluded_failed"]} failed, {d["sweep"]["excluded_no_reading"]} '
            f'without a reading. {scaling}.</p>'
            '<table><thead><tr><th>target</th><th>degree</th><th>held-out RMS</th>'
            f'<th>formula</th></tr></thead><tbody>{rows}</tbody></table>'
            f'<div class="figures"><img alt="held-out residuals against each reading" '
            f'src="/jobs/{esc(job_id)}/corrections/{esc(cid)}/residuals.png"></div>')
    path = settings.jobs_dir / job_id / "sensitivity.json"
    if not path.is_file():  # computed on request only: a page view stays fast
        parts.append(f'<h2 id="sensitivity">Sensitivity (Sobol indices)</h2><p class="muted">Not '
                     f'computed yet: <a href="/sweeps/{esc(job_id)}/sensitivity">GET /sweeps/'
                     f'{esc(job_id)}/sensitivity</a> computes them (a few seconds; fitting a '
                     'correction does it too), and they then show here.</p>')
        return "".join(parts)
    sens = json.loads(path.read_text(encoding="utf-8"))
    params = sens["parameters"]
    head = "".join(f"<th>S1 {esc(p)}</th><th>ST {esc(p)}</th>" for p in params)
    body = []
    for name, m in sens["metrics"].items():
        if "skipped" in m:
            body.append(f"<tr><td>{esc(name)}</td><td colspan=\"{2 * len(params) + 1}\">"
                        f"skipped: {esc(m['skipped'])}</td></tr>")
            continue
        cells = "".join(f"<td>{m['S1'][p]:.2f}</td><td>{m['ST'][p]:.2f}</td>" for p in params)
        body.append(f"<tr><td>{esc(name)} [{esc(m['unit'])}]</td>{cells}"
                    f"<td>{m['surrogate']['relative_held_out_rms']:.2f}</td></tr>")
    parts.append(f'<h2 id="sensitivity">Sensitivity (Sobol indices)</h2>'
                 f'<p class="muted">{esc(sens["method"])}. S1: first-order, ST: total. Last '
                 'column: the surrogate\'s held-out RMS over the metric\'s standard deviation '
                 '(where it is not small, the indices describe the surrogate more than the '
                 'model).</p>'
                 f'<table><thead><tr><th>metric</th>{head}<th>surrogate RMS / std</th></tr>'
                 f'</thead><tbody>{"".join(body)}</tbody></table>')
    return "".join(parts)
