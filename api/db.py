"""SQLite store of jobs and points (WAL mode, busy timeout, explicit write transactions).

Tables
- ``jobs``: one row per submitted sweep (statuses and their transitions: ``api.status``).
- ``points``: one row per point key (a hash of all parameters of one run), shared by all jobs, so an
  identical point is computed once; its netCDF lives in ``DATA_DIR/points/``.  ``model_version``
  is the model version that computed it (the calibration that applies depends on it; NULL in
  rows stored before schema version 5).
- ``job_points``: the grid of a job: (job, index) -> point key, swept values and the point's status
  within that job.

Every write runs in ``BEGIN IMMEDIATE`` so that concurrent writers (the API's request threads and
the runner thread) wait for each other (busy timeout) instead of failing on a lock upgrade.
Every SQL statement of the service is a named function here; the API and the runner call them.
"""

from __future__ import annotations

import json
import sqlite3
import time
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Iterator

from .status import ENDED_JOB_STATUSES, JOB_STATUSES, POINT_RESULTS, POINT_STATUSES, sql_list

SCHEMA_VERSION = 5
BUSY_TIMEOUT_MS = 30_000

# Columns of ``points`` up to schema version 2 that nothing read (a point's parameters and wall
# time are in its file, its job's grid in ``job_points``): ``init`` drops them from an older
# database.
DROPPED_POINT_COLUMNS = ("params_json", "wall_s", "computed_by", "finished_at")

POINTS_TABLE = f"""
CREATE TABLE IF NOT EXISTS points (
    key          TEXT PRIMARY KEY,
    status       TEXT NOT NULL CHECK (status IN ({sql_list(("pending",) + POINT_RESULTS)})),
    message      TEXT,
    metrics_json TEXT,
    submissions  INTEGER NOT NULL DEFAULT 0,
    model_version TEXT
)"""

SCHEMA = f"""
CREATE TABLE IF NOT EXISTS jobs (
    seq          INTEGER PRIMARY KEY AUTOINCREMENT,
    id           TEXT NOT NULL UNIQUE,
    status       TEXT NOT NULL
                 CHECK (status IN ({sql_list(JOB_STATUSES)})),
    spec_json    TEXT NOT NULL,
    n_points     INTEGER NOT NULL,
    created_at   REAL NOT NULL,
    started_at   REAL,
    finished_at  REAL,
    error        TEXT,
    retry_failed INTEGER NOT NULL DEFAULT 0,
    owner        TEXT
);
{POINTS_TABLE};
CREATE TABLE IF NOT EXISTS job_points (
    job_id     TEXT NOT NULL REFERENCES jobs(id),
    idx        INTEGER NOT NULL,
    key        TEXT NOT NULL,
    E0         REAL NOT NULL,
    IOP        REAL NOT NULL,
    thickness  REAL NOT NULL,
    pmax       REAL NOT NULL,
    status     TEXT NOT NULL DEFAULT 'pending'
               CHECK (status IN ({sql_list(POINT_STATUSES)})),
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
        # SQLite may have rolled back already (it does on a full disk, SQLITE_FULL): a second
        # ROLLBACK would raise and hide the cause
        if con.in_transaction:
            con.execute("ROLLBACK")
        raise
    try:
        con.execute("COMMIT")
    except BaseException:  # e.g. a full disk: never keep the write lock of a failed commit
        if con.in_transaction:
            con.execute("ROLLBACK")
        raise


SQLITE_HEADER = b"SQLite format 3\x00"  # the first 16 bytes of every SQLite database file


class DatabaseUnusable(RuntimeError):
    """The job database cannot be used as it is (damaged, not a database, or of a newer schema
    than this version knows); the message is one line naming the file and what to do."""


def _refuse_damaged(path: Path, what: str) -> DatabaseUnusable:
    return DatabaseUnusable(
        f"the job database {path} is damaged ({what}): move it aside (or restore it from a "
        "backup) and start again; a new database is then created, the computed points in "
        "points/ are kept and reused, the records of the jobs are lost")


def check(con: sqlite3.Connection, path: Path) -> None:
    """Refuse a database this version must not touch: one of a newer schema (never downgraded)
    or one that SQLite's ``PRAGMA quick_check`` finds damaged (checked at every start-up: a
    page overwritten mid-file would otherwise make every later query fail)."""
    version = con.execute("PRAGMA user_version").fetchone()[0]
    if version > SCHEMA_VERSION:
        raise DatabaseUnusable(
            f"the job database {path} has schema version {version}, newer than the version "
            f"{SCHEMA_VERSION} this airpuff knows: run the airpuff that wrote it, or use another "
            "--data-dir (it is left as it is)")
    problems = [row[0] for row in con.execute("PRAGMA quick_check(3)")]
    if problems != ["ok"]:
        raise _refuse_damaged(path, "; ".join(" ".join(p.split()) for p in problems)[:300])


def init(path: str | Path) -> None:
    """Create the database (and its folder) if needed, or bring one of an older schema version to
    this one, keeping its jobs and points.  Raises ``DatabaseUnusable`` for a file that is not an
    SQLite database, is damaged (``check``) or has a newer schema."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.is_file() and path.stat().st_size > 0:
        with open(path, "rb") as fh:
            if fh.read(len(SQLITE_HEADER)) != SQLITE_HEADER:
                raise _refuse_damaged(path, "it is not an SQLite database file")
    try:
        con = connect(path)
    except sqlite3.OperationalError:
        raise
    except sqlite3.DatabaseError as err:
        raise _refuse_damaged(path, str(err)) from None
    try:
        check(con, path)
        with write(con):
            for stmt in SCHEMA.split(";"):
                if stmt.strip():
                    con.execute(stmt)
            if "retry_failed" not in _columns(con, "jobs"):  # a database of schema version 1
                con.execute("ALTER TABLE jobs ADD COLUMN retry_failed INTEGER NOT NULL DEFAULT 0")
            if "owner" not in _columns(con, "jobs"):  # schema version 3 or older
                con.execute("ALTER TABLE jobs ADD COLUMN owner TEXT")
            if set(DROPPED_POINT_COLUMNS) & _columns(con, "points"):  # schema version 1 or 2
                _rebuild_points_table(con)
            if "model_version" not in _columns(con, "points"):  # schema version 4 or older
                con.execute("ALTER TABLE points ADD COLUMN model_version TEXT")
            con.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
    except sqlite3.OperationalError:  # busy, locked, a full disk: not the file's fault
        raise
    except sqlite3.DatabaseError as err:  # "file is not a database", "disk image is malformed"
        raise _refuse_damaged(path, str(err)) from None
    finally:
        con.close()


def _columns(con: sqlite3.Connection, table: str) -> set[str]:
    return {r["name"] for r in con.execute(f"PRAGMA table_info({table})")}


def _rebuild_points_table(con: sqlite3.Connection) -> None:
    """``points`` without ``DROPPED_POINT_COLUMNS``, its rows kept: a new table, the rows copied,
    the old table dropped and the new one renamed (SQLite's way to change a table in ways ALTER
    TABLE cannot, https://www.sqlite.org/lang_altertable.html; no other table refers to
    ``points``).  Inside the caller's write transaction."""
    kept = "key, status, message, metrics_json, submissions"
    con.execute(POINTS_TABLE.replace("CREATE TABLE IF NOT EXISTS points",
                                     "CREATE TABLE points_new"))
    con.execute(f"INSERT INTO points_new ({kept}) SELECT {kept} FROM points")
    con.execute("DROP TABLE points")
    con.execute("ALTER TABLE points_new RENAME TO points")


def now() -> float:
    return time.time()


def iso(t: float | None) -> str | None:
    if t is None:
        return None
    return datetime.fromtimestamp(t, tz=timezone.utc).isoformat(timespec="milliseconds")


# -- jobs ------------------------------------------------------------------------------------

class PendingLimit(Exception):
    """A new job would take the points waiting above a limit: ``scope`` is ``"server"`` (all
    clients) or ``"client"`` (its owner); ``pending`` the points waiting now, ``limit`` the
    limit, ``asked`` the job's points."""

    def __init__(self, scope: str, pending: int, asked: int, limit: int):
        self.scope, self.pending, self.asked, self.limit = scope, pending, asked, limit
        super().__init__(f"{pending} + {asked} points above the {scope} limit of {limit}")


PENDING_POINTS = ("SELECT COUNT(*) FROM job_points jp JOIN jobs j ON j.id = jp.job_id "
                  "WHERE jp.status = 'pending' AND j.status IN ('queued', 'running')")


def pending_points(con, owner: str | None = None) -> int:
    """Points waiting in queued or running jobs (of ``owner`` only, if given)."""
    if owner is None:
        return con.execute(PENDING_POINTS).fetchone()[0]
    return con.execute(PENDING_POINTS + " AND j.owner = ?", (owner,)).fetchone()[0]


def insert_job(con, job_id: str, spec: dict, points: Iterable[tuple[str, float, float, float,
                                                                   float]],
               retry_failed: bool = False, owner: str | None = None,
               max_pending: int | None = None, max_pending_owner: int | None = None) -> None:
    """Store a new queued job and its grid: points are (key, E0, IOP, thickness, pmax) in
    index order.  ``retry_failed``: compute again points stored as failed by the model;
    ``owner``: who asked (the client's address).  Raises ``PendingLimit`` if the points waiting
    would exceed ``max_pending`` (all jobs) or ``max_pending_owner`` (the owner's jobs); the
    counts and the insert are one transaction, so concurrent requests cannot both slip in."""
    rows = [(job_id, i, *p) for i, p in enumerate(points)]
    with write(con):
        if max_pending is not None:
            waiting = pending_points(con)
            if waiting + len(rows) > max_pending:
                raise PendingLimit("server", waiting, len(rows), max_pending)
        if max_pending_owner is not None:
            waiting = pending_points(con, owner)
            if waiting + len(rows) > max_pending_owner:
                raise PendingLimit("client", waiting, len(rows), max_pending_owner)
        con.execute("INSERT INTO jobs (id, status, spec_json, n_points, created_at, retry_failed, "
                    "owner) VALUES (?, 'queued', ?, ?, ?, ?, ?)",
                    (job_id, json.dumps(spec, sort_keys=True), len(rows), now(),
                     int(bool(retry_failed)), owner))
        con.executemany("INSERT INTO job_points (job_id, idx, key, E0, IOP, thickness, pmax) "
                        "VALUES (?, ?, ?, ?, ?, ?, ?)", rows)


JOB_COLUMNS = """
    j.seq, j.id, j.status, j.spec_json, j.n_points, j.created_at, j.started_at, j.finished_at,
    j.error, j.retry_failed,
    (SELECT COUNT(*) FROM job_points p WHERE p.job_id = j.id AND p.status = 'ok') AS n_ok,
    (SELECT COUNT(*) FROM job_points p WHERE p.job_id = j.id AND p.status = 'failed') AS n_failed,
    (SELECT COUNT(*) FROM job_points p WHERE p.job_id = j.id AND p.reused = 1
                                           AND p.status IN ('ok', 'failed')) AS n_reused
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


def delete_job(con, job_id: str) -> bool:
    """Remove an ended job and its grid; False if it does not exist or has not ended."""
    with write(con):
        ended = con.execute(f"SELECT 1 FROM jobs WHERE id = ? AND status IN "
                            f"({sql_list(ENDED_JOB_STATUSES)})", (job_id,)).fetchone()
        if ended is None:
            return False
        con.execute("DELETE FROM job_points WHERE job_id = ?", (job_id,))
        con.execute("DELETE FROM jobs WHERE id = ?", (job_id,))
        return True


def job_points(con, job_id: str) -> list[sqlite3.Row]:
    return con.execute(
        "SELECT jp.idx, jp.key, jp.E0, jp.IOP, jp.thickness, jp.pmax, jp.status, jp.message, "
        "jp.reused, pt.metrics_json, pt.model_version FROM job_points jp "
        "LEFT JOIN points pt ON pt.key = jp.key "
        "WHERE jp.job_id = ? ORDER BY jp.idx", (job_id,)).fetchall()


def point_row(con, key: str) -> sqlite3.Row | None:
    return con.execute("SELECT * FROM points WHERE key = ?", (key,)).fetchone()


# -- the runner's statements -----------------------------------------------------------------

def requeue_running_jobs(con) -> int:
    """Jobs left running by a previous server go back to the queue; returns how many."""
    with write(con):
        return con.execute("UPDATE jobs SET status = 'queued' WHERE status = 'running'").rowcount


def queued_jobs(con) -> list[sqlite3.Row]:
    """(id, seq, spec_json, retry_failed) of the queued jobs, oldest first."""
    return con.execute("SELECT id, seq, spec_json, retry_failed FROM jobs WHERE status = 'queued' "
                       "ORDER BY seq").fetchall()


def claim_job(con, job_id: str) -> bool:
    """queued -> running (started_at kept from an earlier run); False if no longer queued."""
    with write(con):
        return con.execute("UPDATE jobs SET status = 'running', "
                           "started_at = COALESCE(started_at, ?) WHERE id = ? AND status = 'queued'",
                           (now(), job_id)).rowcount == 1


def end_job(con, job_id: str, status: str, error: str | None) -> None:
    """running -> ``status`` (done or failed) with its error message."""
    with write(con):
        con.execute("UPDATE jobs SET status = ?, error = ?, finished_at = ? "
                    "WHERE id = ? AND status = 'running'", (status, error, now(), job_id))


def pending_job_points(con, job_id: str, limit: int = -1) -> list[sqlite3.Row]:
    """(idx, key) of the pending points of a job, in grid order (the first ``limit`` of them;
    all if negative)."""
    return con.execute("SELECT idx, key FROM job_points WHERE job_id = ? AND status = 'pending' "
                       "ORDER BY idx LIMIT ?", (job_id, limit)).fetchall()


def running_jobs(con) -> list[sqlite3.Row]:
    """(id, spec_json, retry_failed) of the running jobs, oldest first."""
    return con.execute("SELECT id, spec_json, retry_failed FROM jobs WHERE status = 'running' "
                       "ORDER BY seq").fetchall()


def set_job_point_key(con, job_id: str, idx: int, key: str) -> None:
    """Follow the current key of a point stored with the key of an older version."""
    with write(con):
        con.execute("UPDATE job_points SET key = ? WHERE job_id = ? AND idx = ?",
                    (key, job_id, idx))


def mark_reused(con, rows: Iterable[tuple[str, str | None, str, str]]) -> None:
    """Pending points of a job whose result is already stored: rows of (status, message, job id,
    key)."""
    with write(con):
        con.executemany("UPDATE job_points SET status = ?, message = ?, reused = 1 "
                        "WHERE job_id = ? AND key = ? AND status = 'pending'", list(rows))


def reopen_job_points(con, job_id: str, keys: Iterable[str]) -> None:
    """Points of a running job whose stored file turned out unusable: pending again (and their
    ``points`` rows), to be computed anew."""
    keys = list(keys)
    with write(con):
        con.executemany("UPDATE job_points SET status = 'pending', message = NULL, reused = 0 "
                        "WHERE job_id = ? AND key = ?", [(job_id, k) for k in keys])
        con.executemany("UPDATE points SET status = 'pending' WHERE key = ?", [(k,) for k in keys])


def point_needed(con, key: str) -> bool:
    """Whether a queued or running job still waits for the point ``key``."""
    return con.execute(
        "SELECT 1 FROM job_points jp JOIN jobs j ON j.id = jp.job_id WHERE jp.key = ? AND "
        "jp.status = 'pending' AND j.status IN ('queued', 'running') LIMIT 1",
        (key,)).fetchone() is not None


def cancel_points_of_cancelled_jobs(con) -> None:
    """Pending points of cancelled jobs become cancelled (jobs cancelled by an older version of
    the API left them pending)."""
    with write(con):
        con.execute("UPDATE job_points SET status = 'cancelled', message = 'job cancelled' "
                    "WHERE status = 'pending' AND job_id IN "
                    "(SELECT id FROM jobs WHERE status = 'cancelled')")


def upsert_pending_points(con, keys: Iterable[str], submitted: bool) -> None:
    """A ``points`` row, status pending, for each key; ``submitted`` counts one submission to
    the cluster."""
    with write(con):
        con.executemany(
            "INSERT INTO points (key, status, submissions) VALUES (?, 'pending', ?) "
            "ON CONFLICT (key) DO UPDATE SET status = 'pending', submissions = submissions + ?",
            [(k, int(submitted), int(submitted)) for k in keys])


def record_point_results(con, results: Iterable[tuple[str, str | None, Any]]) -> None:
    """The results of points, in one transaction: ``(key, id of the job that submitted it,
    record)`` with ``record`` a ``sweep.record.PointRecord``.  The ``points`` row gets the
    record; every running job waiting for the key gets the status and message (``reused``
    unless it is the submitting job and the point was computed)."""
    with write(con):
        for key, job_id, rec in results:
            computed = bool(rec.computed)
            con.execute(
                "UPDATE points SET status = ?, message = ?, metrics_json = ?, model_version = ? "
                "WHERE key = ?",
                (rec.status, rec.message or None, json.dumps(rec.metrics or {}),
                 rec.model_version, key))
            con.execute(
                "UPDATE job_points SET status = ?, message = ?, "
                "reused = CASE WHEN job_id = ? AND ? THEN 0 ELSE 1 END "
                "WHERE key = ? AND status = 'pending' AND job_id IN "
                "(SELECT id FROM jobs WHERE status = 'running')",
                (rec.status, rec.message or None, job_id, computed, key))


def running_jobs_without_pending_points(con) -> list[sqlite3.Row]:
    """(id, spec_json, n_points) of running jobs whose every point has its result."""
    return con.execute(
        "SELECT id, spec_json, n_points FROM jobs j WHERE status = 'running' AND NOT EXISTS "
        "(SELECT 1 FROM job_points p WHERE p.job_id = j.id AND p.status = 'pending') "
        "ORDER BY seq").fetchall()


def job_point_keys(con, job_id: str) -> list[str]:
    """The point keys of a job in grid (C) order."""
    return [r[0] for r in con.execute("SELECT key FROM job_points WHERE job_id = ? ORDER BY idx",
                                      (job_id,))]


def job_point_counts(con, job_id: str) -> dict[str, int]:
    """Point status -> number of points of a job."""
    return dict(con.execute("SELECT status, COUNT(*) FROM job_points WHERE job_id = ? "
                            "GROUP BY status", (job_id,)).fetchall())


def first_failure_message(con, job_id: str) -> str | None:
    """The message of a job's first failed point (grid order)."""
    row = con.execute("SELECT message FROM job_points WHERE job_id = ? AND status = 'failed' "
                      "ORDER BY idx LIMIT 1", (job_id,)).fetchone()
    return row[0] if row else None


def loads(text: str | None) -> Any:
    return None if text is None else json.loads(text)
