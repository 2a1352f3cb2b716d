"""The deployment of docker/compose.yaml, without Docker.

No Docker engine is needed (tests/deploy/test_docker.py runs the real containers where one is):
the test reads docker/compose.yaml, takes the
command of each service (a Dask scheduler, two Dask workers, the API with its runner) and runs
exactly those commands as separate OS processes on loopback.  Only what a container would supply
differently is substituted: listen addresses (127.0.0.1), ports (0: picked by the process and read
from its log), the scheduler's host name, the data folder, and the baked Numba cache path (the
test suite's cache instead).  Each worker starts in its own working directory, not the API's, and
the API's data folder is given relative to the API's working directory (a path that means nothing
to the workers).  A sweep is submitted over HTTP; its metrics must match the point files in the
API's data folder, the tasks must have run on the two external workers, and each task's result
must have carried its point file back through Dask (the design: workers need no shared folder).

A second test checks the wiring of compose.yaml and the Dockerfile that the processes cannot
show: one image for all services, the worker environment, the data volume, health checks.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import httpx
import pytest
import xarray as xr
import yaml

from tests.conftest import airpuff
from tests.api.test_api_jobs import check_against_files
from tests.api.support import ServerProcess, group_gone, kill_group, signal_group, wait_job

REPO = Path(__file__).resolve().parents[2]
COMPOSE = REPO / "docker" / "compose.yaml"
DOCKERFILE = REPO / "docker" / "Dockerfile"
TOKEN = "deploy-test-token"
BODY = {"E0": [0.4, 0.6], "IOP": [16.0], "thickness": [0.5], "pmax": [10.0],
        "resolution": "coarse", "t_end": 3.0}
START_TIMEOUT = 60.0  # s, for each process to come up
JOB_TIMEOUT = 120.0  # s, for the job (the API also warms the Numba cache first)


# -- compose.yaml --------------------------------------------------------------------------------
def load_compose() -> dict:
    with open(COMPOSE) as fh:
        return yaml.safe_load(fh)


def flag(cmd: list[str], name: str) -> str:
    assert name in cmd, f"{name} missing from {cmd}"
    return cmd[cmd.index(name) + 1]


def scheduler_url(compose: dict) -> str:
    """The address the other services use for the scheduler: tcp://<service name>:<port>."""
    return f"tcp://scheduler:{flag(compose['services']['scheduler']['command'], '--port')}"


def localize(cmd: list[str], compose: dict, *, scheduler: str | None = None,
             data_dir: str | None = None) -> list[str]:
    """A compose command as a local process on loopback: same program and arguments, with the
    container-specific values substituted (see the module docstring)."""
    out = []
    for i, arg in enumerate(cmd):
        prev = cmd[i - 1] if i else None
        if prev == "--host":
            arg = "127.0.0.1"
        elif prev == "--port":
            arg = "0"
        elif prev == "--dashboard-address":
            arg = "127.0.0.1:0"
        elif prev == "--data-dir":
            assert data_dir is not None
            arg = data_dir
        elif arg == scheduler_url(compose):
            assert scheduler is not None
            arg = scheduler
        out.append(arg)
    out[0] = executable(out[0])
    return out


def executable(name: str) -> str:
    """The console script ``name`` of this environment (the venv's bin/), else from PATH."""
    here = Path(sys.executable).parent / name
    path = str(here) if here.exists() else shutil.which(name)
    if path is None:
        pytest.fail(f"the command {name!r} of compose.yaml is not installed here "
                    "(pip install -e . provides airpuff; dask[distributed] provides dask)")
    return path


def service_env(service: dict, **extra: str) -> dict[str, str]:
    """This process's environment plus the service's, with the baked Numba cache path replaced
    by this test suite's (tests/conftest.py sets NUMBA_CACHE_DIR)."""
    env = dict(os.environ)
    env.pop("AIRPUFF_API_TOKEN", None)
    for k, v in (service.get("environment") or {}).items():
        if "${" not in str(v):  # values interpolated by compose come from the test instead
            env[k] = str(v)
    env["NUMBA_CACHE_DIR"] = os.environ["NUMBA_CACHE_DIR"]
    env["PYTHONPATH"] = str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")
    env.update(extra)
    return env


# -- processes -----------------------------------------------------------------------------------
class Proc:
    """One command in its own session (process group), output to a log file."""

    def __init__(self, name: str, cmd: list[str], cwd: Path, env: dict, log_dir: Path):
        self.name, self.cmd = name, cmd
        self.stopped = False
        self.log_path = log_dir / f"{name}.log"
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=self._log,
                                     stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                     start_new_session=True)

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait_for(self, pattern: str, timeout: float = START_TIMEOUT) -> re.Match:
        deadline = time.monotonic() + timeout
        while True:
            m = re.search(pattern, self.log())
            if m:
                return m
            if self.proc.poll() is not None:
                raise AssertionError(f"{self.name} exited with {self.proc.returncode}:\n"
                                     + self.log()[-3000:])
            if time.monotonic() > deadline:
                raise AssertionError(f"{self.name}: no {pattern!r} after {timeout} s:\n"
                                     + self.log()[-3000:])
            time.sleep(0.1)

    def stop(self, timeout: float = 30.0) -> float:
        """SIGTERM to the group; the seconds until every process of the group is gone."""
        t0 = time.monotonic()
        signal_group(self.proc.pid, signal.SIGTERM)
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"{self.name} ignored SIGTERM for {timeout} s:\n"
                                 + self.log()[-3000:]) from None
        assert group_gone(self.proc.pid, timeout), f"processes of {self.name} outlived it"
        self.stopped = True
        self._log.close()
        return time.monotonic() - t0

    def kill(self) -> None:
        """Last resort, always run: SIGKILL the whole group (unless it stopped cleanly)."""
        if self.stopped:
            return
        kill_group(self.proc)
        self._log.close()


# -- the tests -----------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.service
@pytest.mark.cluster
def test_compose_topology_as_local_processes(tmp_path):
    """scheduler + 2 workers (each in its own working directory) + `airpuff serve --scheduler`,
    as compose.yaml runs them; a sweep over HTTP; its metrics match the API's point files."""
    from distributed import Client

    compose = load_compose()
    services = compose["services"]
    n_workers = int(services["worker"]["deploy"]["replicas"])
    logs = tmp_path / "logs"
    api_cwd = tmp_path / "api"
    worker_cwds = [tmp_path / f"worker-{i + 1}" for i in range(n_workers)]
    for d in (logs, api_cwd, *worker_cwds):
        d.mkdir()
    data_rel = "data"  # relative to the API's working directory on purpose
    procs: list[Proc] = []
    client = None
    t0 = time.monotonic()
    try:
        sched = Proc("scheduler", localize(services["scheduler"]["command"], compose),
                     tmp_path, service_env(services["scheduler"]), logs)
        procs.append(sched)
        address = sched.wait_for(r"Scheduler at:\s+(tcp://127\.0\.0\.1:\d+)").group(1)
        dashboard = sched.wait_for(r"[Dd]ashboard at:\s+(http://127\.0\.0\.1:\d+)").group(1)
        assert httpx.get(f"{dashboard}/health", timeout=5).text == "ok"  # compose's health check

        for i, cwd in enumerate(worker_cwds):
            procs.append(Proc(f"worker-{i + 1}", localize(services["worker"]["command"], compose,
                                                         scheduler=address),
                              cwd, service_env(services["worker"]), logs))
        api_cmd = localize(services["api"]["command"], compose, scheduler=address,
                           data_dir=data_rel)
        api = Proc("api", api_cmd, api_cwd,
                   service_env(services["api"], AIRPUFF_API_TOKEN=TOKEN), logs)
        procs.append(api)
        url = api.wait_for(r"listening on (http://127\.0\.0\.1:\d+)").group(1)

        # The test watches the cluster from outside as a second client: where did tasks run?
        client = Client(address, timeout=30)
        client.wait_for_workers(n_workers, timeout=START_TIMEOUT)
        client.get_task_stream()  # starts the scheduler's task recording
        cwds = client.run(os.getcwd)
        assert sorted(cwds.values()) == sorted(str(d) for d in worker_cwds), cwds
        assert str(api_cwd) not in cwds.values()
        env = client.run(lambda: (os.environ.get("NUMBA_NUM_THREADS"),
                                  os.environ.get("NUMBA_CACHE_DIR")))
        assert set(env.values()) == {("1", os.environ["NUMBA_CACHE_DIR"])}, env
        assert all(v == 1 for v in client.nthreads().values()), client.nthreads()

        headers = {"Authorization": f"Bearer {TOKEN}"}
        with httpx.Client(base_url=url, timeout=30, headers=headers) as http:
            deadline = time.monotonic() + START_TIMEOUT
            while (health := http.get("/health").json())["runner"] != "ready":
                assert health["runner"] != "failed", (health, api.log()[-3000:])
                assert time.monotonic() < deadline, (health, api.log()[-3000:])
                time.sleep(0.2)
            t_ready = time.monotonic() - t0

            r = http.post("/sweeps", json=BODY)
            assert r.status_code == 202, r.text
            job_id = r.json()["id"]
            job = wait_job(http, job_id, timeout=JOB_TIMEOUT)
            assert job["status"] == "done", (job, api.log()[-3000:])
            assert job["points_total"] == 2 and job["points_done"] == 2, job
            m = http.get(f"/sweeps/{job_id}/metrics")
            assert m.status_code == 200, m.text
            points = m.json()["points"]
            ds_bytes = http.get(f"/sweeps/{job_id}/dataset")
            assert ds_bytes.status_code == 200
            deadline = time.monotonic() + 15  # the runner refreshes its worker count every 5 s
            while (health := http.get("/health").json())["workers"] != n_workers:
                assert time.monotonic() < deadline, health
                time.sleep(0.5)
        assert httpx.get(f"{url}/sweeps", timeout=10).status_code == 401  # the token is in force
        t_job = time.monotonic() - t0 - t_ready

        # The metrics served are those of the point files, which the API wrote into ITS data
        # folder (relative to its own working directory) ...
        data_dir = api_cwd / data_rel
        assert check_against_files(SimpleNamespace(data_dir=data_dir), job, points) == 2
        assert all(p["DA"] is not None and p["DA"] > 0 for p in points), points
        path = tmp_path / "sweep.nc"
        path.write_bytes(ds_bytes.content)
        with xr.open_dataset(path) as ds:
            assert sorted(ds["E0"].values.tolist()) == BODY["E0"]
            assert (ds["status"] == "ok").all()
        # ... from results computed by the external workers, which wrote nothing where they run.
        tasks = [t for t in client.get_task_stream() if str(t["key"]).startswith("airpuff-point-")]
        assert len(tasks) == 2, tasks
        assert {t["worker"] for t in tasks} <= set(cwds), tasks
        # Each task's result carried its point file back through Dask (not just metrics).
        smallest = min(f.stat().st_size for f in (data_dir / "points").glob("*.nc"))
        assert all(t["nbytes"] >= smallest for t in tasks), \
            ([(t["key"], t["nbytes"]) for t in tasks], smallest)
        assert [p for d in worker_cwds for p in d.rglob("*.nc")] == []
        assert not (worker_cwds[0] / data_rel).exists()
        client.close()
        client = None

        # Stopping: the API leaves the external cluster alone; then the cluster stops cleanly.
        t_stop = {"api": api.stop()}
        assert all(p.proc.poll() is None for p in procs if p is not api), \
            "stopping the API stopped the cluster"
        t_stop.update({p.name: p.stop() for p in reversed(procs) if p is not api})
        print(f"\ncompose topology: ready {t_ready:.1f} s, job {t_job:.1f} s, "
              f"stop {max(t_stop.values()):.1f} s")
    finally:
        if client is not None:
            client.close()
        for p in reversed(procs):
            p.kill()


def test_compose_and_dockerfile_wiring():
    """What the local processes cannot show: the services share one image and its environment,
    the worker environment is one thread with the baked Numba cache, the API alone mounts the
    volume of results and database at its --data-dir, and ports and health checks agree."""
    compose = load_compose()
    services = compose["services"]
    assert set(services) == {"scheduler", "worker", "api"}
    docker_text = DOCKERFILE.read_text()
    baked_cache = re.search(r"NUMBA_CACHE_DIR=(\S+)", docker_text).group(1)

    for name, svc in services.items():
        assert svc["image"] == services["api"]["image"], name
        build = svc["build"]
        assert (COMPOSE.parent / build["context"] / build["dockerfile"]).resolve() == DOCKERFILE
        env = svc["environment"]
        assert env["NUMBA_NUM_THREADS"] == "1" and env["NUMBA_CACHE_DIR"] == baked_cache, name
        assert isinstance(svc["command"], list), f"{name}: exec form, no shell"

    sched = services["scheduler"]["command"]
    assert sched[:2] == ["dask", "scheduler"] and flag(sched, "--host") == "0.0.0.0"
    dash_port = flag(sched, "--dashboard-address").rsplit(":", 1)[1]
    assert f":{dash_port}/health" in " ".join(services["scheduler"]["healthcheck"]["test"])

    worker = services["worker"]
    assert worker["command"][:3] == ["dask", "worker", scheduler_url(compose)]
    assert flag(worker["command"], "--nthreads") == "1"
    assert worker["deploy"]["replicas"] == 2
    assert "volumes" not in worker  # results come back through Dask: no shared file system

    api = services["api"]
    cmd = api["command"]
    assert cmd[:2] == ["airpuff", "serve"] and flag(cmd, "--scheduler") == scheduler_url(compose)
    assert flag(cmd, "--host") == "0.0.0.0"
    port, data_dir = flag(cmd, "--port"), flag(cmd, "--data-dir")
    assert f"127.0.0.1:${{AIRPUFF_API_PORT:-{port}}}:{port}" in api["ports"]  # port choosable
    assert f":{port}/health" in " ".join(api["healthcheck"]["test"])
    (volume,) = [v.split(":")[0] for v in api["volumes"] if v.split(":")[1] == data_dir]
    assert volume in compose["volumes"]
    for name in ("worker", "api"):
        assert services[name]["depends_on"]["scheduler"]["condition"] == "service_healthy"

    # The Dockerfile: Python 3.11 slim, the project installed by pip from the repository (every
    # package of pyproject.toml copied in), a non-root user that owns the baked cache and
    # warms it, the API's data folder owned by that user too.
    assert re.search(r"^ARG PYTHON_IMAGE=python:3\.11-slim$", docker_text, re.M)
    include = re.search(r"^include = \[(.*)\]$", (REPO / "pyproject.toml").read_text(), re.M)
    packages = re.findall(r'"([^"]+)"', include.group(1))
    assert packages
    for pkg in packages:
        assert re.search(rf"^COPY {pkg.rstrip('*')} ", docker_text, re.M), pkg
    assert re.search(r'pip" install --quiet --no-deps "\.\[all\]"', docker_text)
    users = re.findall(r"^USER (\S+)$", docker_text, re.M)
    assert users and users[-1] not in ("root", "0")
    after_user = docker_text[docker_text.rindex("\nUSER "):]
    assert "warm_numba_cache()" in after_user and "jit_counts" in after_user  # warmed, checked
    assert re.search(rf"chown {users[-1]}:\S+ \"\$NUMBA_CACHE_DIR\" {data_dir}", docker_text)
    ignore = (DOCKERFILE.parent / "Dockerfile.dockerignore").read_text().split()
    for pkg in packages:
        assert f"!{pkg.rstrip('*')}/**" in ignore, pkg


def test_save_point_refuses_a_result_without_a_netcdf_file(tmp_path):
    """The API stores what came back through Dask only if it is a netCDF file."""
    from sweep.record import PointRecord
    from sweep.storage import failed_path, point_path, save_point

    with pytest.raises(ValueError, match="carries no netCDF file"):
        save_point(tmp_path, "k1", PointRecord(key="k1", status="ok"), b"<html>")
    with pytest.raises(ValueError, match="carries no netCDF file"):
        save_point(tmp_path, "k1", PointRecord(key="k1", status="ok"))
    assert not point_path(tmp_path, "k1").exists()
    rec = save_point(tmp_path, "k2", PointRecord(key="k2", status="failed", message="blew up",
                                                 pid=1, computed=True))
    assert rec.status == "failed" and failed_path(tmp_path, "k2").exists()
    assert "pid" not in failed_path(tmp_path, "k2").read_text()


@pytest.mark.slow
@pytest.mark.service
@pytest.mark.cluster
def test_a_point_file_whose_record_was_lost_is_read_back_not_recomputed(tmp_path):
    """The API writes a point file, then its record; a crash in between leaves a file without a
    record.  The next runner takes the file as the point's result instead of recomputing it."""
    from airpuff_core.params import RunParams
    from sweep.storage import point_key, point_path, save_point
    from sweep.worker import compute_point

    body = {"E0": [0.5], "IOP": [12.0, 18.0], "thickness": [0.5], "pmax": [10.0],
            "resolution": "coarse", "t_end": 1.0}
    data = tmp_path / "data"
    queued = ServerProcess(data, "--no-runner")
    server = ServerProcess(data, "--workers", "1")
    try:
        queued.start()
        with queued.client() as c:
            r = c.post("/sweeps", json=body)
            assert r.status_code == 202, r.text
            job_id = r.json()["id"]
        queued.stop()

        # The first point's result as it comes back from a worker, stored by save_point.
        options = {k: v for k, v in body.items() if k not in ("E0", "IOP", "thickness", "pmax")}
        params = RunParams.from_dict({**options, "E0": 0.5, "IOP": 12.0, "thickness": 0.5,
                                      "pmax": 10.0})
        rec, netcdf = compute_point(params)
        assert rec.status == "ok" and netcdf[:4] == b"\x89HDF", rec.message
        key = point_key(params)
        save_point(data / "points", key, rec, netcdf)
        before = point_path(data / "points", key).stat()

        server.start()
        with server.client() as c:
            job = wait_job(c, job_id, timeout=JOB_TIMEOUT)
            assert job["status"] == "done", job
            points = {p["IOP"]: p for p in c.get(f"/sweeps/{job_id}/metrics").json()["points"]}
        assert points[12.0]["key"] == key and points[12.0]["reused"] is True
        assert points[18.0]["reused"] is False and points[18.0]["status"] == "ok"
        for name, value in rec.metrics.items():
            assert points[12.0][name] == value, name
        after = point_path(data / "points", key).stat()
        assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)
        server.stop()
    finally:
        for s in (queued, server):
            if s.proc is not None:
                s.kill()


@pytest.mark.parametrize("address", ["scheduler", "tcp://scheduler", "foo://scheduler:8786",
                                     "tcp://scheduler:87x6"])
def test_a_malformed_scheduler_address_is_one_line_error(tmp_path, address):
    proc = airpuff("serve", "--port", "0", "--data-dir", str(tmp_path / "d"), "--scheduler",
                   address, timeout=60)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        f"airpuff serve: error: invalid --scheduler={address!r}: accepted a Dask scheduler "
        "address such as tcp://host:8786"), proc.stderr
