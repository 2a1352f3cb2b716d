"""A service one request cannot block (issue 30, items 1, 2 and 6).

Real `airpuff serve` processes (uvicorn on a loopback port) with Dask worker processes and the
real solver (coarse), the job database read back with sqlite3, a full disk made with a small
tmpfs (root only).  Item 1: a run is bounded at validation, a task at its wall-clock limit, and
DELETE stops a running task.  Item 2: Dask gets a window of tasks, jobs take turns, pending
points are capped.  Item 6: a full disk loses no result and names its cause.
"""

from __future__ import annotations

import errno
import os
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from airpuff_core.budget import MAX_ESTIMATED_STEPS

from tests.api.support import REPO, ServerProcess, submit, wait_job

pytestmark = pytest.mark.service

QUICK = {"IOP": [15.0], "thickness": [0.5], "pmax": [10.0], "resolution": "coarse",
         "t_end": 1.0}
# A point of many minutes at coarse resolution (2 s of model time, an estimated 155,000 steps),
# inside the step budget: what a wall-clock limit or a DELETE has to stop.
LONG = {**QUICK, "E0": [0.5], "t_end": 2000.0}
TIME_LIMIT_S = 20


def run_cli(*args, timeout=120):
    env = dict(os.environ)
    env.pop("AIRPUFF_API_TOKEN", None)
    return subprocess.run([sys.executable, "-m", "api.cli", *args], capture_output=True,
                          text=True, timeout=timeout, cwd=REPO, env=env)


def worker_pids(server: ServerProcess) -> set[int]:
    """The Dask worker processes of ``server`` (spawned processes of its session)."""
    pids = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if os.getsid(int(entry.name)) != server.proc.pid:
                continue
            cmdline = (entry / "cmdline").read_bytes()
        except (OSError, ProcessLookupError):
            continue
        if b"spawn_main" in cmdline:
            pids.add(int(entry.name))
    return pids


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def submissions(data_dir: Path) -> dict[str, int]:
    con = sqlite3.connect(data_dir / "airpuff.db")
    try:
        return dict(con.execute("SELECT key, submissions FROM points").fetchall())
    finally:
        con.close()


# -- item 1: bounded work ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def queued_only(tmp_path_factory):
    """A server without a runner (jobs stay queued), small pending-point limits."""
    with ServerProcess(tmp_path_factory.mktemp("queue") / "data", "--no-runner",
                       "--max-pending-points", "30", "--max-pending-per-client", "20"
                       ).running() as s:
        yield s


def test_a_run_above_the_step_budget_is_refused_at_validation(queued_only):
    """Item 1: cfl 1e-9 is refused with the estimate in the message (422, CLI exit 2)."""
    with queued_only.client() as c:
        r = c.post("/sweeps", json={"E0": [0.5], "IOP": [12], "resolution": "coarse",
                                    "cfl": 1e-9})
        assert r.status_code == 422, r.text
        (err,) = r.json()["detail"]
        assert err["field"] == "cfl", err
        assert "estimated" in err["msg"] and f"{MAX_ESTIMATED_STEPS:,}" in err["msg"], err
        r = c.post("/sweeps", json={"E0": [0.5], "resolution": "coarse", "cfl": 5e-324})
        assert r.status_code == 422 and r.json()["detail"][0]["field"] == "cfl", r.text
    for cmd in (("run", "--cfl", "1e-9", "--t-end", "0.001", "--resolution", "coarse"),
                ("sweep", "--E0", "0.4,0.5", "--cfl", "1e-9", "--resolution", "coarse",
                 "--out", str(queued_only.data_dir.parent / "refused"))):
        p = run_cli(*cmd)
        assert p.returncode == 2, (cmd, p.stderr)
        (line,) = p.stderr.strip().splitlines()
        assert "cfl" in line and "estimated" in line, line


@pytest.fixture(scope="module")
def limited(tmp_path_factory):
    """One worker process, a wall-clock limit of TIME_LIMIT_S per point; room for 100,000
    points waiting (the six large jobs below)."""
    with ServerProcess(tmp_path_factory.mktemp("limited") / "data", "--workers", "1",
                       "--task-time-limit", str(TIME_LIMIT_S), "--max-pending-points", "100000",
                       "--max-pending-per-client", "100000").running(wait_runner=True) as s:
        yield s


@pytest.mark.cluster
@pytest.mark.slow
def test_a_point_over_its_time_limit_is_stopped_and_its_worker_restarted(limited):
    """Item 1: the task is stopped (its worker process replaced), the point fails with the
    limit named, and the next job runs."""
    with limited.client() as c:
        job_id = submit(c, LONG)
        wait_job(c, job_id, until=("running",), timeout=60, poll=0.1)
        deadline = time.monotonic() + 60
        while not worker_pids(limited) and time.monotonic() < deadline:
            time.sleep(0.2)
        before = worker_pids(limited)
        job = wait_job(c, job_id, timeout=TIME_LIMIT_S + 240)
        assert job["status"] == "failed", job
        assert before and not before & worker_pids(limited), "the worker was not replaced"
        (point,) = c.get(f"/sweeps/{job['id']}/metrics").json()["points"]
        assert "wall-clock limit" in point["message"] and f"{TIME_LIMIT_S} s" in point["message"]
        quick = wait_job(c, submit(c, {**QUICK, "E0": [0.45]}), timeout=240)
        assert quick["status"] == "done", quick


@pytest.mark.cluster
@pytest.mark.slow
def test_delete_stops_the_running_task(limited):
    """Item 1: DELETE of a running job ends its task: the worker running it is replaced, and a
    later job computes at once."""
    with limited.client() as c:
        job_id = submit(c, {**LONG, "E0": [0.55]})
        wait_job(c, job_id, until=("running",), timeout=60, poll=0.1)
        deadline = time.monotonic() + 60
        while not worker_pids(limited) and time.monotonic() < deadline:
            time.sleep(0.2)
        time.sleep(5)  # the task has started on the only worker
        before = worker_pids(limited)
        assert before
        r = c.delete(f"/sweeps/{job_id}")
        assert r.status_code == 200 and r.json()["status"] == "cancelled", r.text
        deadline = time.monotonic() + 60
        while before & worker_pids(limited) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not before & worker_pids(limited), "the worker running the task still runs"
        quick = wait_job(c, submit(c, {**QUICK, "E0": [0.47]}), timeout=240)
        assert quick["status"] == "done", quick


# -- item 2: a bounded, fair queue --------------------------------------------------------------

def test_pending_points_are_capped_per_client_and_in_all(queued_only, tmp_path):
    """Item 2: a job above the per-client limit gets 429, above the server's 503, with the
    limits in the answer; nothing is stored for them."""
    with queued_only.client() as c:
        assert c.post("/sweeps", json={**QUICK, "E0": [0.3 + 0.01 * i for i in range(15)]}
                      ).status_code == 202
        r = c.post("/sweeps", json={**QUICK, "E0": [0.6 + 0.01 * i for i in range(10)]})
        assert r.status_code == 429, r.text
        body = r.json()
        assert body["limits"]["max_pending_per_client"] == 20 and body["limits"]["pending"] == 15
        assert "20" in body["detail"] and "--max-pending-per-client" in body["detail"]
        assert r.headers["Retry-After"]
    # a second server on the same database with a larger per-client limit: the server's limit
    other = ServerProcess(queued_only.data_dir, "--no-runner", "--max-pending-points", "30",
                          "--max-pending-per-client", "100",
                          log_path=tmp_path / "other.log")
    with other.running(), other.client() as c:
        assert c.post("/sweeps", json={**QUICK, "E0": [0.6 + 0.01 * i for i in range(10)]}
                      ).status_code == 202
        r = c.post("/sweeps", json={**QUICK, "E0": [0.8 + 0.01 * i for i in range(10)]})
        assert r.status_code == 503, r.text
        assert r.json()["limits"]["max_pending_points"] == 30
        assert "--max-pending-points" in r.json()["detail"]
        assert c.get("/sweeps").json()["total"] == 2


@pytest.mark.cluster
@pytest.mark.slow
def test_a_small_job_is_not_starved_behind_a_large_one(limited):
    """Item 2: jobs take turns in the window of tasks: a one-point job submitted after a
    30-point one finishes while most of the large one still waits."""
    with limited.client() as c:
        big = submit(c, {**QUICK, "E0": [0.3 + 0.01 * i for i in range(30)]})
        wait_job(c, big, until=("running",), timeout=60, poll=0.1)
        t0 = time.monotonic()
        small = wait_job(c, submit(c, {**QUICK, "E0": [0.9]}), timeout=300)
        waited = time.monotonic() - t0
        assert small["status"] == "done", small
        big_now = c.get(f"/sweeps/{big}").json()
        print(f"small job done after {waited:.1f} s; the large one had "
              f"{big_now['points_done']} of 30 points done")
        assert big_now["points_done"] <= 10, big_now
        assert c.delete(f"/sweeps/{big}").status_code == 200


@pytest.mark.cluster
@pytest.mark.slow
def test_six_large_jobs_do_not_balloon_the_server(limited):
    """Item 2: six jobs of 10,000 points each: the server feeds Dask a window of tasks, so its
    memory stays near where it was before they came (all 60,000 submitted at once took 300 ->
    985 MB)."""
    server = limited
    with server.client(timeout=120) as c:
        before = rss_mb(server.proc.pid)
        ids = []
        for k in range(6):
            body = {**QUICK, "E0": [round(0.3 + 0.001 * i + 0.0001 * k, 4) for i in range(100)],
                    "IOP": [round(10 + 0.1 * i, 2) for i in range(100)]}
            ids.append(submit(c, body))
        for job_id in ids:
            wait_job(c, job_id, until=("running",), timeout=300)
        time.sleep(5)
        during = rss_mb(server.proc.pid)
        for job_id in ids:
            assert c.delete(f"/sweeps/{job_id}").status_code == 200
        time.sleep(3)
        after = rss_mb(server.proc.pid)
        print(f"server RSS: {before:.0f} MB at start, {during:.0f} MB with 60,000 points "
              f"waiting, {after:.0f} MB after cancelling")
        assert during - before < 200, (before, during)


# -- item 6: a full disk -------------------------------------------------------------------------

def _mount_tmpfs(path: Path, size: str) -> None:
    path.mkdir(parents=True, exist_ok=True)
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                       capture_output=True, text=True)
    if p.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {p.stderr.strip()}")


def _fill(path: Path) -> None:
    """Write ``path`` until the disk is full (it may be full already)."""
    try:
        with open(path, "wb") as fh:
            while True:
                fh.write(b"\0" * 4096)
                fh.flush()
    except OSError as err:
        assert err.errno == errno.ENOSPC, err


@pytest.mark.cluster
@pytest.mark.skipif(os.geteuid() != 0, reason="mounting a tmpfs needs root")
def test_a_full_disk_keeps_every_result_and_names_its_cause(tmp_path):
    """Item 6: a data directory on a 1.2 MB tmpfs and a 12-point job (about 150 kB a point):
    results that cannot be written are kept (none computed twice), /health and a new POST name
    ENOSPC, and once space is freed the job ends done with all 12 points."""
    disk = tmp_path / "disk"
    _mount_tmpfs(disk, "1200k")
    server = ServerProcess(disk / "data", "--workers", "2", log_path=tmp_path / "server.log")
    try:
        with server.running(wait_runner=True), server.client() as c:
            job_id = submit(c, {**QUICK, "E0": [0.3 + 0.02 * i for i in range(12)]})
            deadline = time.monotonic() + 300
            while "ENOSPC" not in (c.get("/health").json()["runner_error"] or ""):
                assert time.monotonic() < deadline, c.get("/health").json()
                assert c.get(f"/sweeps/{job_id}").json()["status"] == "running"
                time.sleep(0.5)
            _fill(disk / "ballast")
            r = c.post("/sweeps", json={**QUICK, "E0": [0.95]})
            assert r.status_code == 507 and "ENOSPC" in r.json()["detail"], r.text
            subprocess.run(["mount", "-o", "remount,size=16m", str(disk)], check=True)
            (disk / "ballast").unlink(missing_ok=True)
            job = wait_job(c, job_id, timeout=300)
            assert job["status"] == "done" and job["points_done"] == 12, job
            assert sorted(submissions(disk / "data").values()) == [1] * 12
            deadline = time.monotonic() + 30
            while c.get("/health").json()["runner_error"] is not None:
                assert time.monotonic() < deadline, c.get("/health").json()
                time.sleep(0.5)
    finally:
        if server.proc is not None:
            server.kill()
        subprocess.run(["umount", "-l", str(disk)], check=False)
