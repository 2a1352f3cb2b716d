"""`airpuff sweep` as a user runs it: a separate process, interrupted with Ctrl-C, then resumed.

Test modules run one after the other and each shuts its Dask cluster down, so only one cluster
exists at a time.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import xarray as xr

from sweep.grid import SweepSpec
from sweep.storage import point_key, point_path

from tests.conftest import airpuff_argv

pytestmark = pytest.mark.cluster

# Points of 12 ms (about a second each at coarse resolution): with 3 ms points the whole sweep
# could finish between the first stored file and the Ctrl-C under a loaded machine.
ARGS = ["--E0", "0.4,0.6", "--IOP", "12:20:3", "--resolution", "coarse", "--t-end", "12",
        "--workers", "2"]


@pytest.mark.slow
def test_ctrl_c_then_resume_computes_only_the_rest(tmp_path):
    out = tmp_path / "sweep"
    spec = SweepSpec(E0=[0.4, 0.6], IOP=[12.0, 16.0, 20.0],
                     options={"resolution": "coarse", "t_end": 12.0}).validate()
    files = [point_path(out / "points", point_key(p)) for p in spec.points()]

    # A shell starts background jobs with SIGINT ignored, and a child inherits that; Python then
    # installs no KeyboardInterrupt handler. Reset it so the sweep gets SIGINT as a terminal's
    # foreground process does, however pytest itself was started.
    proc = subprocess.Popen(airpuff_argv("sweep", *ARGS, "--out", str(out)), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and not any(f.exists() for f in files):
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)  # what Ctrl-C does
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "interrupted" in err and "run the same command again to resume" in err
    stored = {f for f in files if f.exists()}
    assert 1 <= len(stored) < len(files)  # interrupted in the middle
    mtimes = {f: f.stat().st_mtime_ns for f in stored}

    done = subprocess.run(airpuff_argv("sweep", *ARGS, "--out", str(out), "--json"),
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)  # exactly one JSON object on stdout
    assert report["computed"] == len(files) - len(stored)
    assert report["reused"] == len(stored) and report["failed"] == 0
    assert all(f.exists() for f in files)
    assert {f: f.stat().st_mtime_ns for f in stored} == mtimes  # finished points not rewritten
    with xr.open_dataset(report["path"]) as ds:
        assert (ds["status"].values == "ok").all() and ds.sizes["IOP"] == 3

    # a third run has nothing to do: no cluster, and the summary table says so
    again = subprocess.run(airpuff_argv("sweep", *ARGS, "--out", str(out)), capture_output=True,
                           text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert "6 points: 6 ok, 0 failed; 0 computed now, 6 already stored" in again.stdout
    assert f"wrote {out / 'sweep.nc'}" in again.stdout
    for p in spec.points():  # one table row per point
        assert any(line.split()[:2] == [f"{p.E0:g}", f"{p.IOP:g}"] for line in again.stdout.splitlines())


@pytest.mark.slow
def test_demo_and_analysis_scripts_on_a_stored_sweep(coarse_sweep, tmp_path):
    """examples/analyze_sweep.py reads a sweep.nc written by `airpuff sweep` (the session's
    coarse sweep, tests/conftest.py) with plain xarray and writes its figure."""
    script = Path(__file__).resolve().parents[2] / "examples" / "analyze_sweep.py"
    res = subprocess.run([sys.executable, script, str(coarse_sweep), "--out", str(tmp_path / "s.png")],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "s.png").stat().st_size > 10_000
    assert "elasticity" in res.stdout and "E0" in res.stdout

    from sweep.plots import plot_metrics_vs_iop

    with xr.open_dataset(coarse_sweep) as ds:
        png = plot_metrics_vs_iop(ds.load(), tmp_path / "m.png")
    assert png.stat().st_size > 10_000


@pytest.mark.slow
def test_sweep_with_the_shell_cornea_keys_and_records_it(tmp_path):
    """`--cornea shell` reaches every point: its key (beside the membrane's, not over it), its
    netCDF and the sweep's run options; `identify --refine` would rerun with it."""
    from airpuff_core import RunParams

    out = tmp_path / "shell"
    args = ["--E0", "0.5", "--IOP", "16", "--resolution", "coarse", "--t-end", "0.5",
            "--workers", "1", "--out", str(out), "--json"]
    for cornea in ("shell", "membrane"):
        run = subprocess.run(airpuff_argv("sweep", *args, "--cornea", cornea), capture_output=True,
                             text=True, timeout=600)
        assert run.returncode == 0, run.stderr
        assert json.loads(run.stdout)["computed"] == 1  # the membrane point is a new point
    for cornea in ("shell", "membrane"):
        params = RunParams(E0=0.5, IOP=16, resolution="coarse", t_end=0.5, cornea=cornea)
        with xr.open_dataset(point_path(out / "points", point_key(params))) as ds:
            # the older spelling is the registry's Kirchhoff shell (G_t = 0)
            assert ds.attrs["cornea"] == {"shell": "kirchhoff"}.get(cornea, cornea)
            assert (ds.attrs["solver_bending_rigidity_N_m"] > 0) == (cornea == "shell")
    with xr.open_dataset(out / "sweep.nc") as ds:
        assert json.loads(ds.attrs["run_options_json"])["cornea"] == "membrane"  # the last one
