"""Sweeps on a real LocalCluster of 2 worker processes with the real solver.

One cluster serves the whole module (this machine has 2 cores; a cluster start costs seconds).
Runs are coarse and short (t_end 3 ms: the applanation metrics are then missing, DA and the
velocities exist), which is enough to check the plumbing; ``make demo`` runs full-length points.

The facts checked are independent of the sweep code: metrics are compared with a direct
``airpuff_core.simulate`` call in this process, computed points are counted from the files'
modification times as well as from the runner's report, and the failure reason is compared with
the SimulationError that a direct call raises.
"""

from __future__ import annotations

import math
import os
import signal
import threading
import time

import numpy as np
import pytest
import xarray as xr

from airpuff_core import RunParams, SimulationError
from airpuff_core import simulate
from airpuff_core.dataset import decodable_ms, open_dataset
from airpuff_core.params import SWEPT
from airpuff_core.result import METRICS
from sweep.numba_cache import jit_counts
from sweep.grid import SweepSpec
from sweep.runner import run_sweep
from sweep.storage import failed_path, point_key, point_path

pytestmark = pytest.mark.cluster

SHORT = {"resolution": "coarse", "t_end": 3.0}  # ms


@pytest.fixture(scope="module")
def main_sweep(dask_client, tmp_path_factory):
    """A 2 x 2 sweep (E0 x IOP) run once; several tests read it."""
    out = tmp_path_factory.mktemp("sweep_main")
    spec = SweepSpec(E0=[0.4, 0.6], IOP=[12.0, 20.0], thickness=[0.5], pmax=[10.0],
                     options=dict(SHORT)).validate()
    outcome = run_sweep(spec, out, client=dask_client)
    return spec, outcome, out


def _same(a: float, b: float) -> bool:
    """Equal floats to round-off (worker processes may run LAPACK with other threading, which
    changes the last bits), NaN equal to NaN (a missing metric must be missing in both)."""
    return (math.isnan(a) and math.isnan(b)) or math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)


def test_sweep_on_two_worker_processes_matches_direct_runs(main_sweep):
    spec, outcome, out = main_sweep
    assert (outcome.n_points, outcome.computed, outcome.reused, outcome.failed) == (4, 4, 0, 0)
    # the points really ran in two other processes
    pids = {r.pid for r in outcome.records}
    assert len(pids) == 2 and os.getpid() not in pids

    with open_dataset(out / "sweep.nc") as ds:
        ds = ds.load()
    assert tuple(d for d in ds["DA"].dims) == SWEPT
    assert ds["apex_displacement"].dims == SWEPT + ("time",)
    assert ds["E0"].values.tolist() == [0.4, 0.6] and ds["IOP"].values.tolist() == [12.0, 20.0]
    assert (ds["status"].values == "ok").all()

    for p in spec.points():
        direct = simulate(p)  # what `airpuff run` computes for these parameters
        at = ds.sel(E0=p.E0, IOP=p.IOP, thickness=p.thickness, pmax=p.pmax)
        for name in METRICS:
            assert _same(float(at[name]), float(direct.metrics[name])), (p, name)
        assert math.isfinite(float(at["DA"])) and float(at["DA"]) > 0
        # the file's times are the run's as written for exact decoding (dataset.decodable_ms)
        np.testing.assert_array_equal(ds["time"].values, decodable_ms(direct.time))
        np.testing.assert_array_equal(at["apex_displacement"].values,
                                      direct.histories["apex_displacement"])
        np.testing.assert_array_equal(at["jet_pressure_apex"].values,
                                      direct.histories["jet_pressure_apex"])
        # the per-point file holds the full run (shapes too) under the point's key
        assert str(at["point_key"].values) == point_key(p)
        with xr.open_dataset(point_path(out / "points", point_key(p))) as one:
            assert "cornea_x" in one and float(one["E0"]) == p.E0


def test_combined_file_is_self_describing(main_sweep):
    spec, outcome, out = main_sweep
    with open_dataset(outcome.path) as ds:
        assert ds.attrs["Conventions"] == "CF-1.10"
        for name, (unit, _) in METRICS.items():
            assert ds[name].attrs["units"] == unit and ds[name].attrs["long_name"]
        assert ds["E0"].attrs["units"] == "MPa" and ds["IOP"].attrs["units"] == "mmHg"
        assert ds["thickness"].attrs["units"] == "mm" and ds["pmax"].attrs["units"] == "kPa"
        assert ds["time"].attrs["units"].startswith("milliseconds since ")  # a CF time axis [ms]
        assert ds["apex_displacement"].attrs["units"] == "mm"
        assert ds["jet_pressure_apex"].attrs["units"] == "mmHg"
        # the run options: scalar coordinates with units, and attributes
        assert float(ds["t_end"]) == 3.0 and ds["t_end"].attrs["units"] == "ms"
        assert ds.attrs["param_resolution"] == "coarse"
        assert ds.attrs["n_ok"] == 4 and ds.attrs["n_failed"] == 0
        assert SweepSpec.from_dict(__import__("json").loads(ds.attrs["sweep_json"])).to_dict() == spec.to_dict()


def test_numba_compiles_nothing_in_warmed_workers(main_sweep, dask_client):
    """The runner warmed the cache in this process before the fan-out: workers only load."""
    _, outcome, _ = main_sweep
    assert all(r.jit_compiled == 0 for r in outcome.records), \
        [(r.pid, r.jit_compiled) for r in outcome.records]
    by_pid: dict[int, list] = {}
    for r in outcome.records:
        by_pid.setdefault(r.pid, []).append(r)
    for pid, recs in by_pid.items():
        first = [r for r in recs if r.first_in_process]
        later = [r for r in recs if not r.first_in_process]
        assert len(first) == 1 and first[0].jit_loaded > 0  # loaded once, from the cache
        assert all(r.jit_loaded == 0 for r in later)  # and never again in that process
    # and from the workers' own Numba statistics: no cache miss anywhere
    stats = dask_client.run(jit_counts)
    for addr, counts in stats.items():
        assert counts and sum(miss for _, miss in counts.values()) == 0, (addr, counts)
    envs = dask_client.run(lambda: (os.environ.get("NUMBA_NUM_THREADS"),
                                    os.environ.get("NUMBA_CACHE_DIR")))
    assert {e[0] for e in envs.values()} == {"1"}
    assert {e[1] for e in envs.values()} == {os.environ.get("NUMBA_CACHE_DIR")}


def test_resume_computes_only_missing_points(main_sweep, dask_client):
    spec, first, out = main_sweep
    points_dir = out / "points"
    files = {point_key(p): point_path(points_dir, point_key(p)) for p in spec.points()}
    before = {k: (f.stat().st_ino, f.stat().st_mtime_ns) for k, f in files.items()}

    # same sweep again: nothing to do, and no cluster needed for it
    again = run_sweep(spec, out, client=None, workers=2)
    assert (again.computed, again.reused) == (0, 4)
    assert {k: (f.stat().st_ino, f.stat().st_mtime_ns) for k, f in files.items()} == before

    # a crash lost one point; the sweep also grew by one IOP value (2 new points)
    lost = spec.points()[1]
    point_path(points_dir, point_key(lost)).unlink()
    grown = SweepSpec(E0=spec.E0, IOP=spec.IOP + [16.0], thickness=spec.thickness, pmax=spec.pmax,
                      options=dict(spec.options)).validate()
    resumed = run_sweep(grown, out, client=dask_client)
    assert resumed.computed == 3 and resumed.reused == 3 and resumed.failed == 0
    computed_keys = {r.key for r in resumed.records if r.computed}
    expected = {point_key(lost)} | {point_key(p) for p in grown.points() if p.IOP == 16.0}
    assert computed_keys == expected
    # the other finished points were not rewritten
    for k, f in files.items():
        if k != point_key(lost):
            assert (f.stat().st_ino, f.stat().st_mtime_ns) == before[k]
    with xr.open_dataset(out / "sweep.nc") as ds:
        assert ds.sizes["IOP"] == 3 and (ds["status"].values == "ok").all()
        # the recomputed point is identical to its first computation
        a = first.records[1].metrics
        at = ds.sel(E0=lost.E0, IOP=lost.IOP, thickness=lost.thickness, pmax=lost.pmax)
        for name in METRICS:
            assert _same(float(at[name]), float("nan") if a[name] is None else a[name])


def test_failed_point_is_recorded_and_others_succeed(dask_client, tmp_path):
    # A 10 micrometre cornea (accepted range (0, 2] mm) cannot carry the IOP: the
    # Dirichlet-Neumann coupling diverges at once -- an honest solver failure.
    bad = RunParams(thickness=0.01, **SHORT)
    with pytest.raises(SimulationError) as direct:
        simulate(bad)
    spec = SweepSpec(E0=[0.5], IOP=[16.0], thickness=[0.01, 0.5], pmax=[10.0], options=dict(SHORT))
    outcome = run_sweep(spec.validate(), tmp_path, client=dask_client)
    assert (outcome.computed, outcome.failed, outcome.ok) == (2, 1, 1)

    with xr.open_dataset(tmp_path / "sweep.nc") as ds:
        failed = ds.sel(thickness=0.01).squeeze()
        good = ds.sel(thickness=0.5).squeeze()
        assert str(failed["status"].values) == "failed"
        assert str(failed["message"].values) == " ".join(str(direct.value).split())
        assert all(math.isnan(float(failed[m])) for m in METRICS)
        assert np.isnan(failed["apex_displacement"].values).all()
        assert str(good["status"].values) == "ok" and float(good["DA"]) > 0
        assert ds.attrs["n_failed"] == 1 and ds.attrs["n_ok"] == 1
    key = point_key(spec.points()[0])
    assert failed_path(tmp_path / "points", key).exists()
    assert not point_path(tmp_path / "points", key).exists()

    # a resume keeps the recorded failure; --retry-failed runs it again (and it fails again)
    again = run_sweep(spec, tmp_path, client=dask_client)
    assert (again.computed, again.failed) == (0, 1)
    retried = run_sweep(spec, tmp_path, client=dask_client, retry_failed=True)
    assert (retried.computed, retried.failed) == (1, 1)


def test_existing_scheduler_by_address(dask_client, tmp_path):
    """--scheduler ADDRESS: the sweep joins a running cluster, and leaves it running."""
    spec = SweepSpec(E0=[0.42], IOP=[14.0, 18.0], options=dict(SHORT)).validate()
    outcome = run_sweep(spec, tmp_path, scheduler=dask_client.scheduler.address)
    assert (outcome.computed, outcome.failed) == (2, 0)
    assert outcome.warnings == []  # its workers have one thread, NUMBA_NUM_THREADS=1, our cache
    worker_pids = set(dask_client.run(os.getpid).values())
    assert {r.pid for r in outcome.records} <= worker_pids
    assert len(worker_pids) == 2  # the cluster is still there


def test_killed_worker_process_does_not_lose_points(dask_client, tmp_path):
    spec = SweepSpec(E0=[0.45, 0.55], IOP=[13.0, 17.0, 21.0], thickness=[0.5], pmax=[10.0],
                     options=dict(SHORT)).validate()
    points_dir = tmp_path / "points"
    killed: dict = {}

    def kill_a_busy_worker():
        # wait until the first point is stored, so the workers are in the middle of the sweep
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and not list(points_dir.glob("*.nc")):
            time.sleep(0.05)
        while time.monotonic() < deadline:
            busy = [addr for addr, keys in dask_client.processing().items() if keys]
            if busy:
                pid = dask_client.run(os.getpid, workers=[busy[0]])[busy[0]]
                os.kill(pid, signal.SIGKILL)
                killed.update(pid=pid, addr=busy[0], stored=len(list(points_dir.glob("*.nc"))))
                return
            time.sleep(0.05)

    pids_before = set(dask_client.run(os.getpid).values())
    killer = threading.Thread(target=kill_a_busy_worker, daemon=True)
    killer.start()
    outcome = run_sweep(spec, tmp_path, client=dask_client)
    killer.join(timeout=10)

    assert killed, "no worker was killed during the sweep"
    assert killed["pid"] in pids_before and killed["stored"] < spec.n_points
    assert outcome.failed == 0 and outcome.computed + outcome.reused == spec.n_points
    assert outcome.computed >= spec.n_points - 1  # one may have been stored just before the kill
    with xr.open_dataset(tmp_path / "sweep.nc") as ds:
        assert (ds["status"].values == "ok").all()
        assert np.isfinite(ds["DA"].values).all()
    # the Nanny replaced the killed process
    dask_client.wait_for_workers(2, timeout=60)
    pids_after = set(dask_client.run(os.getpid).values())
    assert killed["pid"] not in pids_after and len(pids_after) == 2
