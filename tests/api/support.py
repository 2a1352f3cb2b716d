"""Helpers of the API tests (no tests here): a real `airpuff serve` subprocess on a loopback port.

The server is started as ``python -m api.cli serve --port 0 ...`` in its own session (process
group), so that the test can check that stopping it leaves no process (Dask workers included)
behind.  It prints the address it listens on; the helper waits for ``/health``.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Iterator

import httpx

REPO = Path(__file__).resolve().parents[2]
LISTEN_RE = re.compile(r"listening on (http://\S+?:\d+)")


class ServerProcess:
    def __init__(self, data_dir: Path, *args: str, token: str | None = None,
                 log_path: Path | None = None, env: dict[str, str] | None = None):
        self.data_dir = Path(data_dir)
        self.args = list(args)
        self.token = token
        self.env = dict(env or {})  # set in the server's environment
        self.log_path = Path(log_path) if log_path else self.data_dir.parent / (
            self.data_dir.name + f"-server-{time.monotonic_ns()}.log")
        self.proc: subprocess.Popen | None = None
        self.url: str | None = None

    # -- life cycle ---------------------------------------------------------------------------
    def start(self, timeout: float = 180.0, wait_runner: bool = False) -> "ServerProcess":
        env = {**os.environ, **self.env}
        env.pop("AIRPUFF_API_TOKEN", None)
        if self.token is not None:
            env["AIRPUFF_API_TOKEN"] = self.token
        cmd = [sys.executable, "-m", "api.cli", "serve", "--port", "0",
               "--data-dir", str(self.data_dir), "--log-level", "info", *self.args]
        self._log = open(self.log_path, "ab")
        self.proc = subprocess.Popen(cmd, cwd=REPO, stdout=self._log, stderr=subprocess.STDOUT,
                                     env=env, start_new_session=True)
        deadline = time.monotonic() + timeout
        while self.url is None:
            m = LISTEN_RE.search(self.log_text())
            if m:
                self.url = m.group(1)
                break
            self._check_alive()
            if time.monotonic() > deadline:
                self.kill()
                raise AssertionError("server did not start:\n" + self.log_text()[-3000:])
            time.sleep(0.1)
        with httpx.Client(base_url=self.url, timeout=5) as c:
            while True:
                self._check_alive()
                try:
                    r = c.get("/health")
                    if r.status_code == 200 and (not wait_runner
                                                 or r.json()["runner"] == "ready"):
                        break
                    if wait_runner and r.json()["runner"] == "failed":
                        raise AssertionError(f"runner failed: {r.json()}\n{self.log_text()[-3000:]}")
                except httpx.TransportError:
                    pass
                if time.monotonic() > deadline:
                    self.kill()
                    raise AssertionError("server not healthy:\n" + self.log_text()[-3000:])
                time.sleep(0.2)
        return self

    @contextlib.contextmanager
    def running(self, **start_options) -> Iterator["ServerProcess"]:
        """The started server for the length of a ``with`` block (a module fixture's life)."""
        try:
            yield self.start(**start_options)
        finally:
            if self.proc is not None:
                self.stop()

    def _check_alive(self) -> None:
        if self.proc is not None and self.proc.poll() is not None:
            raise AssertionError(f"server exited with {self.proc.returncode}:\n"
                                 + self.log_text()[-3000:])

    def client(self, token: str | None = "default", timeout: float = 30.0) -> httpx.Client:
        tok = self.token if token == "default" else token
        headers = {"Authorization": f"Bearer {tok}"} if tok else {}
        return httpx.Client(base_url=self.url, timeout=timeout, headers=headers)

    def log_text(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except FileNotFoundError:
            return ""

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 60.0) -> float:
        """Send ``sig`` to the server, wait for it and for every process of its group (the Dask
        workers) to be gone.  Returns the seconds that took; raises if anything lingered."""
        if self.proc is None:
            return 0.0
        t0 = time.monotonic()
        pgid = self.proc.pid
        try:
            self.proc.send_signal(sig)
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            raise AssertionError(f"server ignored signal {sig} for {timeout} s:\n"
                                 + self.log_text()[-3000:])
        lingering = not group_gone(pgid, timeout)
        elapsed = time.monotonic() - t0
        self._log.close()
        self.proc = None
        if lingering:
            signal_group(pgid, signal.SIGKILL)
            raise AssertionError("processes of the server outlived it (killed now)")
        return elapsed

    def kill(self) -> None:
        """Last resort (also on test failure): SIGKILL the whole process group."""
        if self.proc is None:
            return
        kill_group(self.proc)
        self._log.close()
        self.proc = None


def signal_group(pgid: int, sig: int) -> None:
    """Send ``sig`` to every process of the group ``pgid`` (none left: nothing to do)."""
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL every process of the group of ``proc`` (started in its own session) and wait
    (up to 30 s) for them to be gone."""
    signal_group(proc.pid, signal.SIGKILL)
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        pass
    group_gone(proc.pid, 30)


def group_gone(pgid: int, timeout: float) -> bool:
    """True once no process of the group ``pgid`` is left; False if some still live after
    ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            os.killpg(pgid, 0)
        except (ProcessLookupError, PermissionError):
            return True
        time.sleep(0.1)
    return False


def wait_job(client: httpx.Client, job_id: str, until=("done", "failed", "cancelled"),
             timeout: float = 300.0, poll: float = 0.3) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        r = client.get(f"/sweeps/{job_id}")
        assert r.status_code == 200, r.text
        job = r.json()
        if job["status"] in until:
            return job
        if time.monotonic() > deadline:
            raise AssertionError(f"job {job_id} still {job['status']} after {timeout} s: {job}")
        time.sleep(poll)


def post_at_once(server: ServerProcess, bodies: list[dict]) -> list[httpx.Response]:
    """``POST /sweeps`` of each body from its own thread and connection, all released at the
    same moment (a barrier): the answers, in the order of ``bodies``."""
    barrier = threading.Barrier(len(bodies))
    answers: list = [None] * len(bodies)

    def post(k: int) -> None:
        with server.client() as c:
            barrier.wait()
            answers[k] = c.post("/sweeps", json=bodies[k])

    threads = [threading.Thread(target=post, args=(k,)) for k in range(len(bodies))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return answers


def submit(client: httpx.Client, body: dict) -> str:
    """POST a sweep; its job id (asserts a 202)."""
    r = client.post("/sweeps", json=body)
    assert r.status_code == 202, r.text
    return r.json()["id"]
