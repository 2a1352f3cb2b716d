"""Shared fixtures.  One real coarse run through the real CLI serves several tests."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault("NUMBA_CACHE_DIR", str(ROOT / ".numba_cache"))
# The tests' own runs use one thread: this process also starts LocalClusters, whose nannies set
# NUMBA_NUM_THREADS=1 here whenever they (re)start a worker, and Numba refuses to compile once
# that disagrees with a thread pool it has started (airpuff_core/threads.py).  The runs on
# several threads are tested in a subprocess of their own (tests/core/test_threads.py).
os.environ.setdefault("NUMBA_NUM_THREADS", "1")


# The stated accuracy of a clinical point (issue 31): what a faster scheme may move its metrics by.
STATED_ACCURACY = {"P1": 0.05, "P2": 0.05, "CH": 0.05, "DA": 0.002}  # mmHg, DA mm


def assert_within_stated_accuracy(metrics, reference):
    """Every metric of ``STATED_ACCURACY`` in ``metrics`` within its accuracy of ``reference``."""
    for name, accuracy in STATED_ACCURACY.items():
        assert abs(metrics[name] - reference[name]) < accuracy, (name, metrics[name],
                                                                 reference[name])


def airpuff_argv(*args) -> list[str]:
    """The command line of the real `airpuff` command with ``args`` (as `python -m api.cli`)."""
    return [sys.executable, "-m", "api.cli", *args]


def airpuff(*args, timeout=600, cwd=None):
    """Run the real `airpuff` command (as `python -m api.cli`) and return the CompletedProcess."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run(airpuff_argv(*args), capture_output=True, text=True,
                          timeout=timeout, cwd=cwd or ROOT, env=env)


@pytest.fixture(scope="session")
def coarse_run(tmp_path_factory):
    """`airpuff run --resolution coarse --json --out run.nc`: (metrics dict, netCDF path)."""
    out = tmp_path_factory.mktemp("coarse") / "run.nc"
    proc = airpuff("run", "--resolution", "coarse", "--json", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stdout.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stdout
    return json.loads(lines[0]), out


@pytest.fixture(scope="session")
def clinical_paper_result():
    """One run of the clinical preset's normal eye (CCT 0.54 mm, IOP 16 mmHg) at paper
    resolution in this process, shared by the tests that need such a run (its energy budget)."""
    from airpuff_core import RunParams, simulate

    return simulate(RunParams(model="clinical", thickness=0.54, resolution="paper"))


@pytest.fixture(scope="module")
def dask_client():
    """A LocalCluster of two worker processes sharing the Numba cache, for one test module (one
    cluster at a time on this machine)."""
    from sweep.cluster import close_client, make_client
    from sweep.numba_cache import shared_numba_cache_dir

    shared_numba_cache_dir()  # before the solver is imported here, if it is not yet
    c = make_client(workers=2)
    try:
        c.wait_for_workers(2, timeout=120)
        yield c
    finally:
        close_client(c)


@pytest.fixture
def client(server):
    """An HTTP client of the module's ``server`` fixture (a ``ServerProcess``), with its token."""
    with server.client() as c:
        yield c


@pytest.fixture(scope="session")
def coarse_sweep(tmp_path_factory):
    """A real 2 x 2 x 2 coarse sweep (E0 x IOP x thickness) through the real CLI: the sweep.nc
    (its points in the folder beside it) of the correction tests, CLI and HTTP."""
    out = tmp_path_factory.mktemp("correct") / "sweep"
    proc = airpuff("sweep", "--E0", "0.4,0.7", "--IOP", "12,22", "--thickness", "0.45,0.6",
                   "--resolution", "coarse", "--workers", "2", "--json", "--out", str(out),
                   timeout=1200)
    assert proc.returncode == 0, proc.stderr
    return out / "sweep.nc"
