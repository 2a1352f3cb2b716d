"""Jobs end to end: a real `airpuff serve` (uvicorn on a loopback port) with a real Dask cluster of
two worker processes, the real solver (coarse, short t_end), SQLite and netCDF read back with
xarray.  One server for the module (one Dask cluster at a time on this machine).
"""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
import xarray as xr

from airpuff_core.params import RunParams
from airpuff_core.provenance import model_version
from airpuff_core.result import METRICS
from sweep.storage import failed_path, point_key, point_path
from tests.api.support import ServerProcess, post_at_once, submit, wait_job

pytestmark = [pytest.mark.service, pytest.mark.cluster]

# Short coarse runs: about a second or two of solver time per point.
OPTIONS = {"resolution": "coarse", "t_end": 1.0}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with ServerProcess(tmp_path_factory.mktemp("jobs") / "data", "--workers", "2").running(
            wait_runner=True) as s:
        yield s


def file_ids(server, keys) -> dict[str, tuple[int, int]]:
    """(inode, mtime_ns) of each point's result file: an atomic rewrite changes the inode."""
    out = {}
    for k in keys:
        for p in (point_path(server.data_dir / "points", k), failed_path(server.data_dir / "points", k)):
            if p.exists():
                st = p.stat()
                out[k] = (st.st_ino, st.st_mtime_ns)
    return out


def same(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return math.isclose(a, b, rel_tol=1e-12, abs_tol=0.0)


def check_against_files(server, job, points):
    """Every record agrees with the per-point file of its key (netCDF for ok, JSON for failed)."""
    options = {k: v for k, v in job["request"].items() if k not in ("E0", "IOP", "thickness", "pmax")}
    n_ok = 0
    for rec in points:
        params = RunParams.from_dict({**options, **{k: rec[k] for k in ("E0", "IOP", "thickness",
                                                                         "pmax")}})
        key = point_key(params)
        assert rec["key"] == key
        if rec["status"] == "ok":
            n_ok += 1
            with xr.open_dataset(point_path(server.data_dir / "points", key)) as ds:
                assert float(ds["E0"]) == rec["E0"] and float(ds["IOP"]) == rec["IOP"]
                for name in METRICS:
                    v = float(ds[name])
                    assert same(None if not np.isfinite(v) else v, rec[name]), (name, v, rec)
        else:
            assert rec["status"] == "failed", rec
            assert rec["message"] and all(rec[m] is None for m in METRICS)
            assert failed_path(server.data_dir / "points", key).exists()
    return n_ok


def test_job_runs_and_metrics_match_point_files(client, server, tmp_path):
    body = {"E0": [0.4, 0.6], "IOP": [12.0, 18.0], "thickness": [0.5], "pmax": [10.0], **OPTIONS}
    t0 = time.monotonic()
    job_id = submit(client, body)
    seen = {client.get(f"/sweeps/{job_id}").json()["status"]}
    while True:  # poll: the job passes through running while points finish
        job = client.get(f"/sweeps/{job_id}").json()
        seen.add(job["status"])
        if job["status"] in ("done", "failed", "cancelled"):
            break
        assert time.monotonic() - t0 < 300, job
        time.sleep(0.2)
    wall = time.monotonic() - t0
    assert job["status"] == "done", job
    assert "running" in seen or "queued" in seen
    assert job["points_total"] == 4 and job["points_done"] + job["points_failed"] == 4
    assert job["created_at"] <= job["started_at"] <= job["finished_at"]

    m = client.get(f"/sweeps/{job_id}/metrics").json()
    assert m["status"] == "done" and m["units"]["DA"] == "mm"
    recs = m["points"]
    assert [(p["E0"], p["IOP"]) for p in recs] == [(e, i) for e in body["E0"] for i in body["IOP"]]
    assert all(p["reused"] is False for p in recs)  # a fresh data dir: everything computed
    n_ok = check_against_files(server, job, recs)
    assert n_ok == job["points_done"] and n_ok >= 1, recs
    assert any(p["DA"] is not None and p["DA"] > 0 for p in recs)

    # The combined netCDF of this job, as downloaded.
    r = client.get(f"/sweeps/{job_id}/dataset")
    assert r.status_code == 200 and r.headers["content-type"] == "application/x-netcdf"
    path = tmp_path / "sweep.nc"
    path.write_bytes(r.content)
    with xr.open_dataset(path) as ds:
        assert ds.attrs["Conventions"].startswith("CF-")
        assert list(ds["E0"].values) == body["E0"] and list(ds["IOP"].values) == body["IOP"]
        for rec in recs:
            sel = ds.sel(E0=rec["E0"], IOP=rec["IOP"], thickness=rec["thickness"], pmax=rec["pmax"])
            assert str(sel["status"].values) == rec["status"]
            assert str(sel["point_key"].values) == rec["key"]
            for name in METRICS:
                v = float(sel[name])
                assert same(None if not np.isfinite(v) else v, rec[name]), name
            # no calibration for these options: the calibrated readings are missing, and the
            # records say why as the netCDF does, naming the command that makes one
            if rec["status"] == "ok":
                assert rec["model_version"] == str(sel["model_version"].values) == model_version()
                assert rec["calibration"] is None and rec["IOPg_cal"] is None
                assert ("make one with: airpuff calibrate --instrument paper --resolution coarse "
                        "--model paper --t-end 1" in rec["calibration_missing"])
                assert rec["calibration_missing"] in ds["IOPg_cal"].attrs["comment"]
    print(f"\n4-point job: {wall:.1f} s wall; {n_ok} ok")


def test_identical_jobs_at_the_same_moment_compute_each_point_once(server):
    body = {"E0": [0.45, 0.55], "IOP": [14.0, 17.0], "thickness": [0.55], "pmax": [10.0],
            **OPTIONS}
    answers = post_at_once(server, [body, body])
    assert [a.status_code for a in answers] == [202, 202], [a.text for a in answers]
    ids = [a.json()["id"] for a in answers]
    assert ids[0] != ids[1]
    with server.client() as c:
        jobs = [wait_job(c, i) for i in ids]
        recs = [c.get(f"/sweeps/{i}/metrics").json()["points"] for i in ids]
    assert [j["status"] for j in jobs] == ["done", "done"], jobs
    a, b = recs
    assert [p["key"] for p in a] == [p["key"] for p in b]
    for pa, pb in zip(a, b):
        assert pa["status"] == pb["status"]
        for name in METRICS:
            assert pa[name] == pb[name], name
        # Exactly one of the two jobs computed the point; the other waited for it.
        assert sorted([pa["reused"], pb["reused"]]) == [False, True], (pa, pb)
    assert jobs[0]["points_reused"] + jobs[1]["points_reused"] == \
        jobs[0]["points_done"]  # == each job's done count, since the results are shared
    for job in jobs:
        check_against_files(server, job, a)


def test_finished_points_are_reused_not_recomputed(client, server, tmp_path):
    first = {"E0": [0.35, 0.65], "IOP": [15.0], "thickness": [0.5], "pmax": [10.0], **OPTIONS}
    job1 = wait_job(client, submit(client, first))
    recs1 = client.get(f"/sweeps/{job1['id']}/metrics").json()["points"]
    before = file_ids(server, [p["key"] for p in recs1])
    assert len(before) == 2

    # A larger grid that contains the two points: only the new one is computed.
    second = {**first, "E0": [0.35, 0.5, 0.65]}
    t0 = time.monotonic()
    job2 = wait_job(client, submit(client, second))
    assert job2["status"] == "done", job2
    recs2 = client.get(f"/sweeps/{job2['id']}/metrics").json()["points"]
    by_e0 = {p["E0"]: p for p in recs2}
    for old in recs1:
        new = by_e0[old["E0"]]
        assert new["key"] == old["key"] and new["reused"] is True
        for name in METRICS:
            assert new[name] == old[name]
    assert by_e0[0.5]["reused"] is False
    assert job2["points_reused"] == sum(p["status"] == "ok" for p in recs1)
    assert file_ids(server, [p["key"] for p in recs1]) == before  # files not rewritten

    # The same grid again is served entirely from stored points.
    job3 = wait_job(client, submit(client, second))
    recs3 = client.get(f"/sweeps/{job3['id']}/metrics").json()["points"]
    assert job3["status"] == "done" and all(p["reused"] for p in recs3)
    assert file_ids(server, [p["key"] for p in recs2]) == file_ids(server, [p["key"] for p in recs3])

    # Each download is its own job's combined file.
    for job, body in ((job1, first), (job2, second)):
        r = client.get(f"/sweeps/{job['id']}/dataset")
        assert r.status_code == 200
        path = tmp_path / f"{job['id']}.nc"
        path.write_bytes(r.content)
        with xr.open_dataset(path) as ds:
            assert list(ds["E0"].values) == body["E0"]
            assert json.loads(ds.attrs["sweep_json"])["E0"] == body["E0"]
    print(f"\nsuperset job {time.monotonic() - t0:.1f} s incl. a fully reused repeat")


def test_cancel_a_running_job(client, server):
    body = {"E0": [0.3, 0.7], "IOP": [11.0, 13.0, 19.0, 21.0], "thickness": [0.45],
            "pmax": [10.0], **OPTIONS}
    job_id = submit(client, body)
    wait_job(client, job_id, until=("running", "done", "failed"), poll=0.05)
    r = client.delete(f"/sweeps/{job_id}")
    assert r.status_code == 200, r.text
    assert r.json()["status"] == "cancelled"
    finished_at_cancel = r.json()["points_done"] + r.json()["points_failed"]
    recs = client.get(f"/sweeps/{job_id}/metrics").json()["points"]
    statuses = [p["status"] for p in recs]
    assert "pending" not in statuses and "cancelled" in statuses, statuses
    assert client.get(f"/sweeps/{job_id}/dataset").status_code == 409
    # The runner still works afterwards.
    other = wait_job(client, submit(client, {**body, "IOP": [11.0], "thickness": [0.6]}))
    assert other["status"] == "done", other
    # The cancelled job stayed cancelled, and its queued points were not run: at most the
    # points already on a worker (two workers) finished after the cancel.
    assert client.get(f"/sweeps/{job_id}").json()["status"] == "cancelled"
    written = file_ids(server, [p["key"] for p in recs])
    assert len(written) <= finished_at_cancel + 2, (len(written), finished_at_cancel)
    # DELETE of an ended job (cancelled or done) removes it
    for ended in (job_id, other["id"]):
        assert client.delete(f"/sweeps/{ended}").status_code == 204
        assert client.get(f"/sweeps/{ended}").status_code == 404


def test_one_runner_per_data_dir(server):
    """A second server with a runner on the same data directory refuses to start."""
    import subprocess
    import sys

    p = subprocess.run([sys.executable, "-m", "api.cli", "serve", "--port", "0", "--data-dir",
                        str(server.data_dir)], capture_output=True, text=True, timeout=120)
    assert p.returncode == 1 and "runner.lock" in p.stderr, p.stderr
    with server.client() as c:
        assert c.get("/health").json()["runner"] == "ready"
