"""Restart: stop the server while a job runs, start a new one on the same data directory; the job
completes and the points finished before the stop are not recomputed.  A database of an older
schema version is brought to the current one at start-up, its jobs and points kept.

Real processes throughout: `airpuff serve` under uvicorn, a LocalCluster of two worker processes,
SQLite, netCDF.  The two servers run one after the other (one Dask cluster at a time).
"""

from __future__ import annotations

import json
import signal
import sqlite3
import time

import pytest
import xarray as xr

from tests.api.support import ServerProcess, submit, wait_job
from tests.api.test_api_jobs import check_against_files, file_ids

from api.db import SCHEMA_VERSION
from sweep.storage import point_path

pytestmark = [pytest.mark.service, pytest.mark.cluster, pytest.mark.slow]

# points of about 0.5 s each: long enough that the points still to run when the server is
# stopped cannot all finish during its shutdown (at 1 ms the job once finished there)
BODY = {"E0": [0.3, 0.45, 0.6], "IOP": [12.0, 20.0], "thickness": [0.5], "pmax": [10.0],
        "resolution": "coarse", "t_end": 8.0}


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_job_survives_a_server_restart(tmp_path, sig):
    data = tmp_path / "data"
    first = ServerProcess(data, "--workers", "2")
    second = ServerProcess(data, "--workers", "2")
    try:
        first.start(wait_runner=True)
        with first.client() as c:
            r = c.post("/sweeps", json=BODY)
            assert r.status_code == 202
            job_id = r.json()["id"]
            total = r.json()["points_total"]
            # Stop once some points are finished and most are not.
            deadline = time.monotonic() + 240
            while True:
                job = c.get(f"/sweeps/{job_id}").json()
                finished = job["points_done"] + job["points_failed"]
                if finished >= 2:
                    break
                assert job["status"] in ("queued", "running"), job
                assert time.monotonic() < deadline, job
                time.sleep(0.05)
            before = c.get(f"/sweeps/{job_id}/metrics").json()["points"]
        assert finished < total - 1, "the job ran too fast to be interrupted; lengthen t_end"
        done_before = {p["key"]: p for p in before if p["status"] in ("ok", "failed")}
        files_before = file_ids(first, done_before)
        assert set(files_before) == set(done_before)

        stop_s = first.stop(sig=sig, timeout=60)  # also checks that no worker process lingers
        con = sqlite3.connect(data / "airpuff.db")
        try:
            assert con.execute("SELECT status FROM jobs WHERE id = ?", (job_id,)).fetchone() == \
                ("running",)
        finally:
            con.close()

        second.start(wait_runner=False)
        with second.client() as c:
            job = wait_job(c, job_id, timeout=300)
            assert job["status"] == "done", job
            assert job["points_done"] + job["points_failed"] == total
            after = c.get(f"/sweeps/{job_id}/metrics").json()["points"]
            r = c.get(f"/sweeps/{job_id}/dataset")
            assert r.status_code == 200
        # Points finished before the stop kept their results and their files (same inode and
        # modification time: not recomputed, not rewritten).
        by_key = {p["key"]: p for p in after}
        for key, old in done_before.items():
            assert by_key[key]["status"] == old["status"]
            assert by_key[key]["reused"] is False  # still counted as this job's own computation
            for name in ("DA", "t_HC", "v_in_max"):
                assert by_key[key][name] == old[name]
        assert file_ids(second, done_before) == files_before
        assert all(p["status"] in ("ok", "failed") for p in after)
        check_against_files(second, job, after)
        path = tmp_path / "sweep.nc"
        path.write_bytes(r.content)
        with xr.open_dataset(path) as ds:
            assert int((ds["status"] == "missing").sum()) == 0
            assert ds.sizes["E0"] == 3 and ds.sizes["IOP"] == 2
        print(f"\n{signal.Signals(sig).name}: stopped with {len(done_before)}/{total} points "
              f"finished; shutdown {stop_s:.1f} s")
    finally:
        for s in (first, second):
            if s.proc is not None:
                s.kill()


# The points table as servers of schema version 2 created it (api/db.py before version 3).
POINTS_V2 = """
CREATE TABLE points (
    key          TEXT PRIMARY KEY,
    params_json  TEXT NOT NULL,
    status       TEXT NOT NULL CHECK (status IN ('pending', 'ok', 'failed')),
    message      TEXT,
    metrics_json TEXT,
    wall_s       REAL,
    computed_by  TEXT,
    submissions  INTEGER NOT NULL DEFAULT 0,
    finished_at  REAL
)"""


def as_schema_version_2(db_path, points_dir, job_id: str) -> None:
    """Give the database the points table of schema version 2, filled as such a server filled
    it (parameters and wall time from each point's file, the submitting job, an end time)."""
    con = sqlite3.connect(db_path, isolation_level=None)
    try:
        rows = con.execute("SELECT key, status, message, metrics_json, submissions "
                           "FROM points").fetchall()
        con.execute("BEGIN IMMEDIATE")
        con.execute("DROP TABLE points")
        con.execute(POINTS_V2)
        for key, status, message, metrics_json, submissions in rows:
            with xr.open_dataset(point_path(points_dir, key)) as ds:
                params_json, wall = ds.attrs["parameters_json"], float(ds.attrs["wall_time_s"])
            con.execute("INSERT INTO points VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                        (key, params_json, status, message, metrics_json, wall, job_id,
                         submissions, time.time()))
        con.execute("PRAGMA user_version=2")
        con.execute("COMMIT")
    finally:
        con.close()


def test_a_database_of_schema_version_2_is_migrated_and_its_points_reused(tmp_path):
    """Schema version 3 dropped the points columns nothing read (params_json, wall_s,
    computed_by, finished_at): a server started on a version-2 database keeps its jobs and points,
    reuses the stored points and computes new ones into the migrated table.  (Version 5 added
    each point's model version; a row without one gets it from its key: the records, calibrated
    readings included, stay the same.)"""
    data = tmp_path / "data"
    body = {"E0": [0.4, 0.6], "IOP": [16.0], "thickness": [0.5], "pmax": [10.0],
            "resolution": "coarse", "t_end": 3.0}
    first = ServerProcess(data, "--workers", "2")
    second = ServerProcess(data, "--workers", "2")
    try:
        with first.running(wait_runner=True) as server, server.client() as c:
            old_id = submit(c, body)
            assert wait_job(c, old_id)["status"] == "done"
            old_points = c.get(f"/sweeps/{old_id}/metrics").json()["points"]
        assert [p["status"] for p in old_points] == ["ok", "ok"]
        files = file_ids(first, {p["key"] for p in old_points})
        as_schema_version_2(data / "airpuff.db", data / "points", old_id)

        with second.running(wait_runner=True) as server, server.client() as c:
            assert c.get(f"/sweeps/{old_id}/metrics").json()["points"] == old_points
            # the two stored points and one new one
            new_id = submit(c, {**body, "E0": [0.4, 0.5, 0.6]})
            job = wait_job(c, new_id)
            new_points = c.get(f"/sweeps/{new_id}/metrics").json()["points"]
        assert job["status"] == "done" and job["points_done"] == 3, job
        assert job["points_reused"] == 2, job
        by_key = {p["key"]: p for p in new_points}
        for old in old_points:
            assert by_key[old["key"]]["reused"] is True
            assert by_key[old["key"]]["DA"] == old["DA"]
        assert file_ids(second, {p["key"] for p in old_points}) == files  # not rewritten
        check_against_files(second, job, new_points)

        con = sqlite3.connect(data / "airpuff.db")
        try:
            assert con.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION == 5
            columns = [r[1] for r in con.execute("PRAGMA table_info(points)")]
            assert columns == ["key", "status", "message", "metrics_json", "submissions",
                               "model_version"]
            stored = {k: (st, json.loads(m), n) for k, st, m, n in con.execute(
                "SELECT key, status, metrics_json, submissions FROM points")}
        finally:
            con.close()
        assert set(stored) == {p["key"] for p in new_points}
        for p in new_points:  # each point computed once, its metrics as the API reports them
            status, metrics, submissions = stored[p["key"]]
            assert (status, submissions) == ("ok", 1)
            assert metrics["DA"] == p["DA"]
    finally:
        for s in (first, second):
            if s.proc is not None:
                s.kill()
