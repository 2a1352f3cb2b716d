"""HTTP API without computation: validation, 404s, auth, binding, OpenAPI, schemathesis.

These servers run with ``--no-runner`` (jobs are stored and stay queued; no Dask cluster, no
solver), which is a supported deployment: a runner started later on the same data directory picks
the jobs up.  The computing side is in test_api_jobs.py and test_api_restart.py.
"""

from __future__ import annotations

import json
import socket
import sqlite3
import subprocess
import sys

import pytest

from airpuff_core.params import CHOICES, INT_PARAMETERS, PARAMETERS, PRESET_PARAMETERS, SWEPT
from airpuff_core.result import METRICS
from tests.api.support import ServerProcess, post_at_once

pytestmark = pytest.mark.service

MAX_POINTS = 50  # this server's --max-points: small, so schemathesis cannot queue big grids


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with ServerProcess(tmp_path_factory.mktemp("api") / "data", "--no-runner",
                       "--max-points", str(MAX_POINTS)).running() as s:
        yield s


GOOD = {"E0": [0.4, 0.6], "IOP": [12.0, 16.0, 20.0], "thickness": [0.5], "pmax": [10.0],
        "resolution": "coarse", "t_end": 3.0}


def test_binds_loopback_by_default(server):
    assert server.url.startswith("http://127.0.0.1:")
    port = int(server.url.rsplit(":", 1)[1])
    # The port is not reachable on this machine's other addresses.
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.connect(("10.255.255.255", 1))
        other = probe.getsockname()[0]
    except OSError:
        other = None
    finally:
        probe.close()
    if other is None or other.startswith("127."):
        pytest.skip("this machine has no non-loopback IPv4 address")
    with pytest.raises(OSError):
        socket.create_connection((other, port), timeout=2).close()


def test_health(client):
    r = client.get("/health")
    assert r.status_code == 200
    assert r.json()["status"] == "ok" and r.json()["runner"] == "disabled"


def test_submit_answers_202_with_location(client, server):
    r = client.post("/sweeps", json=GOOD)
    assert r.status_code == 202, r.text
    body = r.json()
    assert body["status"] == "queued"
    assert body["points_total"] == 2 * 3
    assert r.headers["location"] == f"/sweeps/{body['id']}"
    job = client.get(r.headers["location"]).json()
    assert job["id"] == body["id"] and job["status"] == "queued"
    assert job["points_total"] == 6 and job["points_done"] == 0 and job["points_failed"] == 0
    assert job["request"]["E0"] == GOOD["E0"] and job["request"]["t_end"] == GOOD["t_end"]
    assert job["started_at"] is None and job["created_at"].endswith("+00:00")
    # The grid is stored in C order over E0, IOP, thickness, pmax with its point keys.
    m = client.get(f"/sweeps/{body['id']}/metrics").json()
    got = [(p["E0"], p["IOP"]) for p in m["points"]]
    assert got == [(e, i) for e in GOOD["E0"] for i in GOOD["IOP"]]
    assert all(p["status"] == "pending" and p["P1"] is None for p in m["points"])
    assert len({p["key"] for p in m["points"]}) == 6
    assert m["units"]["E0"] == "MPa" and m["units"]["P1"] == "mmHg"
    # The job row is in the SQLite file in WAL mode.
    con = sqlite3.connect(server.data_dir / "airpuff.db")
    try:
        assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert con.execute("SELECT status FROM jobs WHERE id = ?", (body["id"],)).fetchone() == \
            ("queued",)
    finally:
        con.close()


def test_list_is_newest_first(client):
    ids = [client.post("/sweeps", json={**GOOD, "E0": [0.1 * (k + 1)]}).json()["id"]
           for k in range(3)]
    listed = [j["id"] for j in client.get("/sweeps", params={"limit": 1000}).json()["jobs"]]
    assert [i for i in listed if i in ids] == ids[::-1]
    page = client.get("/sweeps", params={"limit": 2}).json()
    assert len(page["jobs"]) == 2 and page["total"] >= 3
    queued = client.get("/sweeps", params={"status": "queued"}).json()
    assert all(j["status"] == "queued" for j in queued["jobs"])


BAD = [
    ({"E0": [-0.5]}, "E0"),
    ({"E0": [0.0]}, "E0"),
    ({"IOP": ["abc"]}, "IOP"),
    ({"IOP": [True]}, "IOP"),
    ({"IOP": "16"}, "IOP"),
    ({"thickness": [5.0]}, "thickness"),
    ({"pmax": []}, "pmax"),
    ({"E0": [0.5, 0.5]}, "E0"),
    ({"resolution": "ultra"}, "resolution"),
    ({"geometry": 3}, "geometry"),
    ({"t_end": -1}, "t_end"),
    ({"t_end": "3"}, "t_end"),
    ({"mu": None}, "mu"),
    ({"max_coupling_iterations": 2.5}, "max_coupling_iterations"),
    ({"bogus": 1}, "bogus"),
    ({"options": {"t_end": 3}}, "options"),
    ({"R": 5.0, "r_post": 6.0}, "r_post"),  # cross-field: the support must lie inside the arc
    ({"cornea": "plate"}, "cornea"),
    ({"model": "clinic"}, "model"),
    ({"instrument": "nct"}, "instrument"),
    ({"instrument": "ora", "ora_delay": 25.0}, "ora_delay"),
    ({"instrument": "ora", "ora_rise_rate": 0.0}, "ora_rise_rate"),
    ({"instrument": "corvis", "pmax": [12.0]}, "pmax"),  # the paper's jet only
    ({"ora_delay": 3.0}, "ora_delay"),  # read by instrument=ora only
]


@pytest.mark.parametrize("patch,field", BAD, ids=[f"{f}-{json.dumps(p)[:30]}" for p, f in BAD])
def test_bad_input_is_422_naming_the_field(client, patch, field):
    r = client.post("/sweeps", json={**GOOD, **patch})
    assert r.status_code == 422, r.text
    errors = r.json()["detail"]
    assert any(e["loc"][:2] == ["body", field] and e["field"] == field and field in e["msg"]
               for e in errors), errors


def test_grid_above_max_points_is_422(client):
    n_e0 = MAX_POINTS // 2 + 1
    body = {**GOOD, "E0": [0.01 * (k + 1) for k in range(n_e0)], "IOP": [10.0, 20.0]}
    r = client.post("/sweeps", json=body)
    assert r.status_code == 422, r.text
    (err,) = r.json()["detail"]
    assert err["type"] == "grid_too_large" and "E0 x IOP" in err["msg"]
    assert str(2 * n_e0) in err["msg"] and str(MAX_POINTS) in err["msg"]
    # One point below the limit is accepted.
    body["E0"] = body["E0"][:MAX_POINTS // 2]
    assert client.post("/sweeps", json=body).status_code == 202


@pytest.mark.parametrize("content", [b"{", b"[1, 2]", b"null", b'{"E0": [NaN]}',
                                     b'{"E0": [1e999]}', b"\xff\xfe"])
def test_malformed_bodies_are_422(client, content):
    r = client.post("/sweeps", content=content, headers={"content-type": "application/json"})
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"][0] == "body"


def test_oversized_body_is_413(client):
    r = client.post("/sweeps", content=b'{"E0": [' + b"0.5, " * 300_000 + b"0.5]}",
                    headers={"content-type": "application/json"})
    assert r.status_code == 413


def test_bad_query_is_422(client):
    for params in ({"limit": 0}, {"limit": "x"}, {"offset": -1}, {"status": "sleeping"}):
        r = client.get("/sweeps", params=params)
        assert r.status_code == 422, (params, r.text)
        assert r.json()["detail"][0]["field"] == next(iter(params))


@pytest.mark.parametrize("method,suffix", [("GET", ""), ("GET", "/metrics"),
                                           ("GET", "/dataset"), ("DELETE", "")])
@pytest.mark.parametrize("job_id", ["0" * 32, "no-such-job", "..%2F..%2Fairpuff.db", "%00"])
def test_unknown_ids_are_404(client, method, suffix, job_id):
    r = client.request(method, f"/sweeps/{job_id}{suffix}")
    assert r.status_code == 404, r.text


def test_dataset_of_unfinished_job_is_409_and_cancel(client):
    job_id = client.post("/sweeps", json=GOOD).json()["id"]
    assert client.get(f"/sweeps/{job_id}/dataset").status_code == 409
    r = client.delete(f"/sweeps/{job_id}")
    assert r.status_code == 200 and r.json()["status"] == "cancelled"
    assert r.json()["finished_at"] is not None
    assert client.get(f"/sweeps/{job_id}").json()["status"] == "cancelled"
    points = client.get(f"/sweeps/{job_id}/metrics").json()["points"]
    assert {p["status"] for p in points} == {"cancelled"}
    assert client.get(f"/sweeps/{job_id}/dataset").status_code == 409
    # DELETE of an ended job removes it
    assert client.delete(f"/sweeps/{job_id}").status_code == 204
    assert client.get(f"/sweeps/{job_id}").status_code == 404


def test_identical_submissions_at_the_same_moment(client, server):
    results = post_at_once(server, [GOOD] * 4)
    assert all(r.status_code == 202 for r in results), [r.text for r in results]
    ids = [r.json()["id"] for r in results]
    assert len(set(ids)) == 4
    keys = [[p["key"] for p in client.get(f"/sweeps/{i}/metrics").json()["points"]] for i in ids]
    assert all(k == keys[0] for k in keys)  # identical parameters -> identical point keys


def test_openapi_documents_units_and_ranges(client):
    r = client.get("/openapi.json")
    assert r.status_code == 200
    schema = r.json()
    props = schema["components"]["schemas"]["SweepRequest"]["properties"]
    assert set(props) == set(PARAMETERS) | set(CHOICES) | set(INT_PARAMETERS) | {"retry_failed"}
    for name, spec in PARAMETERS.items():
        p = props[name]
        number = p["items"] if name in SWEPT else p
        if name in PRESET_PARAMETERS:  # a number or null (null: the model preset's value)
            number = next(a for a in p["anyOf"] if a.get("type") == "number")
        assert p["x-unit"] == spec.unit, name
        lo = "minimum" if spec.low_inclusive else "exclusiveMinimum"
        hi = "maximum" if spec.high_inclusive else "exclusiveMaximum"
        assert number[lo] == spec.low and number[hi] == spec.high, name
        assert spec.accepted() in p["description"], name
        if name in SWEPT:
            assert p["minItems"] == 1 and p["maxItems"] == MAX_POINTS
    for name, allowed in CHOICES.items():
        assert props[name]["enum"] == list(allowed)
    assert "bending rigidity" in props["cornea"]["description"]
    assert "from model: membrane (paper), shell (clinical)" in props["cornea"]["description"]
    record = schema["components"]["schemas"]["PointRecord"]["properties"]
    for name, (unit, _) in METRICS.items():
        assert f"[{unit}]" in record[name]["description"]
    assert "/sweeps/{job_id}/dataset" in schema["paths"]
    assert client.get("/docs").status_code == 200


def test_token_required_except_health_and_docs(tmp_path):
    token = "s3cret-token"
    s = ServerProcess(tmp_path / "data", "--no-runner", token=token).start()
    try:
        with s.client(token=None) as anon, s.client(token="wrong") as wrong, s.client() as ok:
            assert anon.get("/health").status_code == 200
            job = ok.post("/sweeps", json=GOOD)
            assert job.status_code == 202
            jid = job.json()["id"]
            for method, path in [("GET", "/sweeps"), ("POST", "/sweeps"), ("GET", f"/sweeps/{jid}"),
                                 ("GET", f"/sweeps/{jid}/metrics"),
                                 ("GET", f"/sweeps/{jid}/dataset"), ("DELETE", f"/sweeps/{jid}")]:
                for c in (anon, wrong):
                    r = c.request(method, path, json=GOOD if method == "POST" else None)
                    assert r.status_code == 401, (method, path, r.status_code)
                    assert r.headers["www-authenticate"] == "Bearer"
            assert ok.get(f"/sweeps/{jid}").json()["status"] == "queued"  # not cancelled above
            # the docs page and the schema it loads are open (the browser sends no token)
            assert anon.get("/docs").status_code == 200
            assert anon.get("/openapi.json").json()["components"]["securitySchemes"]
    finally:
        s.stop()


def test_serve_cli_rejects_bad_options(tmp_path):
    for args in (["--port", "70000"], ["--port", "x"], ["--workers", "0"], ["--max-points", "0"],
                 ["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"]):
        p = subprocess.run([sys.executable, "-m", "api.cli", "serve", "--data-dir",
                            str(tmp_path / "d"), *args], capture_output=True, text=True,
                           timeout=60)
        assert p.returncode == 2, (args, p.stderr)
        assert len(p.stderr.strip().splitlines()) == 1, p.stderr
        assert args[0] in p.stderr or "not allowed" in p.stderr


def test_busy_port_is_reported(tmp_path, server):
    port = server.url.rsplit(":", 1)[1]
    p = subprocess.run([sys.executable, "-m", "api.cli", "serve", "--no-runner", "--port", port,
                        "--data-dir", str(tmp_path / "d")], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 1 and "cannot listen" in p.stderr, p.stderr


def test_body_limit_is_documented_and_answered(server):
    with server.client() as c:
        schema = c.get("/openapi.json").json()
        bodies = [(path, method) for path, ops in schema["paths"].items()
                  for method, op in ops.items() if "requestBody" in op]
        assert ("/sweeps", "post") in bodies and len(bodies) >= 4
        for path, method in bodies:
            assert "413" in schema["paths"][path][method]["responses"], (path, method)
        r = c.post("/sweeps", content=b" " * 1_000_001, headers={"content-type": "application/json"})
        assert r.status_code == 413, r.text


@pytest.mark.slow
def test_schemathesis_finds_no_server_error(server, tmp_path):
    """Property-based run over the whole OpenAPI schema (bounded in time)."""
    exe = [sys.executable, "-m", "schemathesis.cli"]
    cmd = [*exe, "run", f"{server.url}/openapi.json",
           "--checks", "not_a_server_error,status_code_conformance,content_type_conformance,"
                       "response_schema_conformance,negative_data_rejection",
           "--max-time", "30", "--workers", "1", "--request-timeout", "20",
           "--suppress-health-check", "all", "--max-failures", "5"]
    # A body above the service's size limit is refused with 413 (documented per operation): a rejection
    (tmp_path / "schemathesis.toml").write_text(
        "[checks.negative_data_rejection]\n"
        'expected-statuses = ["400", "401", "403", "404", "406", "413", "415", "422", "428"]\n')
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=240, cwd=tmp_path)
    out = p.stdout + p.stderr
    assert p.returncode == 0, out[-6000:]
    # It did exercise the API (and nothing in the server log is a traceback).
    with server.client() as c:
        assert c.get("/sweeps").json()["total"] > 0
    assert "Traceback" not in server.log_text(), server.log_text()[-4000:]
