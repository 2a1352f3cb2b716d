"""HTML of the results pages, built from strings: every value goes through ``esc`` (the standard
library's ``html.escape``, quotes included) before it reaches the page, so text from a request or
the database cannot become markup.  One style sheet, one small script (refresh while jobs run)."""

from __future__ import annotations

import html
from datetime import datetime
from typing import Any, Iterable

STATUS_COLOURS = {"queued": "#777", "running": "#1f6feb", "done": "#1a7f37", "failed": "#cf222e",
                  "cancelled": "#9a6700"}

CSS = """
body{font:14px/1.45 system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;margin:0;color:#1f2328}
header{background:#24292f;color:#fff;padding:.6em 1.2em;display:flex;gap:1.4em;align-items:center}
header a{color:#fff;text-decoration:none}header .brand{font-weight:600;font-size:1.1em}
header form{margin:0 0 0 auto}
main{padding:1em 1.2em;max-width:1300px}
h1{font-size:1.35em;margin:.2em 0 .6em}h2{font-size:1.1em;margin:1.4em 0 .5em}
table{border-collapse:collapse;margin:.3em 0}
th,td{border-bottom:1px solid #d0d7de;padding:.25em .6em;text-align:left;vertical-align:top}
th{background:#f6f8fa;font-weight:600}table.nowrap td{white-space:nowrap}
.points table{font-size:.9em}.points th,.points td{padding:.2em .35em}
td.num{text-align:right;font-variant-numeric:tabular-nums}
.badge{display:inline-block;color:#fff;border-radius:1em;padding:0 .6em;font-size:.9em}
.bar{display:inline-block;width:8em;height:.8em;background:#eaeef2;border-radius:.4em;
overflow:hidden;vertical-align:middle;margin-right:.5em}
.bar span{display:block;height:100%;float:left}.bar .ok{background:#2da44e}
.bar .failed{background:#cf222e}
.muted{color:#656d76}.error{color:#cf222e}.cal{color:#0550ae}
.figures{display:flex;flex-wrap:wrap;gap:.6em}.figures img{border:1px solid #d0d7de;max-width:100%}
form.sweep label{display:block;font-weight:600;margin-top:.7em}
form.sweep input[type=text],form.sweep input[type=password],form.sweep select{width:22em;
padding:.25em;font:inherit;box-sizing:border-box}
form.sweep .help{color:#656d76;font-size:.9em}
form.sweep .field-error{color:#cf222e;font-size:.95em}
form.sweep .invalid{border:2px solid #cf222e}
details{margin-top:1em}summary{cursor:pointer;font-weight:600}
.options{columns:2 26em}.options>div{break-inside:avoid}
button{font:inherit;padding:.3em 1em;margin-top:1em;cursor:pointer}
header button{margin:0;padding:.1em .7em}
"""

# Reload the page when a job in the watched JSON (``GET /sweeps/{id}`` or ``GET /sweeps``) has
# another status than the page shows, and at most every RELOAD_S seconds when only its counts of
# points differ (each reload redraws the figures of a running job).  The request carries the
# session cookie, which the API accepts for GET (api.auth).
RELOAD_S = 10
REFRESH_SCRIPT = """
<script>
(function(){var b=document.body.dataset,t0=Date.now();if(!b.watch)return;
function s(j,f){return (j.jobs||[j]).map(function(x){return f.map(function(k){return x[k]})
.join(':')}).join(',')}
setInterval(function(){fetch(b.watch,{credentials:'same-origin'}).then(function(r){return r.json()})
.then(function(j){if(s(j,['id','status'])!==b.status||(s(j,['points_done','points_failed'])
!==b.counts&&Date.now()-t0>%d))location.reload()}).catch(function(){})},2000)})();
</script>""" % (1000 * RELOAD_S)


def watch_state(jobs: Iterable[dict[str, Any]]) -> tuple[str, str]:
    """(statuses, counts) of jobs as the refresh script writes them from the JSON."""
    jobs = list(jobs)
    return (",".join(f"{j['id']}:{j['status']}" for j in jobs),
            ",".join(f"{j['points_done']}:{j['points_failed']}" for j in jobs))


def esc(value: Any) -> str:
    """``value`` as text safe inside HTML elements and quoted attributes."""
    return html.escape("" if value is None else str(value), quote=True)


def when(iso_text: str | None) -> str:
    """An ISO 8601 UTC time stamp of the API as 'YYYY-MM-DD HH:MM:SS UTC' (or a dash)."""
    if not iso_text:
        return "&ndash;"
    t = datetime.fromisoformat(iso_text)
    return esc(t.strftime("%Y-%m-%d %H:%M:%S UTC"))


def number(value: float | None, digits: int = 4) -> str:
    if value is None:
        return "&ndash;"
    return esc(f"{value:.{digits}g}")


def badge(status: str) -> str:
    return (f'<span class="badge" style="background:{STATUS_COLOURS.get(status, "#777")}">'
            f"{esc(status)}</span>")


def progress(job: dict[str, Any]) -> str:
    """A bar (green done, red failed) and 'done / total, failed, reused' of a job."""
    total = max(job["points_total"], 1)
    ok = 100.0 * job["points_done"] / total
    failed = 100.0 * job["points_failed"] / total
    return (f'<span class="bar" title="{ok:.0f} % done, {failed:.0f} % failed">'
            f'<span class="ok" style="width:{ok:.2f}%"></span>'
            f'<span class="failed" style="width:{failed:.2f}%"></span></span>'
            f'{job["points_done"]} / {job["points_total"]} done, '
            f'{job["points_failed"]} failed, {job["points_reused"]} reused')


def table(headers: Iterable[str], rows: Iterable[Iterable[str]], numeric: set[int] = frozenset(),
          nowrap: bool = False) -> str:
    """A table of cells that are HTML already (escape values before passing them)."""
    head = "".join(f"<th>{h}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f'<td class="num">{c}</td>' if i in numeric else f"<td>{c}</td>"
                                    for i, c in enumerate(row)) + "</tr>" for row in rows)
    cls = ' class="nowrap"' if nowrap else ""
    return f"<table{cls}><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def page(title: str, body: str, *, watch: tuple[str, tuple[str, str]] | None = None,
         logout: bool = False) -> str:
    """A whole page: header with navigation, ``body`` (HTML), and the refresh script when
    ``watch`` is (JSON URL to follow, ``watch_state`` of the jobs as rendered)."""
    logout_form = ('<form method="post" action="/logout"><button type="submit">log out</button>'
                   "</form>") if logout else ""
    watch_attr = (f' data-watch="{esc(watch[0])}" data-status="{esc(watch[1][0])}" '
                  f'data-counts="{esc(watch[1][1])}"' if watch else "")
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{esc(title)} - airpuff</title><style>{CSS}</style></head>"
            f"<body{watch_attr}><header><a class=\"brand\" href=\"/\">airpuff sweeps</a>"
            f'<a href="/">jobs</a><a href="/new">new sweep</a><a href="/docs">API</a>'
            f"{logout_form}</header><main>{body}</main>"
            f"{REFRESH_SCRIPT if watch else ''}</body></html>")
