"""Restart: stop the server while a job runs, start a new one on the same data directory; the job
completes and the points finished before the stop are not recomputed.

Real processes throughout: `airpuff serve` under uvicorn, a LocalCluster of two worker processes,
SQLite, netCDF.  The two servers run one after the other (one Dask cluster at a time).
"""

from __future__ import annotations

import signal
import sqlite3
import time

import pytest
import xarray as xr

try:  # tests/ may or may not be a package
    from .test_api_support import ServerProcess, wait_job
    from .test_api_jobs import check_against_files, file_ids
except ImportError:
    from test_api_support import ServerProcess, wait_job
    from test_api_jobs import check_against_files, file_ids

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
