"""The job runner: a thread that owns the Dask client and moves jobs through their states.

The states and transitions are listed in ``api.status``; every SQL statement is a named function
of ``api.db``.  One loop (period ``Settings.poll_interval``, woken early by the API on submit and
cancel), one method per step:

1. ``_drop_cancelled`` -- cancelled jobs (the API marks the job and its pending points
   ``cancelled`` in one transaction): futures that no queued or running job needs are cancelled
   on the cluster;
2. ``_start_queued`` -- queued jobs (oldest first) become ``running``; each pending point is
   either taken from the ``points`` table (same key, result file still on disk: *reused*),
   attached to a future that is already computing that key for another job, or submitted as
   ``sweep.worker.compute_point`` with ``pure=False``, ``retries`` and a priority that favours
   older jobs;
3. ``_collect`` -- finished futures: the point's netCDF file, which came back through Dask as
   bytes, is written into the data directory by this thread (``sweep.storage.save_point``), then
   the point's record goes to ``points`` and to every running job waiting for that key, in one
   transaction;
4. ``_finish_jobs`` -- running jobs with no pending point: the point files are combined into the
   job's ``sweep.nc`` (only this thread touches netCDF in the server process) and the job becomes
   ``done`` (or ``failed`` if every point failed or combining failed).

Why results travel back through Dask instead of workers writing into the data directory: with
``--scheduler`` the workers may run in other containers, on other hosts, in batch jobs or in
Kubernetes pods.  This way they need no file system shared with the service (no shared volume,
no matching user ids, no path that must mean the same on both sides, no NFS caching delays), so
there is nothing to check at start-up and nothing to misconfigure; and this process is the only
writer of the data directory.  The cost is about 0.1 MB per coarse point through Dask.

The scheduler keeps no state across restarts; the database does.  On start-up, jobs left
``running`` by a previous server are queued again; their finished points are reused, not
recomputed (a point file written just before a crash, whose record did not reach the database,
is read back too), and temporary files left by a write that was killed are removed.

Stored results are trusted only as far as they can be read: a point file that cannot be read
in full (or that another model version wrote) counts as missing -- ``sweep.storage.open_point``
moves it aside to ``points/damaged/`` with a record -- and is computed again, whether the runner
finds it when a job starts or when the job is combined.  A failure of the infrastructure is
submitted again (``INFRASTRUCTURE_RETRIES``) and never reused by a later job; a failure of the
model is reused unless the job asks for ``retry_failed``.  Messages that reach clients (a job's
``error``, a point's ``message``, ``runner_error`` in /health) carry no path of this machine.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import threading
import time
import uuid
from pathlib import Path

from airpuff_core.provenance import model_version
from sweep.storage import INFRASTRUCTURE_RETRIES, one_line_message

from . import db
from .settings import Settings

log = logging.getLogger("airpuff.runner")

MAX_LOST_RESUBMITS = 3  # futures cancelled under us (scheduler restart) are resubmitted this often
# A point whose stored file proves unusable when its job is combined is computed again this often.
MAX_DAMAGED_RECOMPUTES = 2


class RunnerLocked(RuntimeError):
    pass


def acquire_runner_lock(data_dir: Path):
    """Hold ``DATA_DIR/runner.lock`` for the life of the process: one runner per data directory.
    Returns the open file (keep a reference); raises RunnerLocked if another process holds it."""
    data_dir.mkdir(parents=True, exist_ok=True)
    fh = open(data_dir / "runner.lock", "a+")
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.close()
        raise RunnerLocked(f"another airpuff server is running jobs on {data_dir} "
                           "(it holds runner.lock)") from None
    fh.seek(0)
    fh.truncate()
    fh.write(f"{os.getpid()}\n")
    fh.flush()
    return fh


class Runner:
    """Runs in its own thread; ``start()``, ``wake()``, ``stop()`` are safe from any thread."""

    def __init__(self, settings: Settings):
        self.settings = settings
        self.state = "starting"
        self.error: str | None = None
        self.n_workers: int | None = None
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self.client = None
        self.futures: dict[str, object] = {}  # point key -> Future
        self.trigger: dict[str, str] = {}  # point key -> id of the job that submitted it
        self.params: dict[str, object] = {}  # point key -> RunParams (for resubmission)
        self.lost: dict[str, int] = {}
        self.infrastructure_retries: dict[str, int] = {}  # point key -> automatic re-runs
        self.damaged: dict[str, int] = {}  # point key -> recomputes after an unusable file
        self._warmed: set[tuple] = set()
        self._last_info = 0.0
        self._n_cancelled = -1
        self._worker_warnings: set[str] = set()

    # -- control (any thread) ----------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._main, name="airpuff-runner", daemon=True)
        self._thread.start()

    def wake(self) -> None:
        self._wake.set()

    def stop(self, timeout: float = 60.0) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)

    # -- the thread ---------------------------------------------------------------------------
    def _main(self) -> None:
        self.con = db.connect(self.settings.db_path)
        try:
            self._recover()
            if not self._connect():
                return
            self.state = "ready"
            self.error = None
            log.info("runner ready: %s workers", self.n_workers)
            while not self._stop.is_set():
                try:
                    self._tick()
                    self.error = None  # recovered (or never failed)
                except Exception as err:  # noqa: BLE001 - keep serving; the error is reported
                    log.exception("runner loop error")
                    self.error = one_line_message(f"{type(err).__name__}: {err}")
                    self._stop.wait(2.0)
                self._wake.wait(self.settings.poll_interval)
                self._wake.clear()
            self.state = "stopped"
        except Exception as err:  # noqa: BLE001
            log.exception("runner failed")
            self.state = "failed"
            self.error = one_line_message(f"{type(err).__name__}: {err}")
        finally:
            self._close()

    def _close(self) -> None:
        client, self.client = self.client, None
        self.futures.clear()
        if client is not None:
            from sweep.cluster import close_client

            try:
                close_client(client)
            except Exception:  # noqa: BLE001
                log.exception("closing the Dask client")
        self.con.close()

    def _connect(self) -> bool:
        """Warm the Numba cache, then start or join the cluster; retry until stopped."""
        from sweep.cluster import make_client

        s = self.settings
        while not self._stop.is_set():
            try:
                self.state = "starting"
                self._warm(None)
                self.state = "connecting" if s.scheduler else "starting"
                self.client = make_client(workers=s.workers, scheduler=s.scheduler)
                self._update_info(force=True)
                return True
            except Exception as err:  # noqa: BLE001
                log.error("cannot start the Dask client: %s", err)
                self.state = "failed"
                self.error = one_line_message(f"cannot start the Dask client: {err}")
                self._stop.wait(5.0)
        return False

    def _warm(self, options: dict | None) -> None:
        """Compile the solver once per combination of kernel-selecting options (cheap after the
        first time: a short run that loads from the cache)."""
        from airpuff_core.params import CHOICES, RunParams
        from sweep.numba_cache import warm_numba_cache

        params = RunParams.from_dict(options or {})
        tag = tuple(getattr(params, c) for c in CHOICES if c != "resolution")
        if tag in self._warmed:
            return
        self._warmed.add(tag)
        t = warm_numba_cache(params)
        log.info("warmed the Numba cache for %s in %.1f s", tag, t)

    def _update_info(self, force: bool = False) -> None:
        now = time.monotonic()
        if self.client is None or (not force and now - self._last_info < 5.0):
            return
        self._last_info = now
        try:
            n = len(self.client.nthreads())
        except Exception:  # noqa: BLE001 - informational only
            return
        if n != self.n_workers and self.settings.scheduler:
            # Workers of an existing scheduler were started by someone else: say once what in
            # their set-up would oversubscribe the cores or make them compile the solver.
            from sweep.cluster import check_workers

            for warning in check_workers(self.client):
                if warning not in self._worker_warnings:
                    self._worker_warnings.add(warning)
                    log.warning(warning)
        self.n_workers = n

    # -- one pass -----------------------------------------------------------------------------
    def _tick(self) -> None:
        self._drop_cancelled()
        self._start_queued()
        self._collect()
        self._finish_jobs()
        self._update_info()

    def _recover(self) -> None:
        from airpuff_core.atomic import remove_stale_temp_files

        n = db.requeue_running_jobs(self.con)
        if n:
            log.info("requeued %d job(s) left running by a previous server", n)
        # This process holds runner.lock: no other writer, every temporary file is stale.
        folders = [self.settings.points_dir]
        if self.settings.jobs_dir.is_dir():
            folders += [d for d in self.settings.jobs_dir.iterdir() if d.is_dir()]
        removed = [p for folder in folders for p in remove_stale_temp_files(folder)]
        if removed:
            log.info("removed %d temporary file(s) of writes that were killed", len(removed))

    def _drop_cancelled(self) -> None:
        """The API marks a cancelled job and its pending points in one transaction; here the
        futures that no queued or running job needs any more are cancelled on the cluster."""
        n = db.count_jobs(self.con, "cancelled")
        if n == self._n_cancelled:
            return
        self._n_cancelled = n
        db.cancel_points_of_cancelled_jobs(self.con)
        needed = db.needed_point_keys(self.con)
        drop = [k for k in self.futures if k not in needed]
        if drop and self.client is not None:
            self.client.cancel([self.futures[k] for k in drop])
        for k in drop:
            self.futures.pop(k, None)
            self.trigger.pop(k, None)
            self.params.pop(k, None)
        if drop:
            log.info("cancelled %d point task(s) no job needs any more", len(drop))

    def _start_queued(self) -> None:
        """queued -> running (or failed, if this version cannot run the stored job)."""
        from sweep.grid import SweepSpec

        for job in db.queued_jobs(self.con):
            job_id = job["id"]
            if not db.claim_job(self.con, job_id):
                continue
            try:
                spec = SweepSpec.from_dict(json.loads(job["spec_json"]), validate=False)
                points = spec.validated_points()  # this version can run every point
                self._warm(spec.options)
                self._dispatch(job_id, job["seq"], points, bool(job["retry_failed"]))
            except Exception as err:  # noqa: BLE001 - a stored spec this version cannot run
                log.exception("starting job %s", job_id)
                self._end_job(job_id, "failed", f"cannot start the job: {err}")

    def _dispatch(self, job_id: str, seq: int, points: list, retry_failed: bool = False) -> None:
        """Each pending point of a job just started is reused (its result is stored), shared (a
        future computes its key already), read back (a file without a record) or submitted.
        Stored failures are reused only if the model failed and the job does not ask for
        ``retry_failed``; an unusable stored file is moved aside and its point submitted."""
        from sweep.storage import point_key, read_point, reusable

        pending = db.pending_job_points(self.con, job_id)
        reused, submit, on_disk = [], {}, {}
        for row in pending:
            params = points[row["idx"]]
            # The key was computed when the job was submitted; it is recomputed here only to
            # follow a change of the key's definition between versions (a stored job of an
            # older server).
            key = point_key(params)
            if key != row["key"]:
                db.set_job_point_key(self.con, job_id, row["idx"], key)
            if key in self.futures or key in submit or key in on_disk:
                continue  # already computing for another job (or listed twice)
            found = read_point(self.settings.points_dir, key)  # None if unusable (set aside)
            if not reusable(found, retry_failed):
                submit[key] = params
                continue
            row = db.point_row(self.con, key)
            if row is not None and row["status"] == found["status"]:  # its result is recorded
                reused.append((row["status"], row["message"], job_id, key))
            else:  # a file written just before a crash, whose record did not reach the database
                on_disk[key] = {**found, "computed": False}
        if reused:
            db.mark_reused(self.con, reused)
        if on_disk:
            db.upsert_pending_points(self.con, on_disk, submitted=False)
            self._record([(k, job_id, rec) for k, rec in on_disk.items()])
        self._submit(job_id, seq, submit)
        n_reused = len(reused) + len(on_disk)
        log.info("job %s: %d points, %d reused, %d submitted, %d shared with other jobs",
                 job_id, len(points), n_reused, len(submit), len(pending) - n_reused - len(submit))

    def _submit(self, job_id: str, seq: int, submit: dict) -> None:
        """Submit ``{key: RunParams}`` to the cluster for ``job_id``."""
        if not submit:
            return
        from sweep.worker import compute_point

        db.upsert_pending_points(self.con, submit, submitted=True)
        for key, params in submit.items():
            self.futures[key] = self.client.submit(
                compute_point, params, key, pure=False, retries=self.settings.retries,
                priority=-int(seq), key=f"airpuff-point-{key}-{uuid.uuid4().hex[:8]}")
            self.trigger[key] = job_id
            self.params[key] = params

    def _collect(self) -> None:
        """Finished futures: store each point's file and record its result."""
        from sweep.storage import failure_kind, save_point
        from sweep.worker import failure_from_exception

        done = [(k, f) for k, f in self.futures.items() if f.done()]
        if not done:
            return
        needed: set[str] | None = None  # keys a job still waits for: read once, when first asked

        def still_needed(key: str) -> bool:
            nonlocal needed
            if needed is None:
                needed = db.needed_point_keys(self.con)
            return key in needed

        records = []
        for key, fut in done:
            self.futures.pop(key)
            job_id = self.trigger.pop(key, None)
            params = self.params.pop(key, None)
            if fut.status == "finished":
                rec = self._save(save_point, key, fut)
            elif fut.status == "cancelled":  # lost with the scheduler, or cancelled by us
                if (still_needed(key)
                        and self.lost.get(key, 0) < MAX_LOST_RESUBMITS):
                    self.lost[key] = self.lost.get(key, 0) + 1
                    self._submit(job_id, db.job_seq(self.con, job_id), {key: params})
                    continue
                rec = failure_from_exception(self.settings.points_dir, params,
                                             RuntimeError("the task was lost repeatedly"), key)
            else:  # the task itself raised (e.g. KilledWorker: it crashed workers repeatedly)
                rec = failure_from_exception(self.settings.points_dir, params, fut.exception(),
                                             key)
            fut.release()
            if (rec["status"] == "failed" and failure_kind(rec) == "infrastructure"
                    and params is not None and still_needed(key)
                    and self.infrastructure_retries.get(key, 0) < INFRASTRUCTURE_RETRIES):
                self.infrastructure_retries[key] = self.infrastructure_retries.get(key, 0) + 1
                log.warning("point %s: %s; submitting it again (%d of %d)", key, rec["message"],
                            self.infrastructure_retries[key], INFRASTRUCTURE_RETRIES)
                self._submit(job_id, db.job_seq(self.con, job_id), {key: params})
                continue
            self.infrastructure_retries.pop(key, None)
            records.append((key, job_id, rec))
        if records:
            self._record(records)

    def _save(self, save_point, key: str, fut) -> dict:
        """Write the point file that came back through Dask into the data directory."""
        try:
            rec, data = fut.result()
            if rec.get("key") != key:  # the workers run another version of airpuff
                log.warning("point %s came back under key %s: do the workers run the same "
                            "airpuff version as this server?", key, rec.get("key"))
            if rec.get("status") == "ok" and rec.get("model_version") != model_version():
                raise RuntimeError(f"the worker runs model version {rec.get('model_version')}, "
                                   f"this server {model_version()}: install the same airpuff "
                                   "on the workers")
            return save_point(self.settings.points_dir, key, rec, data)
        except Exception as err:  # noqa: BLE001 - e.g. a full disk; a later job recomputes it
            from airpuff_core.result import METRICS

            log.exception("storing point %s", key)
            message = one_line_message(f"could not store the result: {type(err).__name__}: {err}")
            return {"status": "failed", "message": message, "kind": "infrastructure",
                    "metrics": {name: None for name in METRICS}, "wall_s": None,
                    "computed": True}

    def _record(self, records) -> None:
        db.record_point_results(self.con, records)

    def _finish_jobs(self) -> None:
        """running -> done | failed, once no point of the job is pending."""
        from sweep.combine import DamagedPointFiles, write_sweep
        from sweep.grid import SweepSpec

        for job in db.running_jobs_without_pending_points(self.con):
            job_id = job["id"]
            counts = db.job_point_counts(self.con, job_id)
            try:
                # validated when the job started, by this process (_start_queued)
                spec = SweepSpec.from_dict(json.loads(job["spec_json"]), validate=False)
                t0 = time.perf_counter()
                keys = db.job_point_keys(self.con, job_id)
                write_sweep(spec, self.settings.points_dir, self.settings.job_dataset(job_id),
                            keys)
                log.info("job %s combined in %.2f s", job_id, time.perf_counter() - t0)
            except DamagedPointFiles as err:
                self._recompute_damaged(job_id, spec, keys, err.keys)
                continue
            except Exception as err:  # noqa: BLE001
                log.exception("combining job %s", job_id)
                self._end_job(job_id, "failed", f"combining the points failed: "
                                                f"{type(err).__name__}: {err}")
                continue
            if counts.get("ok", 0) == 0:
                first = db.first_failure_message(self.con, job_id)
                self._end_job(job_id, "failed", f"all {job['n_points']} points failed; first: "
                                                f"{first or 'unknown'}")
            else:
                self._end_job(job_id, "done", None)

    def _recompute_damaged(self, job_id: str, spec, keys: list[str], damaged: list[str]) -> None:
        """Point files of a job found unusable when combining (moved aside): their points are
        pending again and submitted, at most ``MAX_DAMAGED_RECOMPUTES`` times each."""
        over = [k for k in damaged if self.damaged.get(k, 0) >= MAX_DAMAGED_RECOMPUTES]
        if over:
            self._end_job(job_id, "failed", f"the file of point {over[0]} was unusable after "
                                            f"{MAX_DAMAGED_RECOMPUTES} recomputations (see "
                                            "points/damaged/)")
            return
        for k in damaged:
            self.damaged[k] = self.damaged.get(k, 0) + 1
        params_by_key = dict(zip(keys, spec.points()))
        log.warning("job %s: %d point file(s) unusable, computing them again", job_id,
                    len(damaged))
        db.reopen_job_points(self.con, job_id, damaged)
        self._submit(job_id, db.job_seq(self.con, job_id),
                     {k: params_by_key[k] for k in damaged if k not in self.futures})

    def _end_job(self, job_id: str, status: str, error: str | None) -> None:
        error = None if error is None else one_line_message(error)
        db.end_job(self.con, job_id, status, error)
        log.info("job %s %s%s", job_id, status, f": {error}" if error else "")
