"""A service that one request cannot block (issue 30, items 3, 4, 5, 7, 8, 9 and 10).

Real `airpuff serve` processes on loopback ports (one without a runner and without a token, as
the default set-up an attacker meets; one with a token and a Dask cluster of one worker process
for the items that need computed points), real `airpuff sweep` and `airpuff run` processes, real
SQLite files damaged on disk, real netCDF files read back with plain xarray.
"""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
import threading
import time

import httpx
import numpy as np
import pytest
import xarray as xr

from api import auth
from api.app import MAX_ERRORS
from api.db import SCHEMA_VERSION
from sweep.storage import DAMAGED_SUBDIR, point_path
from tests.api.support import REPO, ServerProcess, post_at_once, submit, wait_job

pytestmark = pytest.mark.service

COARSE = {"resolution": "coarse", "t_end": 1.0}
TOKEN = "tok-issue30"


def run_cli(*args, env_extra=None, timeout=300):
    env = dict(os.environ)
    env.pop("AIRPUFF_API_TOKEN", None)
    env.pop("AIRPUFF_ALLOWED_HOSTS", None)
    env.update(env_extra or {})
    return subprocess.run([sys.executable, "-m", "api.cli", *args], capture_output=True,
                          text=True, timeout=timeout, cwd=REPO, env=env)


def one_line(stderr: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    return lines[0]


@pytest.fixture(scope="module")
def open_server(tmp_path_factory):
    """The default set-up: no token, loopback, API only; one extra name allowed."""
    with ServerProcess(tmp_path_factory.mktemp("open") / "data", "--no-runner",
                       "--allowed-hosts", "airpuff.example").running() as s:
        yield s


# -- item 3: a body of 60,000 unknown keys ----------------------------------------------------------

def test_unknown_keys_are_refused_early_and_the_errors_capped_while_health_answers(open_server):
    """Three bodies of 60,000 unknown keys each (840 kB) at once: each gets a short 422
    (at most MAX_ERRORS errors and a count of the rest), and /health keeps answering meanwhile
    (it stalled for 6.3 s with the errors built and described on the event loop)."""
    body = json.dumps({f"key{i:05d}": 0 for i in range(60_000)}).encode()
    answers: list[httpx.Response] = []
    seconds: list[float] = []

    def post():
        with open_server.client(timeout=120) as c:
            t0 = time.monotonic()
            answers.append(c.post("/sweeps", content=body,
                                  headers={"content-type": "application/json"}))
            seconds.append(time.monotonic() - t0)

    threads = [threading.Thread(target=post) for _ in range(3)]
    health_latency = []
    with open_server.client(timeout=120) as c:
        for t in threads:
            t.start()
        while any(t.is_alive() for t in threads):
            t0 = time.monotonic()
            assert c.get("/health").status_code == 200
            health_latency.append(time.monotonic() - t0)
            time.sleep(0.02)
        for t in threads:
            t.join()
    print(f"\n60,000 unknown keys ({len(body)} bytes), 3 at once: 422 of "
          f"{[len(r.content) for r in answers]} bytes in {[round(s, 3) for s in seconds]} s; "
          f"/health meanwhile: {len(health_latency)} answers, slowest {max(health_latency):.3f} s")
    for r in answers:
        assert r.status_code == 422, r.text[:300]
        detail = r.json()["detail"]
        assert len(detail) == MAX_ERRORS + 1 and len(r.content) < 50_000, len(r.content)
        assert detail[0]["field"] == "key00000" and "accepted keys are E0" in \
            detail[0]["msg"], detail[0]
        assert "59980 more errors" in detail[-1]["msg"] and "60000 in all" in detail[-1]["msg"]
    assert max(health_latency) < 1.0, health_latency  # a liveness bound, 6x below the stall

    # many errors of known keys are capped the same way, every JSON body of the API is checked
    # so, and nothing was stored
    with open_server.client() as c:
        for path in ("/identify", f"/sweeps/{'0' * 32}/corrections",
                     f"/sweeps/{'0' * 32}/corrections/c1/apply"):
            r = c.post(path, content=body, headers={"content-type": "application/json"})
            assert r.status_code == 422 and len(r.json()["detail"]) == MAX_ERRORS + 1, \
                (path, r.status_code, len(r.content))
        r = c.post("/sweeps", json={"E0": [-1.0 - i for i in range(5000)]})
        assert r.status_code == 422 and len(r.json()["detail"]) == MAX_ERRORS + 1, r.text[:300]
        assert r.json()["detail"][0]["field"] == "E0" and "(0, 50] MPa" in \
            r.json()["detail"][0]["msg"]
        assert c.get("/sweeps").json()["total"] == 0


# -- item 4: DNS rebinding and framing --------------------------------------------------------------

def test_host_header_is_checked_and_pages_cannot_be_framed(open_server):
    """A request naming the server by another name (a DNS rebinding page: Host and a matching
    Origin of attacker.example) is refused with 400 on every path; localhost, the bound address
    and the --allowed-hosts name are served; every answer forbids framing."""
    port = open_server.url.rsplit(":", 1)[1]
    evil = {"host": f"attacker.example:{port}", "origin": f"http://attacker.example:{port}"}
    with open_server.client() as c:
        for method, path, kw in (("POST", "/sweeps", {"json": {"E0": [0.5]}}),
                                 ("GET", "/sweeps", {}), ("GET", "/health", {}),
                                 ("GET", "/", {}), ("GET", "/docs", {}),
                                 ("POST", "/new", {"content": b"E0=0.5", "headers": {
                                     "content-type": "application/x-www-form-urlencoded"}})):
            headers = {**kw.pop("headers", {}), **evil}
            r = c.request(method, path, headers=headers, **kw)
            assert r.status_code == 400, (method, path, r.status_code, r.text[:200])
            assert r.json()["detail"][0]["field"] == "host" and "localhost" in r.text
        assert c.get("/sweeps").json()["total"] == 0  # nothing was submitted
        for host in (f"localhost:{port}", f"127.0.0.1:{port}", "LOCALHOST", "airpuff.example"):
            assert c.get("/health", headers={"host": host}).status_code == 200, host
        for path in ("/", "/new", "/health", "/sweeps", "/jobs/nothing", "/docs"):
            r = c.get(path)
            assert r.headers["x-frame-options"] == "DENY", path
            assert "frame-ancestors 'none'" in r.headers["content-security-policy"], path


# -- item 5: the model hash computed by racing threads ----------------------------------------------

@pytest.mark.slow
def test_simultaneous_posts_right_after_start_all_succeed(tmp_path):
    """Six POSTs at once to a server that has just started, three times: every one is a 202
    (computing the model version lazily in six threads at once raised SystemError: AST
    constructor recursion depth mismatch, a 500)."""
    for trial in range(3):
        server = ServerProcess(tmp_path / f"data{trial}", "--no-runner")
        with server.running():
            answers = post_at_once(server, [{"E0": [0.3 + 0.05 * k], **COARSE}
                                            for k in range(6)])
            assert [r.status_code for r in answers] == [202] * 6, \
                [(r.status_code, r.text[:200]) for r in answers]


# -- item 7: a damaged or newer job database --------------------------------------------------------

def filled_database(data_dir) -> "os.PathLike":
    """A job database of several pages (one job of 1,500 points), as a server leaves it."""
    from api import db

    path = data_dir / "airpuff.db"
    db.init(path)
    con = db.connect(path)
    rows = [(f"{i:032x}", 0.3, 10.0 + i * 1e-3, 0.5, 10.0) for i in range(1500)]
    db.insert_job(con, "0" * 32, {"E0": [0.3], "IOP": [10.0], "thickness": [0.5],
                                 "pmax": [10.0], "options": {}}, rows)
    con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    con.close()
    return path


def serve_briefly(data_dir, timeout=60.0) -> tuple[int | None, str]:
    """Start `airpuff serve --no-runner` on ``data_dir``: (exit code, stderr) if it stopped by
    itself within ``timeout`` s, else (None, stderr so far) after stopping it."""
    env = dict(os.environ)
    env.pop("AIRPUFF_API_TOKEN", None)
    proc = subprocess.Popen([sys.executable, "-m", "api.cli", "serve", "--port", "0",
                             "--no-runner", "--data-dir", str(data_dir)], cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        _, err = proc.communicate(timeout=timeout)
        return proc.returncode, err
    except subprocess.TimeoutExpired:
        proc.terminate()
        _, err = proc.communicate(timeout=60)
        return None, err


@pytest.mark.parametrize("damage", ["overwritten", "truncated", "garbage"])
def test_a_damaged_database_stops_the_server_with_one_line(tmp_path, damage):
    data = tmp_path / "data"
    data.mkdir()
    path = filled_database(data)
    size = path.stat().st_size
    if damage == "overwritten":  # pages in the middle of the file overwritten
        with open(path, "r+b") as fh:
            fh.seek(size // 2)
            fh.write(os.urandom(8192))
    elif damage == "truncated":
        with open(path, "r+b") as fh:
            fh.truncate(size // 3)
    else:
        path.write_bytes(os.urandom(size))
    code, err = serve_briefly(data)
    assert code == 1, (code, err[-2000:])
    line = one_line(err)
    assert str(path) in line and "damaged" in line and "move it aside" in line, line


def test_a_newer_schema_is_refused_never_downgraded(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    path = filled_database(data)
    con = sqlite3.connect(path)
    con.execute(f"PRAGMA user_version={SCHEMA_VERSION + 1}")
    con.close()
    code, err = serve_briefly(data)
    assert code == 1, (code, err[-2000:])
    line = one_line(err)
    assert str(path) in line and f"schema version {SCHEMA_VERSION + 1}" in line, line
    con = sqlite3.connect(path)
    assert con.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION + 1
    con.close()


# -- items 8 and 9: two sweeps into one folder; times read back exactly -----------------------------

FINE_OUTPUT = ("--t-end", "1", "--output-interval", "1e-5", "--resolution", "coarse")


@pytest.fixture(scope="module")
def two_sweeps(tmp_path_factory):
    """`airpuff sweep` into OUT (one point, histories every 1e-5 ms), and while it runs a second
    one into the same OUT: (OUT, first process's result, second's)."""
    out = tmp_path_factory.mktemp("two-sweeps") / "out"
    env = dict(os.environ)
    env.pop("AIRPUFF_API_TOKEN", None)
    first = subprocess.Popen([sys.executable, "-m", "api.cli", "sweep", "--E0", "0.5",
                              "--workers", "1", "--out", str(out), "--json", *FINE_OUTPUT],
                             cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    deadline = time.monotonic() + 120
    while not out.is_dir() and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    second = run_cli("sweep", "--E0", "0.5", "--workers", "1", "--out", str(out), "--json",
                     *FINE_OUTPUT)
    stdout, stderr = first.communicate(timeout=600)
    return out, (first.returncode, stdout, stderr), second


@pytest.mark.cluster
@pytest.mark.slow
def test_a_second_sweep_into_the_same_out_is_refused(two_sweeps):
    out, (code, stdout, stderr), second = two_sweeps
    assert code == 0, stderr
    assert second.returncode == 2, (second.returncode, second.stdout, second.stderr)
    line = one_line(second.stderr)
    assert "another airpuff sweep" in line and "--out" in line and "sweep.lock" in line, line
    # the second run wrote nothing: sweep.nc and sweep.json are the first's
    assert json.loads(stdout)["computed"] == 1


def plain_times(path) -> np.ndarray:
    """``time`` as plain ``xr.open_dataset`` decodes it, in ns since its first value."""
    with xr.open_dataset(path) as ds:
        t = ds["time"].values
    assert t.dtype.kind == "M", t.dtype  # decoded into dates (CF time axis)
    return (t - t[0]).astype("timedelta64[ns]").astype(np.int64)


@pytest.mark.cluster
def test_plain_xarray_decodes_every_time_exactly(two_sweeps, tmp_path):
    """Histories every 1e-5 ms over 1 ms: the run file and sweep.nc decode into 100,001 distinct
    times, 10 ns apart exactly (they decoded into 1,001 distinct values)."""
    out = two_sweeps[0]
    run_nc = tmp_path / "run.nc"
    p = run_cli("run", *FINE_OUTPUT, "--out", str(run_nc))
    assert p.returncode == 0, p.stderr
    expected = 10 * np.arange(100_001, dtype=np.int64)
    for path in (run_nc, out / "sweep.nc"):
        ns = plain_times(path)
        assert ns.size == 100_001 and np.array_equal(ns, expected), (path, ns[:5])
    # an interval whose products t * 1e6 fall below their integers (0.0137 ms: 31 of them)
    from airpuff_core.dataset import time_coordinate

    t = np.arange(5000) * 0.0137
    path = tmp_path / "t.nc"
    xr.Dataset(coords={"time": time_coordinate(t)}).to_netcdf(
        path, encoding={"time": {"_FillValue": None}})
    assert np.array_equal(plain_times(path), 13_700 * np.arange(5000, dtype=np.int64))
    with xr.open_dataset(path, decode_times=False) as ds:  # and in ms as written, to 1e-16
        np.testing.assert_allclose(ds["time"].values, t, rtol=1e-15, atol=0)


# -- item 10 ----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def runner_server(tmp_path_factory):
    """A server with a token and one worker process; stray temporary files of killed writes in
    a job's figures/ and in points/damaged/ before it starts."""
    data = tmp_path_factory.mktemp("runner") / "data"
    stray = [data / "jobs" / "0123abcd" / "figures" / ".ora-P1.png.k2j3.tmp",
             data / "jobs" / "0123abcd" / "figures" / ".history-0.png.77-1401.tmp",
             data / "points" / DAMAGED_SUBDIR / ".abcd.nc.20260101.json.x9y8.tmp"]
    for p in stray:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"half written")
    with ServerProcess(data, "--workers", "1", token=TOKEN).running(wait_runner=True) as s:
        s.stray = stray
        yield s


@pytest.mark.cluster
def test_stray_temporary_files_of_figures_and_damaged_points_are_removed(runner_server):
    assert not any(p.exists() for p in runner_server.stray), runner_server.stray


@pytest.mark.cluster
@pytest.mark.slow
def test_history_of_a_damaged_point_is_set_aside_and_says_so(runner_server):
    with runner_server.client() as c:
        job = wait_job(c, submit(c, {"E0": [0.45], **COARSE}), timeout=300)
        assert job["status"] == "done", job
        key = c.get(f"/sweeps/{job['id']}/metrics").json()["points"][0]["key"]
        stored = point_path(runner_server.data_dir / "points", key)
        with open(stored, "r+b") as fh:
            fh.truncate(stored.stat().st_size // 2)
        figure = f"/jobs/{job['id']}/figures/history-0.png"
        c.cookies.set(auth.SESSION_COOKIE, auth.session_value(TOKEN))  # the pages' login
        r = c.get(figure)
        assert r.status_code == 404 and "could not be read" in r.text and \
            f"points/{DAMAGED_SUBDIR}/" in r.text, (r.status_code, r.text[-500:])
        assert not stored.exists()
        assert any((runner_server.data_dir / "points" / DAMAGED_SUBDIR).glob(stored.name + ".*"))
        assert str(runner_server.data_dir) not in r.text
        r = c.get(figure)
        assert r.status_code == 404 and "missing" in r.text, (r.status_code, r.text[-500:])


@pytest.mark.cluster
def test_points_reused_counts_a_reused_model_failure(runner_server):
    body = {"E0": [0.5], "thickness": [0.01], **COARSE}  # a 10 um cornea: the model fails
    with runner_server.client() as c:
        first = wait_job(c, submit(c, body), timeout=300)
        again = wait_job(c, submit(c, body), timeout=300)
    assert first["status"] == again["status"] == "failed", (first, again)
    assert (first["points_reused"], again["points_reused"]) == (0, 1), (first, again)


@pytest.mark.cluster
def test_health_without_the_token_tells_only_liveness(runner_server):
    with runner_server.client(token=None) as anon:
        health = anon.get("/health").json()
    assert health == {"status": "ok", "version": health["version"], "runner": "ready"}, health
    with runner_server.client() as c:
        health = c.get("/health").json()
    assert health["workers"] == 1 and "runner_error" in health, health


def test_a_tiny_sigma_names_its_range(open_server):
    with open_server.client() as c:
        r = c.post("/identify", json={"job_id": "0" * 32,
                                      "measurement": {"P1": {"value": 17.0, "sigma": 1e-300}}})
    assert r.status_code == 422, r.text
    (err,) = r.json()["detail"]
    assert err["loc"][-1] == "sigma" and "sigma" in err["msg"] and "0.000001" in err["msg"], err


@pytest.mark.parametrize("args", [("run", "--E0", "\uff10.\uff15"),
                                  ("run", "--IOP", "1\u0665"),  # an Arabic-Indic five
                                  ("sweep", "--IOP", "10:20:\uff13", "--out", "never"),
                                  ("sweep", "--E0", "0.5", "--workers", "\uff12", "--out", "never"),
                                  ("serve", "--port", "\uff18\uff10\uff10\uff10")])
def test_digits_of_other_scripts_are_refused(args):
    p = run_cli(*args, timeout=120)
    assert p.returncode == 2, (args, p.stderr)
    assert "accepted" in one_line(p.stderr)
    assert not (REPO / "never").exists()


def test_version():
    from airpuff_core import __version__
    from airpuff_core.provenance import model_version

    p = run_cli("--version", timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == f"airpuff {__version__} (model version {model_version()})"
