"""`airpuff serve`: the HTTP API under uvicorn, with the job runner that owns the Dask client.

    airpuff serve [--host 127.0.0.1] [--port 8000] [--data-dir DIR] [--workers 2 | --scheduler ADDR]

One process: uvicorn serves the FastAPI app; the app's lifespan starts the runner thread, which
starts a LocalCluster of worker processes (or joins ``--scheduler``).  SIGINT/SIGTERM stop the
server, the runner and the cluster; jobs still running are resumed by the next server started on
the same data directory.
"""

from __future__ import annotations

import argparse
import dataclasses
import ipaddress
import logging
import os
import socket
import sys
from pathlib import Path

from api.hosts import ALLOWED_HOSTS_ENV, parse_allowed_hosts
from api.settings import (DEFAULT_MAX_PENDING_PER_CLIENT, DEFAULT_MAX_PENDING_POINTS,
                          DEFAULT_MAX_POINTS, DEFAULT_TIME_LIMIT_S, TOKEN_ENV, Settings)

from .common import fail, parse_whole

PROG = "airpuff serve"


def add_serve_parser(sub) -> None:
    p = sub.add_parser("serve", help="serve parameter sweeps over HTTP", description=(
        "Start the HTTP API (FastAPI under uvicorn) and the job runner that owns the Dask "
        f"cluster. When {TOKEN_ENV} is set (printable ASCII, no white space), every endpoint "
        "except /health, /docs and /openapi.json requires 'Authorization: Bearer <token>'. API documentation: /docs and /openapi.json."))
    p.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default 127.0.0.1, this machine only)")
    p.add_argument("--port", default="8000", help="TCP port (default 8000; 0 picks a free one)")
    p.add_argument("--data-dir", default="airpuff-data", metavar="DIR",
                   help="folder of the job database (airpuff.db) and the netCDF results "
                        "(default ./airpuff-data)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", default=None, metavar="N",
                   help="local Dask worker processes, one thread each (default 2)")
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="use the Dask scheduler at ADDRESS (e.g. tcp://host:8786) instead of "
                        "local workers; results come back through Dask, so its workers need "
                        "not see DIR (they need airpuff installed, one thread each and "
                        "NUMBA_NUM_THREADS=1)")
    p.add_argument("--allowed-hosts", default=os.environ.get(ALLOWED_HOSTS_ENV, ""),
                   metavar="NAMES",
                   help="further names by which clients reach the server, comma separated (the "
                        "Host header; default from $" + ALLOWED_HOSTS_ENV + "): localhost, "
                        "127.0.0.1, ::1 and the --host address are always accepted, any IP "
                        "address too when --host is 0.0.0.0 or ::; '*' accepts any name (behind "
                        "a proxy that checks it). Others get 400: the defence against DNS "
                        "rebinding")
    p.add_argument("--max-points", default=str(DEFAULT_MAX_POINTS), metavar="N",
                   help=f"largest grid a request may ask for (default {DEFAULT_MAX_POINTS})")
    p.add_argument("--task-time-limit", default=f"{DEFAULT_TIME_LIMIT_S:g}", metavar="SECONDS",
                   help="wall-clock limit of one point; a point running longer is stopped (its "
                        f"worker restarted) and fails (default {DEFAULT_TIME_LIMIT_S:g})")
    p.add_argument("--max-pending-points", default=str(DEFAULT_MAX_PENDING_POINTS), metavar="N",
                   help="points waiting in all queued and running jobs at most; a job above "
                        f"gets 503 (default {DEFAULT_MAX_PENDING_POINTS})")
    p.add_argument("--max-pending-per-client", default=str(DEFAULT_MAX_PENDING_PER_CLIENT),
                   metavar="N", help="points waiting from one client address at most; a job "
                                     f"above gets 429 (default {DEFAULT_MAX_PENDING_PER_CLIENT})")
    p.add_argument("--no-runner", action="store_true",
                   help="serve the API only: jobs are stored and stay queued until a server "
                        "with a runner is started on the same data directory")
    p.add_argument("--log-level", default="info",
                   choices=("critical", "error", "warning", "info", "debug"),
                   help="log level (default info)")
    p.set_defaults(func=serve_command)


def _int(name: str, text: str, lo: int, hi: int) -> int:
    try:
        v = parse_whole(str(text))
    except ValueError:
        v = None
    if v is None or not lo <= v <= hi:
        fail(PROG, ValueError(f"invalid {name}={text!r}: accepted an integer in [{lo}, {hi}]"))
    return v


def _scheduler(text: str | None) -> str | None:
    """A Dask scheduler address, checked for its form only (reaching it is the runner's job:
    it retries, so the server may start before the scheduler does)."""
    if text is None:
        return None
    from distributed.comm.addressing import parse_address, parse_host_port
    from distributed.comm.registry import get_backend

    address = text.strip()
    try:
        scheme, location = parse_address(address)
        get_backend(scheme)
        if scheme in ("tcp", "tls", "ws", "wss"):
            host, _ = parse_host_port(location)
            if not host:
                raise ValueError("no host")
    except (ValueError, TypeError) as err:
        fail(PROG, ValueError(f"invalid --scheduler={text!r}: accepted a Dask scheduler address "
                              f"such as tcp://host:8786 ({err})"))
    return address


def _check_token() -> None:
    """The token must be sendable as it is in an HTTP header: printable ASCII, no white space
    around it (otherwise the server would answer 401 to everyone).  Never echoes the token."""
    token = os.environ.get(TOKEN_ENV)
    if not token:
        return
    problem = None
    if token != token.strip():
        problem = "it has white space around it"
    elif not token.isascii():
        problem = "it has non-ASCII characters"
    elif not token.isprintable() or any(c.isspace() for c in token):
        problem = "it has white space or control characters"
    if problem:
        fail(PROG, ValueError(f"invalid {TOKEN_ENV}: {problem}; accepted: printable ASCII "
                              "characters without white space (e.g. from `openssl rand -hex 32`)"))


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def serve_command(args: argparse.Namespace) -> int:
    _check_token()
    port = _int("--port", args.port, 0, 65535)
    max_points = _int("--max-points", args.max_points, 1, 10**9)
    workers = 2 if args.workers is None else _int("--workers", args.workers, 1, 1024)
    scheduler = _scheduler(args.scheduler)
    data_dir = Path(args.data_dir)
    try:
        data_dir.mkdir(parents=True, exist_ok=True)
        probe = data_dir / ".write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as err:
        fail(PROG, ValueError(f"invalid --data-dir={args.data_dir!r}: accepted a writable "
                              f"folder ({err.strerror})"))
    time_limit = _int("--task-time-limit", args.task_time_limit, 1, 10**7)
    max_pending = _int("--max-pending-points", args.max_pending_points, 1, 10**9)
    per_client = _int("--max-pending-per-client", args.max_pending_per_client, 1, 10**9)
    try:
        allowed_hosts = parse_allowed_hosts(args.allowed_hosts)
    except ValueError as err:
        fail(PROG, ValueError(f"invalid --allowed-hosts: {err}; accepted: host names or IP "
                              "addresses, comma separated, or '*'"))
    settings = Settings.from_env(data_dir.resolve(), max_points=max_points, workers=workers,
                                 scheduler=scheduler, run_jobs=not args.no_runner,
                                 bind_address=args.host, allowed_hosts=allowed_hosts,
                                 task_time_limit=float(time_limit),
                                 max_pending_points=max_pending,
                                 max_pending_per_client=per_client)

    logging.basicConfig(level=args.log_level.upper(),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if args.log_level != "debug":  # Dask's own INFO lines drown the service's
        logging.getLogger("distributed").setLevel(logging.WARNING)
    lock = None
    if settings.run_jobs:
        from api.runner import RunnerLocked, acquire_runner_lock

        try:
            lock = acquire_runner_lock(settings.data_dir)
        except RunnerLocked as err:
            sys.stderr.write(f"{PROG}: error: {err}\n")
            return 1

    from api import db

    try:  # before uvicorn: a damaged or newer database stops the server with one line
        db.init(settings.db_path)
    except db.DatabaseUnusable as err:
        sys.stderr.write(f"{PROG}: error: {err}\n")
        return 1

    # Bind before anything starts, so a busy port is reported at once (and --port 0 works).
    try:
        family = socket.AF_INET6 if ":" in args.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((args.host, port))
        sock.listen(128)
        sock.set_inheritable(False)
    except (OSError, OverflowError) as err:
        sys.stderr.write(f"{PROG}: error: cannot listen on {args.host}:{port}: {err}\n")
        return 1
    actual_port = sock.getsockname()[1]
    if not _is_loopback(args.host) and not settings.token:
        sys.stderr.write(f"{PROG}: warning: listening on {args.host} without {TOKEN_ENV}: "
                         "anyone who can reach this port can submit jobs\n")

    import uvicorn

    from api.app import create_app

    app = create_app(dataclasses.replace(settings, database_ready=True))
    host_text = f"[{args.host}]" if ":" in args.host else args.host
    sys.stderr.write(f"{PROG}: listening on http://{host_text}:{actual_port} "
                     f"(data dir {settings.data_dir}, "
                     f"{'runner off' if not settings.run_jobs else (settings.scheduler or f'{workers} local workers')}"
                     f"{', token required' if settings.token else ''})\n")
    sys.stderr.flush()
    config = uvicorn.Config(app, log_level=args.log_level, lifespan="on", access_log=False,
                            timeout_graceful_shutdown=10)
    server = uvicorn.Server(config)
    try:
        server.run(sockets=[sock])
    finally:
        sock.close()
        if lock is not None:
            lock.close()
    return 0 if server.started else 1

