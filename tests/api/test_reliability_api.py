"""Stored results that can be trusted, on the `airpuff serve` side.

A real `airpuff serve` (uvicorn on a loopback port) with a Dask cluster of two worker processes
and the real solver (coarse, t_end 1 ms); point files damaged the way a crash or a full disk
leaves them; the job database read back with sqlite3.  The checks of requests that need no
computation run against a second server started with a token and ``--no-runner``.
"""

from __future__ import annotations

import json
import os
import re
import sqlite3
import subprocess
import sys
import time

import pytest

from airpuff_core.dataset import open_dataset
from airpuff_core.params import MAX_HISTORY_INTERVALS, RunParams
from airpuff_core.provenance import model_version
from api.runner import INFRASTRUCTURE_RETRIES
from sweep.storage import DAMAGED_SUBDIR, point_key, point_path
from tests.api.support import REPO, ServerProcess, submit, wait_job

pytestmark = pytest.mark.service

OPTIONS = {"resolution": "coarse", "t_end": 1.0}
BASE = {"IOP": [15.0], "thickness": [0.5], "pmax": [10.0], **OPTIONS}
ABSOLUTE = re.compile(r"(?<![\w.~-])/(?:[^\s'\"/:]+/)+")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with ServerProcess(tmp_path_factory.mktemp("reliable") / "data", "--workers", "2").running(
            wait_runner=True) as s:
        yield s


def key_of(body: dict, E0: float) -> str:
    values = {k: (v[0] if isinstance(v, list) else v) for k, v in body.items()}
    return point_key(RunParams.from_dict({**values, "E0": E0}))


def points_of(client, job_id) -> dict[float, dict]:
    return {p["E0"]: p for p in client.get(f"/sweeps/{job_id}/metrics").json()["points"]}


def submissions(server, key) -> int:
    con = sqlite3.connect(server.data_dir / "airpuff.db")
    try:
        return con.execute("SELECT submissions FROM points WHERE key = ?", (key,)).fetchone()[0]
    finally:
        con.close()


@pytest.mark.cluster
def test_damaged_point_files_are_set_aside_and_recomputed(client, server, tmp_path):
    """Items 1 and 2 (and the provenance of item 3 in the downloaded dataset): a recorded point
    file truncated to half, and garbage under the key of a point not yet recorded, are moved
    aside with a record and computed again; the job ends done, /health shows no error."""
    first = {**BASE, "E0": [0.35, 0.65]}
    job1 = wait_job(client, submit(client, first), timeout=240)
    assert job1["status"] == "done", job1
    points = server.data_dir / "points"
    recorded = point_path(points, key_of(first, 0.35))
    with open(recorded, "r+b") as fh:
        fh.truncate(recorded.stat().st_size // 2)
    unrecorded = point_path(points, key_of(first, 0.5))
    unrecorded.write_bytes(b"\x89HDF\r\n\x1a\n" + os.urandom(50_000))

    second = {**BASE, "E0": [0.35, 0.5, 0.65]}
    job2 = wait_job(client, submit(client, second), timeout=240)
    assert job2["status"] == "done" and job2["points_failed"] == 0, job2
    recs = points_of(client, job2["id"])
    assert all(p["status"] == "ok" for p in recs.values()), recs
    assert not recs[0.35]["reused"] and not recs[0.5]["reused"] and recs[0.65]["reused"]
    moved = [json.loads(p.read_text()) for p in (points / DAMAGED_SUBDIR).glob("*.json")]
    assert sorted(r["key"] for r in moved) == sorted([key_of(first, 0.35), key_of(first, 0.5)])
    health = client.get("/health").json()
    assert health["runner"] == "ready" and health["runner_error"] is None, health

    r = client.get(f"/sweeps/{job2['id']}/dataset")
    assert r.status_code == 200
    path = tmp_path / "sweep.nc"
    path.write_bytes(r.content)
    with open_dataset(path) as ds:
        assert list(ds["status"].values.ravel()) == ["ok"] * 3
        assert set(ds["model_version"].values.ravel()) == {model_version()}
        assert json.loads(str(ds["provenance"].values.ravel()[0]))["dask_version"]
        assert not os.path.isabs(ds.attrs["point_files"])
        assert str(server.data_dir) not in json.dumps(dict(ds.attrs), default=str)
    # the first job's grid again: all three files read back fine now
    job3 = wait_job(client, submit(client, first), timeout=240)
    assert job3["status"] == "done" and job3["points_reused"] == 2, job3


@pytest.mark.cluster
def test_a_file_damaged_while_its_job_runs_is_recomputed_when_combining(client, server):
    """Item 2: a stored point passes the check when its job starts, then its file is truncated
    while the job's other points compute; combining finds it, sets it aside and computes it
    again, and the job ends done."""
    body = {**BASE, "IOP": [17.0], "E0": [0.4]}
    assert wait_job(client, submit(client, body), timeout=240)["status"] == "done"
    stored = point_path(server.data_dir / "points", key_of(body, 0.4))
    job_id = submit(client, {**body, "E0": [0.4, 0.42, 0.44, 0.46, 0.48]})
    running = wait_job(client, job_id, until=("running", "done", "failed"), poll=0.05)
    assert running["status"] == "running" and running["points_done"] < 5, running
    with open(stored, "r+b") as fh:
        fh.truncate(1000)
    job = wait_job(client, job_id, timeout=240)
    assert job["status"] == "done" and job["points_done"] == 5, job
    assert points_of(client, job_id)[0.4]["reused"] is False
    moved = [json.loads(p.read_text())["key"]
             for p in (server.data_dir / "points" / DAMAGED_SUBDIR).glob("*.json")]
    assert key_of(body, 0.4) in moved


@pytest.mark.cluster
def test_model_and_infrastructure_failures(client, server):
    """Item 6: a write error of the server (a directory where the point file goes: an OSError
    as from a full disk) is retried automatically, then recorded, and computed again by the
    next job; the solver's verdict (a 10 um cornea) is reused unless retry_failed is asked."""
    infra_body = {**BASE, "E0": [0.45]}
    infra_key = key_of(infra_body, 0.45)
    blocker = point_path(server.data_dir / "points", infra_key)
    blocker.mkdir(parents=True)
    job = wait_job(client, submit(client, infra_body), timeout=240)
    assert job["status"] == "failed", job
    (rec,) = points_of(client, job["id"]).values()
    assert "IsADirectoryError" in rec["message"] and not ABSOLUTE.search(rec["message"]), rec
    assert submissions(server, infra_key) == 1 + INFRASTRUCTURE_RETRIES
    blocker.rmdir()
    job = wait_job(client, submit(client, infra_body), timeout=240)
    assert job["status"] == "done", job
    (rec,) = points_of(client, job["id"]).values()
    assert rec["status"] == "ok" and rec["reused"] is False

    model_body = {**BASE, "E0": [0.5], "thickness": [0.01]}
    model_key = key_of(model_body, 0.5)
    for retry_failed, reused, runs in ((False, False, 1), (False, True, 1), (True, False, 2)):
        job = wait_job(client, submit(client, {**model_body, "retry_failed": retry_failed}),
                       timeout=240)
        assert job["status"] == "failed" and job["retry_failed"] is retry_failed, job
        (rec,) = points_of(client, job["id"]).values()
        assert rec["status"] == "failed" and rec["reused"] is reused, rec
        assert submissions(server, model_key) == runs


@pytest.mark.cluster
def test_job_error_carries_no_server_path_and_delete_removes_ended_jobs(client, server):
    """Item 7: a job whose combined file cannot be written fails with an error that names no
    path of the server; DELETE removes an ended job with its folder (and still cancels a
    queued or running one)."""
    job_id = submit(client, {**BASE, "E0": [0.55]})
    (server.data_dir / "jobs" / job_id).write_text("not a folder")  # the job's folder is taken
    job = wait_job(client, job_id, timeout=240)
    assert job["status"] == "failed" and "combining" in job["error"], job
    assert not ABSOLUTE.search(job["error"]) and str(server.data_dir) not in job["error"], job
    assert str(server.data_dir) not in client.get("/health").text
    (server.data_dir / "jobs" / job_id).unlink()

    done = wait_job(client, submit(client, {**BASE, "E0": [0.55]}), timeout=240)
    folder = server.data_dir / "jobs" / done["id"]
    assert done["status"] == "done" and (folder / "sweep.nc").is_file()
    r = client.delete(f"/sweeps/{done['id']}")
    assert r.status_code == 204, r.text
    assert client.get(f"/sweeps/{done['id']}").status_code == 404
    assert not folder.exists()
    assert point_path(server.data_dir / "points", key_of(BASE, 0.55)).is_file()  # shared
    assert client.delete(f"/sweeps/{done['id']}").status_code == 404

    queued = submit(client, {**BASE, "E0": [0.3, 0.7], "IOP": [11.0, 13.0, 19.0]})
    r = client.delete(f"/sweeps/{queued}")
    assert r.status_code == 200 and r.json()["status"] == "cancelled", r.text
    assert client.delete(f"/sweeps/{queued}").status_code == 204


@pytest.mark.cluster
def test_stale_temporary_files_are_removed_at_start_up(server):
    """Item 7: a kill during a write leaves `.<name>.<random>.tmp`; the next server removes
    them (it holds runner.lock, so no other writer exists)."""
    server.stop()
    jobs = server.data_dir / "jobs" / "0123abcd"
    jobs.mkdir(parents=True, exist_ok=True)
    stale = [jobs / ".sweep.nc.x1y2z3.tmp", server.data_dir / "points" / ".abcd.nc.q9w8.tmp"]
    for p in stale:
        p.write_bytes(b"\x89HDF half")
    server.url = None  # a new port, printed into a new log
    server.log_path = server.log_path.with_name(server.log_path.stem + "-restarted.log")
    server.start(wait_runner=True)
    assert not any(p.exists() for p in stale)


# -- requests that need no computation ------------------------------------------------------------

TOKEN = "tok-3f9a2c"


@pytest.fixture(scope="module")
def guarded(tmp_path_factory):
    with ServerProcess(tmp_path_factory.mktemp("guarded") / "data", "--no-runner",
                       token=TOKEN).running() as s:
        yield s


def test_token_is_checked_before_the_body_and_docs_load_their_schema(guarded):
    with guarded.client(token=None) as anon:
        r = anon.post("/sweeps", content=b"{not json", headers={"content-type": "application/json"})
        assert r.status_code == 401, r.text
        assert anon.post("/sweeps", content=b"x" * 100, headers={
            "content-type": "text/plain"}).status_code == 401
        docs = anon.get("/docs")
        assert docs.status_code == 200 and "/openapi.json" in docs.text
        schema = anon.get("/openapi.json")
        assert schema.status_code == 200 and schema.json()["components"]["securitySchemes"]
        assert anon.get("/sweeps").status_code == 401


def test_bodies_are_reported_readably(guarded):
    with guarded.client() as c:
        r = c.post("/sweeps", content=b'{\n  "E0": [0.5,]\n}',
                   headers={"content-type": "application/json"})
        assert r.status_code == 422, r.text
        (err,) = r.json()["detail"]
        assert err["loc"] == ["body"] and "line 2, column" in err["msg"], err
        r = c.post("/sweeps", content=json.dumps({"E0": [0.5]}).encode(),
                   headers={"content-type": "text/plain"})
        assert r.status_code == 415 and "content-type" in r.text, r.text
        r = c.post("/sweeps", content=json.dumps({"E0": [0.5]}).encode("utf-16"),
                   headers={"content-type": "application/json"})
        assert r.status_code == 422 and "UTF-8" in r.text, r.text
        r = c.post("/sweeps", content=json.dumps({"E0": [0.5]}).encode("utf-16-le"),
                   headers={"content-type": "application/json"})
        assert r.status_code == 422, r.text
        assert c.get("/sweeps").json()["total"] == 0  # none of them was stored


def test_history_sample_count_is_bounded(guarded):
    """Item 4: t_end / output_interval is bounded at every edge (RunParams)."""
    with guarded.client() as c:
        r = c.post("/sweeps", json={"E0": [0.5], "t_end": 10000.0, "output_interval": 1e-9})
        assert r.status_code == 422, r.text
        (err,) = r.json()["detail"]
        assert err["field"] == "output_interval", err
        assert "t_end" in err["msg"] and str(MAX_HISTORY_INTERVALS) in err["msg"], err
    p = run_cli("run", "--t-end", "3", "--output-interval", "1e-6", "--resolution", "coarse")
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert "output_interval" in p.stderr and "t_end" in p.stderr, p.stderr


def run_cli(*args, env_extra=None, timeout=120):
    env = dict(os.environ)
    env.pop("AIRPUFF_API_TOKEN", None)
    env.update(env_extra or {})
    return subprocess.run([sys.executable, "-m", "api.cli", *args], capture_output=True,
                          text=True, timeout=timeout, cwd=REPO, env=env)


@pytest.mark.parametrize("token", [" padded-token ", "t\u00f6ken", "two words"])
def test_a_bad_token_stops_the_server_at_start_up(tmp_path, token):
    p = run_cli("serve", "--port", "0", "--no-runner", "--data-dir", str(tmp_path / "d"),
                env_extra={"AIRPUFF_API_TOKEN": token})
    assert p.returncode == 2, p.stderr
    (line,) = p.stderr.strip().splitlines()
    assert "AIRPUFF_API_TOKEN" in line and token.strip() not in line, line


def test_cli_grid_cap_and_strict_numbers(tmp_path):
    """Item 5: the CLI's grid cap answers before making the grid; item 7: `1_0` is no number."""
    out = str(tmp_path / "out")
    p = run_cli("sweep", "--IOP", "10:30:100000000", "--out", out, timeout=60)
    assert p.returncode == 2, p.stderr
    (line,) = p.stderr.strip().splitlines()
    assert "100000000 points" in line and "10000" in line and "--max-points" in line, line
    p = run_cli("sweep", "--E0", "0.4,0.5", "--IOP", "10:30:3", "--max-points", "5", "--out", out)
    assert p.returncode == 2 and "6 points" in p.stderr, p.stderr
    assert not os.path.exists(out)
    for args in (("run", "--E0", "1_0"), ("sweep", "--E0", "0.5,1_0", "--out", out),
                 ("sweep", "--t-end", "1_0", "--out", out)):
        p = run_cli(*args)
        assert p.returncode == 2, (args, p.stderr)
        (line,) = p.stderr.strip().splitlines()
        assert "1_0" in line and "accepted" in line, line
