"""SQLite store of jobs and points (WAL mode, busy timeout, explicit write transactions).

Tables
- ``jobs``: one row per submitted sweep (status queued -> running -> done | failed | cancelled).
- ``points``: one row per point key (a hash of all parameters of one run), shared by all jobs, so an
  identical point is computed once; its netCDF lives in ``DATA_DIR/points/``.
- ``job_points``: the grid of a job: (job, index) -> point key, swept values and the point's status
  within that job.

Every write runs in ``BEGIN IMMEDIATE`` so that concurrent writers (the API's request threads and
the runner thread) wait for each other (busy timeout) instead of failing on a lock upgrade.
"""

from __future__ import annotations

import json
import sqlite3
import time
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Iterator

SCHEMA_VERSION = 1
BUSY_TIMEOUT_MS = 30_000

SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    seq          INTEGER PRIMARY KEY AUTOINCREMENT,
    id           TEXT NOT NULL UNIQUE,
    status       TEXT NOT NULL
                 CHECK (status IN ('queued', 'running', 'done', 'failed', 'cancelled')),
    spec_json    TEXT NOT NULL,
    n_points     INTEGER NOT NULL,
    created_at   REAL NOT NULL,
    started_at   REAL,
    finished_at  REAL,
    error        TEXT
);
CREATE TABLE IF NOT EXISTS points (
    key          TEXT PRIMARY KEY,
    params_json  TEXT NOT NULL,
    status       TEXT NOT NULL CHECK (status IN ('pending', 'ok', 'failed')),
    message      TEXT,
    metrics_json TEXT,
    wall_s       REAL,
    computed_by  TEXT,
    submissions  INTEGER NOT NULL DEFAULT 0,
    finished_at  REAL
);
CREATE TABLE IF NOT EXISTS job_points (
    job_id     TEXT NOT NULL REFERENCES jobs(id),
    idx        INTEGER NOT NULL,
    key        TEXT NOT NULL,
    E0         REAL NOT NULL,
    IOP        REAL NOT NULL,
    thickness  REAL NOT NULL,
    pmax       REAL NOT NULL,
    status     TEXT NOT NULL DEFAULT 'pending'
               CHECK (status IN ('pending', 'ok', 'failed', 'cancelled')),
    message    TEXT,
    reused     INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY (job_id, idx)
);
CREATE INDEX IF NOT EXISTS job_points_key ON job_points (key, status);
CREATE INDEX IF NOT EXISTS job_points_status ON job_points (job_id, status);
CREATE INDEX IF NOT EXISTS jobs_status ON jobs (status, seq);
"""


def connect(path: str | Path) -> sqlite3.Connection:
    """A connection in autocommit mode (transactions are explicit), WAL, busy timeout."""
    con = sqlite3.connect(str(path), timeout=BUSY_TIMEOUT_MS / 1000, isolation_level=None,
                          check_same_thread=False)
    con.row_factory = sqlite3.Row
    con.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
    con.execute("PRAGMA journal_mode=WAL")
    con.execute("PRAGMA synchronous=NORMAL")
    con.execute("PRAGMA foreign_keys=ON")
    return con


@contextmanager
def write(con: sqlite3.Connection) -> Iterator[sqlite3.Connection]:
    """A write transaction taking the write lock at once (waits up to the busy timeout)."""
    con.execute("BEGIN IMMEDIATE")
    try:
        yield con
    except BaseException:
        con.execute("ROLLBACK")
        raise
    else:
        con.execute("COMMIT")


def init(path: str | Path) -> None:
    """Create the database (and its folder) if needed."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    con = connect(path)
    try:
        with write(con):
            for stmt in SCHEMA.split(";"):
                if stmt.strip():
                    con.execute(stmt)
            con.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
    finally:
        con.close()


def now() -> float:
    return time.time()


def iso(t: float | None) -> str | None:
    if t is None:
        return None
    return datetime.fromtimestamp(t, tz=timezone.utc).isoformat(timespec="milliseconds")


# -- jobs ------------------------------------------------------------------------------------

def insert_job(con, job_id: str, spec: dict, points: Iterable[tuple[str, float, float, float,
                                                                   float]]) -> None:
    """Store a new queued job and its grid: points are (key, E0, IOP, thickness, pmax) in
    index order."""
    rows = [(job_id, i, *p) for i, p in enumerate(points)]
    with write(con):
        con.execute("INSERT INTO jobs (id, status, spec_json, n_points, created_at) "
                    "VALUES (?, 'queued', ?, ?, ?)",
                    (job_id, json.dumps(spec, sort_keys=True), len(rows), now()))
        con.executemany("INSERT INTO job_points (job_id, idx, key, E0, IOP, thickness, pmax) "
                        "VALUES (?, ?, ?, ?, ?, ?, ?)", rows)


JOB_COLUMNS = """
    j.seq, j.id, j.status, j.spec_json, j.n_points, j.created_at, j.started_at, j.finished_at,
    j.error,
    (SELECT COUNT(*) FROM job_points p WHERE p.job_id = j.id AND p.status = 'ok') AS n_ok,
    (SELECT COUNT(*) FROM job_points p WHERE p.job_id = j.id AND p.status = 'failed') AS n_failed,
    (SELECT COUNT(*) FROM job_points p WHERE p.job_id = j.id AND p.status = 'ok'
                                           AND p.reused = 1) AS n_reused
"""


def get_job(con, job_id: str) -> sqlite3.Row | None:
    return con.execute(f"SELECT {JOB_COLUMNS} FROM jobs j WHERE j.id = ?", (job_id,)).fetchone()


def list_jobs(con, limit: int, offset: int, status: str | None = None) -> list[sqlite3.Row]:
    where, args = ("WHERE j.status = ?", [status]) if status else ("", [])
    return con.execute(f"SELECT {JOB_COLUMNS} FROM jobs j {where} ORDER BY j.seq DESC "
                       "LIMIT ? OFFSET ?", (*args, limit, offset)).fetchall()


def count_jobs(con, status: str | None = None) -> int:
    if status:
        return con.execute("SELECT COUNT(*) FROM jobs WHERE status = ?", (status,)).fetchone()[0]
    return con.execute("SELECT COUNT(*) FROM jobs").fetchone()[0]


def cancel_job(con, job_id: str) -> bool:
    """Mark a queued or running job cancelled; False if it had already ended."""
    with write(con):
        cur = con.execute("UPDATE jobs SET status = 'cancelled', finished_at = ?, "
                          "error = 'cancelled on request' "
                          "WHERE id = ? AND status IN ('queued', 'running')", (now(), job_id))
        if cur.rowcount != 1:
            return False
        con.execute("UPDATE job_points SET status = 'cancelled', message = 'job cancelled' "
                    "WHERE job_id = ? AND status = 'pending'", (job_id,))
        return True


def job_points(con, job_id: str) -> list[sqlite3.Row]:
    return con.execute(
        "SELECT jp.idx, jp.key, jp.E0, jp.IOP, jp.thickness, jp.pmax, jp.status, jp.message, "
        "jp.reused, pt.metrics_json FROM job_points jp LEFT JOIN points pt ON pt.key = jp.key "
        "WHERE jp.job_id = ? ORDER BY jp.idx", (job_id,)).fetchall()


def point_row(con, key: str) -> sqlite3.Row | None:
    return con.execute("SELECT * FROM points WHERE key = ?", (key,)).fetchone()


def loads(text: str | None) -> Any:
    return None if text is None else json.loads(text)
