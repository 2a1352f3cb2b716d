"""The deployment of docker/compose.yaml on a real Docker engine: the image, its containers, a sweep.

Marked ``docker`` (``pytest -m docker`` selects these tests alone).  They need a running Docker
engine and `docker-compose` (or the `docker compose` plugin); `.ci/run` installs and starts them
where root and apt-get allow.  Without an engine the module is skipped with one line saying why.

The image is built by `docker/build.sh` (the documented way), once per module; the build's
network mode is `host` and pip's CA bundle is the one pip is configured with here, if any (where
the package index is reached only through the host's network and a TLS proxy).  The stack is
compose.yaml itself, under a project name of its own, with the published ports picked by Docker:
a scheduler, two workers and the API with its data volume.  Everything started (containers,
network, volume) is removed at the end; the image stays, as the build cache of the next build.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
import xarray as xr

pytestmark = pytest.mark.docker

REPO = Path(__file__).resolve().parents[2]
COMPOSE = REPO / "docker" / "compose.yaml"
IMAGE = "airpuff:local"
TOKEN = "docker-test-token"
USER_ID = "10001"  # the image's runtime user (docker/Dockerfile)
# The 2 x 2 sweep; a short simulated time keeps it coarse and quick.
SWEEP = {"E0": [0.4, 0.6], "IOP": [12.0, 18.0], "thickness": [0.5], "pmax": [10.0],
         "resolution": "coarse", "t_end": 3.0}
# One point of it, computed alone in a worker container.
POINT = {"E0": 0.5, "IOP": 15.0, "thickness": 0.5, "pmax": 10.0, "resolution": "coarse",
         "t_end": 3.0}
# Two longer points for the killed worker: each worker holds one while the kill comes.
KILL_SWEEP = {"E0": [0.45, 0.55], "IOP": [15.0], "thickness": [0.5], "pmax": [10.0],
              "resolution": "coarse"}
BUILD_TIMEOUT = 1800.0  # s: a first build downloads the dependencies and warms the Numba cache
START_TIMEOUT = 180.0  # s, for the stack to answer "ready" with 2 workers
JOB_TIMEOUT = 600.0  # s (a machine shared with other builds can be slow)


def run(*cmd: str, timeout: float = 120.0, check: bool = True, env: dict | None = None,
        ) -> subprocess.CompletedProcess:
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    if check and proc.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} exited with {proc.returncode}:\n"
                             f"{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}")
    return proc


def compose_command() -> list[str] | None:
    """`docker compose` (the plugin) or `docker-compose` (the standalone program), if either."""
    if run("docker", "compose", "version", check=False).returncode == 0:
        return ["docker", "compose"]
    if shutil.which("docker-compose"):
        return ["docker-compose"]
    return None


def engine_missing() -> str | None:
    """Why these tests cannot run here, or None."""
    if shutil.which("docker") is None:
        return "no docker command (.ci/run installs Debian's docker.io as root)"
    info = run("docker", "info", "--format", "{{.ServerVersion}}", check=False, timeout=30)
    if info.returncode != 0:
        return f"no Docker engine answers: {(info.stderr.strip().splitlines() or ['?'])[-1]}"
    if compose_command() is None:
        return "neither `docker compose` nor docker-compose is installed"
    return None


def pip_ca_bundle() -> str | None:
    """The CA bundle pip is configured with on this machine (PIP_CERT or pip's `cert` setting),
    if any: the build's pip must trust the same authorities to reach the same index."""
    cert = os.environ.get("PIP_CERT")
    if not cert:
        proc = run(sys.executable, "-m", "pip", "config", "get", "global.cert", check=False)
        cert = proc.stdout.strip() if proc.returncode == 0 else None
    return cert if cert and Path(cert).is_file() else None


class Stack:
    """compose.yaml as a project of its own: `compose(...)` runs a compose sub-command on it."""

    def __init__(self, project: str):
        self.project = project
        self.env = dict(os.environ, AIRPUFF_API_PORT="0", AIRPUFF_DASHBOARD_PORT="0",
                        AIRPUFF_API_TOKEN=TOKEN)
        self.headers = {"Authorization": f"Bearer {TOKEN}"}
        self.jobs: dict[str, dict] = {}  # job id -> metrics, for the restart test

    def compose(self, *args: str, timeout: float = 300.0, check: bool = True):
        return run(*compose_command(), "-p", self.project, "-f", str(COMPOSE), *args,
                   timeout=timeout, check=check, env=self.env)

    def containers(self, service: str) -> list[str]:
        ids = self.compose("ps", "-q", service).stdout.split()
        assert ids, f"no container of {service}"
        return ids

    def url(self) -> str:
        port = self.compose("port", "api", "8000").stdout.strip().rsplit(":", 1)[1]
        return f"http://127.0.0.1:{port}"

    def http(self) -> httpx.Client:
        return httpx.Client(base_url=self.url(), timeout=30, headers=self.headers)

    def wait_ready(self, workers: int = 2) -> float:
        """Seconds until the API answers with its runner ready and ``workers`` workers."""
        t0 = time.monotonic()
        health: dict = {}
        while time.monotonic() - t0 < START_TIMEOUT:
            try:
                health = httpx.get(f"{self.url()}/health", timeout=5, headers=self.headers).json()
                if health.get("runner") == "ready" and health.get("workers") == workers:
                    return time.monotonic() - t0
                assert health.get("runner") != "failed", health
            except (httpx.HTTPError, IndexError, AssertionError) as err:
                if isinstance(err, AssertionError):
                    raise
            time.sleep(1)
        raise AssertionError(f"not ready after {START_TIMEOUT} s: {health}\n{self.logs()}")

    def logs(self) -> str:
        return self.compose("logs", "--no-color", "--tail", "40", check=False).stdout[-6000:]

    def wait_job(self, http: httpx.Client, job_id: str) -> dict:
        deadline = time.monotonic() + JOB_TIMEOUT
        while (job := http.get(f"/sweeps/{job_id}").json())["status"] in ("queued", "running"):
            assert time.monotonic() < deadline, (job, self.logs())
            time.sleep(1)
        return job


def inspect(container: str, template: str) -> str:
    return run("docker", "inspect", "-f", template, container).stdout.strip()


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    why = engine_missing()
    if why:
        pytest.skip(f"Docker deployment not tested: {why}")
    build = [str(REPO / "docker" / "build.sh"), "--tag", IMAGE, "--network", "host"]
    if (ca := pip_ca_bundle()) is not None:
        build += ["--ca-bundle", ca]
    t0 = time.monotonic()
    run(*build, timeout=BUILD_TIMEOUT)
    t_build = time.monotonic() - t0
    size_mb = int(inspect(IMAGE, "{{.Size}}")) / 1e6

    s = Stack(f"airpufftest{os.getpid()}")
    try:
        t0 = time.monotonic()
        s.compose("up", "-d", "--no-build")
        t_ready = s.wait_ready()
        t_up = time.monotonic() - t0
        print(f"\ndocker: image {size_mb:.0f} MB, build {t_build:.0f} s (cached layers reused), "
              f"stack up and ready {t_up:.1f} s")
        yield s
    finally:
        s.compose("down", "--volumes", "--remove-orphans", "--timeout", "10", check=False)
        left = run("docker", "ps", "-aq", "--filter", f"label=com.docker.compose.project={s.project}",
                   check=False).stdout.split()
        assert not left, f"containers left behind: {left}"


def test_every_container_runs_as_the_non_root_user(stack):
    for service in ("scheduler", "worker", "api"):
        for cid in stack.containers(service):
            assert run("docker", "exec", cid, "id", "-u").stdout.strip() == USER_ID, service
            # Every process of the container, PID 1 (docker-init) included, as seen by the host.
            top = run("docker", "top", cid, "-eo", "pid,uid,args").stdout.splitlines()[1:]
            assert top and all(line.split()[1] == USER_ID for line in top), (service, top)
    assert len(stack.containers("worker")) == 2


def test_the_numba_cache_of_the_image_is_warm(stack):
    """In a worker container, a fresh process computes two points: the first loads every kernel
    from the image's cache and compiles none; its extra time over the second is the start-up
    that a cold cache would spend compiling."""
    worker = stack.containers("worker")[0]
    code = ("import json; from airpuff_core.params import RunParams; "
            "from sweep.worker import compute_point; "
            f"p = RunParams.from_dict({json.dumps(POINT)}); "
            "r = [compute_point(p)[0] for _ in range(2)]; "
            "print(json.dumps([{k: getattr(x, k) for k in ('wall_s', 'jit_compiled', 'jit_loaded', "
            "'first_in_process', 'status')} for x in r]))")
    first, second = json.loads(run("docker", "exec", worker, "python", "-c", code,
                                   timeout=300).stdout.splitlines()[-1])
    assert first["status"] == second["status"] == "ok", (first, second)
    assert first["first_in_process"] and first["jit_compiled"] == 0, first
    assert first["jit_loaded"] > 0, first  # the kernels came from the cache, not from nowhere
    assert second["jit_compiled"] == second["jit_loaded"] == 0, second
    print(f"\nworker container, fresh process: first point {first['wall_s']:.2f} s "
          f"({first['jit_loaded']} kernels loaded, 0 compiled), second {second['wall_s']:.2f} s")


def point_files(stack, tmp_path: Path) -> dict[str, Path]:
    """The API's point files (its volume), copied out of the container: key -> path."""
    api = stack.containers("api")[0]
    run("docker", "cp", f"{api}:/data/points", str(tmp_path))
    return {p.stem: p for p in (tmp_path / "points").glob("*.nc")}


def test_a_sweep_over_http_is_computed_by_the_worker_containers(stack, tmp_path):
    with stack.http() as http:
        assert httpx.get(f"{stack.url()}/sweeps", timeout=10).status_code == 401  # token needed
        r = http.post("/sweeps", json=SWEEP)
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        t0 = time.monotonic()
        job = stack.wait_job(http, job_id)
        t_job = time.monotonic() - t0
        assert job["status"] == "done" and job["points_done"] == 4, (job, stack.logs())
        metrics = http.get(f"/sweeps/{job_id}/metrics")
        assert metrics.status_code == 200, metrics.text
        points = metrics.json()["points"]
        dataset = http.get(f"/sweeps/{job_id}/dataset")
        assert dataset.status_code == 200, dataset.text
    stack.jobs[job_id] = points
    print(f"\n2 x 2 coarse sweep on the containers: {t_job:.1f} s")

    assert len(points) == 4 and all(p["status"] == "ok" for p in points), points
    (tmp_path / "sweep.nc").write_bytes(dataset.content)
    with xr.open_dataset(tmp_path / "sweep.nc") as ds:
        assert sorted(ds["E0"].values.tolist()) == SWEEP["E0"]
        assert sorted(ds["IOP"].values.tolist()) == SWEEP["IOP"]
        assert (ds["status"] == "ok").all()
        for p in points:  # the combined file holds the metrics served
            at = ds["DA"].sel(E0=p["E0"], IOP=p["IOP"], thickness=p["thickness"],
                              pmax=p["pmax"])
            assert float(at) == pytest.approx(p["DA"], rel=1e-12), p

    # The point files were computed by the worker containers: their provenance names the
    # host, the hostname of a worker container (not the API's, which stored them).
    files = point_files(stack, tmp_path)
    workers = {inspect(c, "{{.Config.Hostname}}") for c in stack.containers("worker")}
    api_host = inspect(stack.containers("api")[0], "{{.Config.Hostname}}")
    hosts = set()
    for p in points:
        with xr.open_dataset(files[p["key"]]) as ds:
            hosts.add(ds.attrs["computed_on_host"])
            assert float(ds["DA"]) == pytest.approx(p["DA"], rel=1e-12)
    assert hosts <= workers and api_host not in hosts, (hosts, workers, api_host)


def processing_workers(stack) -> dict[str, int]:
    """Worker IP -> number of sweep tasks it is computing now (asked of the scheduler)."""
    scheduler = stack.containers("scheduler")[0]
    code = ("import json; from distributed import Client; c = Client('tcp://127.0.0.1:8786', "
            "timeout=30); print(json.dumps({a.split('://')[1].rsplit(':', 1)[0]: "
            "sum(str(k).startswith('airpuff-point-') for k in ks) "
            "for a, ks in c.processing().items()})); c.close()")
    return json.loads(run("docker", "exec", scheduler, "python", "-c", code,
                          timeout=120).stdout.splitlines()[-1])


def test_a_sigkilled_worker_container_is_survived(stack, tmp_path):
    """SIGKILL the worker container that is computing a point: the scheduler gives its task to
    the other worker and the job finishes with every point."""
    ips = {inspect(c, "{{range .NetworkSettings.Networks}}{{.IPAddress}}{{end}}"): c
           for c in stack.containers("worker")}
    with stack.http() as http:
        r = http.post("/sweeps", json=KILL_SWEEP)
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        deadline = time.monotonic() + JOB_TIMEOUT
        while not any((busy := processing_workers(stack)).values()):
            assert time.monotonic() < deadline, stack.logs()
            time.sleep(0.5)
        victim_ip = next(ip for ip, n in busy.items() if n)
        assert http.get(f"/sweeps/{job_id}").json()["points_done"] < 2
        victim = ips[victim_ip]
        run("docker", "kill", "--signal", "KILL", victim)
        job = stack.wait_job(http, job_id)
        assert job["status"] == "done" and job["points_done"] == 2, (job, stack.logs())
        points = http.get(f"/sweeps/{job_id}/metrics").json()["points"]
    assert all(p["status"] == "ok" for p in points), points
    stack.jobs[job_id] = points
    # The killed worker did not finish its point: the survivor computed it.
    files = point_files(stack, tmp_path)
    survivors = {inspect(c, "{{.Config.Hostname}}") for c in ips.values() if c != victim}
    hosts = set()
    for p in points:
        with xr.open_dataset(files[p["key"]]) as ds:
            hosts.add(ds.attrs["computed_on_host"])
    assert hosts & survivors, (hosts, survivors)
    # A killed container stays down (Docker restarts only what exits by itself); started
    # again, the worker rejoins the scheduler.
    run("docker", "start", victim)
    print(f"\nkilled worker started again, stack ready in {stack.wait_ready():.1f} s")


def test_a_recreated_api_container_keeps_its_jobs(stack):
    """A new API container on the same volume serves the earlier jobs and their results."""
    assert stack.jobs, "the sweeps above did not run"
    old = stack.containers("api")[0]
    t0 = time.monotonic()
    stack.compose("up", "-d", "--no-build", "--no-deps", "--force-recreate", "api")
    new = stack.containers("api")[0]
    assert new != old
    stack.wait_ready()
    print(f"\nAPI container recreated and ready in {time.monotonic() - t0:.1f} s")
    with stack.http() as http:
        for job_id, points in stack.jobs.items():
            job = http.get(f"/sweeps/{job_id}").json()
            assert job["status"] == "done", job
            assert http.get(f"/sweeps/{job_id}/metrics").json()["points"] == points
            assert http.get(f"/sweeps/{job_id}/dataset").content[:4] == b"\x89HDF"
