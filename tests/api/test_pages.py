"""The results pages over plain HTTP (no browser): a real `airpuff serve --no-runner` on a loopback
port.  The sweep form must give exactly the messages of POST /sweeps, beside the right field; the
token must guard every page; text from a request must come back escaped.  The pages in a real
browser, with a running job, are tested in test_pages_browser.py.
"""

from __future__ import annotations

import html
import json
import re

import httpx
import pytest

from tests.api.support import ServerProcess

pytestmark = pytest.mark.service

TOKEN = "pages-token"
FIELD_ERROR = re.compile(r'<(?:div|p) class="(?:field-)?error" id="error-([\w]+)">(.*?)</(?:div|p)>')


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with ServerProcess(tmp_path_factory.mktemp("pages") / "data", "--no-runner",
                       "--max-points", "4", token=TOKEN).running() as s:
        yield s


@pytest.fixture(scope="module")
def session(server):
    """A client logged in through the form (cookie only, no bearer header)."""
    with httpx.Client(base_url=server.url, timeout=30) as c:
        r = c.post("/login", data={"token": TOKEN, "next": "/new"})
        assert r.status_code == 303 and r.headers["location"] == "/new"
        assert "HttpOnly" in r.headers["set-cookie"] and "SameSite=strict" in r.headers["set-cookie"]
        yield c


def form_errors(page: str) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for field, msg in FIELD_ERROR.findall(page):
        out.setdefault(field, []).append(html.unescape(msg))
    return out


# (form fields, the same request as a JSON body)
CASES = [
    ({"E0": "0.3, -1"}, {"E0": [0.3, -1.0]}),
    ({"IOP": "12, 12"}, {"IOP": [12.0, 12.0]}),
    ({"T": "soon"}, {"T": "soon"}),
    ({"t_end": "nan"}, {"t_end": float("nan")}),
    ({"resolution": "huge"}, {"resolution": "huge"}),
    ({"max_coupling_iterations": "2.5"}, {"max_coupling_iterations": "2.5"}),
    ({"E0": "0.3:0.6:3", "IOP": "10, 20"}, {"E0": [0.3, 0.45, 0.6], "IOP": [10.0, 20.0]}),
    ({"cfl": "0.9", "pmax": "60"}, {"cfl": 0.9, "pmax": [60.0]}),
]


@pytest.mark.parametrize("fields, body", CASES, ids=[",".join(c[0]) for c in CASES])
def test_form_gives_the_messages_of_post_sweeps(server, session, fields, body):
    with server.client() as api:
        r = api.post("/sweeps", content=json.dumps(body),  # json.dumps writes NaN as NaN
                     headers={"Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    expected: dict[str, list[str]] = {}
    for d in r.json()["detail"]:
        field = d["field"] if d["field"] in body else "_general"
        expected.setdefault(field, []).append(d["msg"])
    page = session.post("/new", data=fields)
    assert page.status_code == 422
    assert form_errors(page.text) == expected
    # what was typed is shown again (a choice outside the list cannot be: the select keeps its own)
    for name, text in fields.items():
        if name != "resolution":
            assert f'name="{name}" value="{html.escape(text)}"' in page.text


def test_axis_syntax_errors_are_reported_with_the_rest(session):
    page = session.post("/new", data={"E0": "0.3;0.6", "IOP": "10:20:x", "T": "-1"})
    errors = form_errors(page.text)
    assert sorted(errors) == ["E0", "IOP", "T"]
    assert errors["E0"] == ["E0: invalid E0='0.3;0.6': accepted a comma list of numbers "
                            "(e.g. 0.3,0.5,0.7) or start:stop:num (e.g. 10:30:5)"]
    assert errors["IOP"] == ["IOP: invalid IOP='10:20:x': accepted start:stop:num with num a "
                             "whole number >= 1"]
    # start:stop:num is capped before any array is made
    page = session.post("/new", data={"E0": "0.1:1:1000000000000"})
    assert form_errors(page.text)["E0"] == ["E0: invalid E0='0.1:1:1000000000000': accepted "
                                            "start:stop:num with num at most 4"]


def test_a_good_form_makes_the_job_the_api_would(server, session):
    r = session.post("/new", data={"E0": "0.3:0.6:2", "IOP": "12, 18", "thickness": "",
                                   "resolution": "coarse", "t_end": "2"})
    assert r.status_code == 303
    job_id = r.headers["location"].rsplit("/", 1)[1]
    with server.client() as api:
        job = api.get(f"/sweeps/{job_id}").json()
        same = api.post("/sweeps", json={"E0": [0.3, 0.6], "IOP": [12, 18],
                                         "resolution": "coarse", "t_end": 2.0}).json()
        twin = api.get(f"/sweeps/{same['id']}").json()
    assert job["status"] == "queued" and job["points_total"] == 4
    assert job["request"] == twin["request"]
    page = session.get(f"/jobs/{job_id}")
    assert page.status_code == 200 and "queued" in page.text
    assert f'data-watch="/sweeps/{job_id}"' in page.text  # refreshes while queued
    assert "t_end" in page.text and "<td>ms</td>" in page.text
    listing = session.get("/")
    assert f'href="/jobs/{job_id}"' in listing.text and 'data-watch="/sweeps?limit=100"' in listing.text
    # no figure before a point is done
    assert session.get(f"/jobs/{job_id}/figures/ora-P1.png").status_code == 404
    assert session.get(f"/jobs/{job_id}/figures/..%2F..%2Fairpuff.db.png").status_code == 404


def test_the_cornea_follows_the_model_unless_chosen(server, session):
    """The cornea's select offers 'from model' first, selected: left there, the form sends no
    cornea and the model preset decides, as a POST /sweeps without the key does."""
    page = session.get("/new")
    assert ('<option value="">from model: membrane (paper), shell (clinical), '
            'shell (clinical_published)</option>'
            in page.text)
    r = session.post("/new", data={"E0": "0.5", "model": "clinical", "cornea": "", "t_end": "2"})
    assert r.status_code == 303
    job_id = r.headers["location"].rsplit("/", 1)[1]
    with server.client() as api:
        job = api.get(f"/sweeps/{job_id}").json()
        same = api.post("/sweeps", json={"E0": [0.5], "model": "clinical", "t_end": 2.0}).json()
        twin = api.get(f"/sweeps/{same['id']}").json()
    assert job["request"] == twin["request"]


def test_every_page_needs_the_token(server):
    with httpx.Client(base_url=server.url, timeout=30) as anon:
        for path in ("/", "/new", "/jobs/x", "/jobs/x/figures/ora-P1.png"):
            r = anon.get(path)
            assert r.status_code == 303 and r.headers["location"].startswith("/login"), path
        assert anon.post("/new", data={"E0": "0.5"}).status_code == 303
        r = anon.post("/login", data={"token": "wrong", "next": "/"})
        assert r.status_code == 401 and "wrong token" in r.text and "set-cookie" not in r.headers
        # a forged cookie does not open anything
        anon.cookies.set("airpuff_session", "0" * 64)
        assert anon.get("/").status_code == 303
        assert anon.get("/sweeps").status_code == 401


def test_cookie_opens_reads_not_writes(server, session):
    assert session.get("/sweeps").status_code == 200
    assert session.post("/sweeps", json={}).status_code == 401
    assert session.delete("/sweeps/x").status_code == 401
    # a form posted from another site is refused even with the cookie
    r = session.post("/new", data={"E0": "0.5"}, headers={"Origin": "http://evil.example"})
    assert r.status_code == 403
    r = session.post("/logout")
    assert r.status_code == 303 and 'airpuff_session=""' in r.headers["set-cookie"]


def test_forms_take_form_bodies_and_the_session_is_checked_before_the_body(server):
    # the pages' forms take what a browser sends; JSON (or anything else) is refused by name
    with httpx.Client(base_url=server.url, timeout=30) as c:
        assert c.post("/login", data={"token": TOKEN}).status_code == 303
        r = c.post("/new", json={"E0": "0.5"})
        assert r.status_code == 415 and "application/x-www-form-urlencoded" in r.text, r.text
        assert r.json()["detail"][0]["field"] == "content-type"
    # ... and the API still takes JSON only, even with the bearer header
    with server.client() as api:
        r = api.post("/sweeps", data={"E0": "0.5"})
        assert r.status_code == 415 and "application/json" in r.text, r.text
    # without the session, a form's body is never read: a body above the limit is not the
    # reason given (413) -- the login form is
    with httpx.Client(base_url=server.url, timeout=30) as anon:
        big = {"E0": "1" * 2_000_000}
        r = anon.post("/new", data=big)
        assert r.status_code == 303 and r.headers["location"] == "/login?next=%2Fnew"
        # the login form is open, and its body is bounded like every other
        assert anon.post("/login", data=big).status_code == 413


def test_request_text_is_escaped(server):
    with httpx.Client(base_url=server.url, timeout=30) as c:
        c.post("/login", data={"token": TOKEN})
        r = c.get("/jobs/<script>alert(1)")
        assert r.status_code == 404 and "<script>alert" not in r.text
        assert "&lt;script&gt;alert(1)" in r.text
        r = c.post("/new", data={"E0": '"><img src=x onerror=alert(1)>'})
        assert '<img src=x' not in r.text and "&quot;&gt;&lt;img src=x" in r.text
    with httpx.Client(base_url=server.url, timeout=30) as anon:
        r = anon.get("/login", params={"next": '/"><script>x</script>'})
        assert "<script>x" not in r.text
        # only local paths are followed after logging in
        r = anon.post("/login", data={"token": TOKEN, "next": "//evil.example/"})
        assert r.headers["location"] == "/"


def test_pages_without_a_token(tmp_path):
    with ServerProcess(tmp_path / "data", "--no-runner").running() as s, \
            httpx.Client(base_url=s.url, timeout=30) as c:
        assert c.get("/").status_code == 200
        assert "No jobs yet" in c.get("/").text
        assert c.get("/new").status_code == 200
        assert c.get("/login").status_code == 303
