"""The job runner: a thread that owns the Dask client and moves jobs through their states.

The states and transitions are listed in ``api.status``; every SQL statement is a named function
of ``api.db``; how points are computed (submission a window at a time, storage of the results,
retries, recomputes) is the sweep engine's (``sweep.engine.PointEngine``), shared with
`airpuff sweep`.  One loop (period ``Settings.poll_interval``, woken early by the API on submit
and cancel), one method per step:

1. ``_drop_cancelled`` -- cancelled jobs (the API marks the job and its pending points
   ``cancelled`` in one transaction): tasks that no queued or running job needs are cancelled;
2. ``_start_queued`` -- queued jobs become ``running``; each pending point whose result is stored
   (``sweep.engine.stored_record``) is taken from the ``points`` table, or read back from its
   file if the record did not reach the database;
3. ``_feed`` -- the engine takes the pending points of the running jobs, one job at a time in
   turn, into its window of tasks on the cluster (a point already in flight for another job is
   shared);
4. ``_collect`` -- finished tasks, whose files the engine has stored: the point's record goes to
   ``points`` and to every running job waiting for that key, in one transaction;
5. ``_finish_jobs`` -- running jobs with no pending point: the point files are combined into the
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

A point file found unusable when a job is combined (moved aside by ``sweep.storage.open_point``)
makes its point pending again, to be computed anew.  Messages that reach clients (a job's
``error``, a point's ``message``, ``runner_error`` in /health) carry no path of this machine.
"""

from __future__ import annotations

import json
import logging
import threading
import time
import uuid
from pathlib import Path

from sweep.engine import MAX_DAMAGED_RECOMPUTES, PointEngine, stored_record
from sweep.storage import INFRASTRUCTURE_RETRIES, NO_SPACE, disk_full, one_line_message

from . import db
from .settings import Settings

log = logging.getLogger("airpuff.runner")

# s between two tries to write a job's dataset on a full disk
COMBINE_RETRY_S = 5.0
# s a local cluster may be without any worker before it is replaced
LOST_CLUSTER_S = 10.0

__all__ = ["Runner", "RunnerLocked", "acquire_runner_lock", "INFRASTRUCTURE_RETRIES"]


class RunnerLocked(RuntimeError):
    pass


def acquire_runner_lock(data_dir: Path):
    """Hold ``DATA_DIR/runner.lock`` for the life of the process: one runner per data directory.
    Returns the open file (keep a reference); raises RunnerLocked if another process holds it."""
    from sweep.folder_lock import FolderLocked, hold_folder_lock

    try:
        return hold_folder_lock(data_dir, "runner.lock")
    except FolderLocked:
        raise RunnerLocked(f"another airpuff server is running jobs on {data_dir} "
                           "(it holds runner.lock)") from None


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
        self.engine: PointEngine | None = None
        self.specs: dict[str, object] = {}  # id of a running job -> its SweepSpec
        # results collected but not yet in the database (it could not be written): kept and
        # written again on each pass, their points not submitted again meanwhile
        self.unrecorded: list[tuple] = []
        self.disk_error: str | None = None  # why results or datasets wait for room
        self._combine_after: dict[str, float] = {}  # job id -> next try of a combine [monotonic]
        self._no_workers_since: float | None = None  # when a local cluster lost its last worker
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
                    # recovered (or never failed), unless results wait for room on the disk
                    self.error = self.engine.storage_error or self.disk_error
                except Exception as err:  # noqa: BLE001 - keep serving; the error is reported
                    log.exception("runner loop error")
                    cause = f"{NO_SPACE}: " if disk_full(err) else ""
                    self.error = one_line_message(f"{cause}{type(err).__name__}: {err}")
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
        self.engine = None
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
                self.engine = PointEngine(
                    self.client, s.points_dir, retries=s.retries, time_limit_s=s.task_time_limit,
                    on_submit=lambda keys: db.upsert_pending_points(self.con, keys,
                                                                    submitted=True))
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
        if n == 0 and not self.settings.scheduler:
            self._renew_local_cluster(now)
        else:
            self._no_workers_since = None

    def _renew_local_cluster(self, now: float) -> None:
        """A local cluster left without any worker for ``LOST_CLUSTER_S`` (a nanny that closed
        after its worker was ended, seen with distributed 2026.8) is replaced by a new one; the
        points in flight are submitted again from the database by ``_feed``."""
        from sweep.cluster import close_client, make_client

        if self._no_workers_since is None:
            self._no_workers_since = now
        if now - self._no_workers_since < LOST_CLUSTER_S:
            return
        log.warning("the local cluster has had no worker for %.0f s: starting a new one",
                    now - self._no_workers_since)
        old, self.client = self.client, None
        try:
            close_client(old)
        except Exception:  # noqa: BLE001 - it is being replaced
            log.exception("closing the old Dask client")
        self.client = make_client(workers=self.settings.workers)
        self.engine.client = self.client
        self.engine.tasks.clear()
        self._no_workers_since = None

    # -- one pass -----------------------------------------------------------------------------
    def _tick(self) -> None:
        self._drop_cancelled()
        self._start_queued()
        self._feed()
        self._collect()
        self._finish_jobs()
        self._update_info()

    def _recover(self) -> None:
        from airpuff_core.atomic import remove_stale_temp_files

        n = db.requeue_running_jobs(self.con)
        if n:
            log.info("requeued %d job(s) left running by a previous server", n)
        # This process holds runner.lock: no other writer, every temporary file is stale.
        removed = [p for folder in self.settings.temporary_file_folders()
                   for p in remove_stale_temp_files(folder)]
        if removed:
            log.info("removed %d temporary file(s) of writes that were killed", len(removed))

    def _drop_cancelled(self) -> None:
        """The API marks a cancelled job and its pending points in one transaction; here the
        tasks that no queued or running job needs any more are cancelled on the cluster."""
        n = db.count_jobs(self.con, "cancelled")
        if n == self._n_cancelled:
            return
        self._n_cancelled = n
        db.cancel_points_of_cancelled_jobs(self.con)
        dropped = self.engine.cancel([k for k in self.engine.tasks
                                      if not db.point_needed(self.con, k)])
        if dropped:
            log.info("cancelled %d point task(s) no job needs any more", len(dropped))

    def _start_queued(self) -> None:
        """queued -> running (or failed, if this version cannot run the stored job)."""
        from sweep.grid import SweepSpec

        for job in db.queued_jobs(self.con):
            job_id = job["id"]
            if not db.claim_job(self.con, job_id):
                continue
            try:
                spec = SweepSpec.from_dict(json.loads(job["spec_json"]), validate=False)
                spec.validate()  # this version can run every point
                self._warm(spec.options)
                self.specs[job_id] = spec
                self._reuse_stored(job_id, spec, bool(job["retry_failed"]))
            except Exception as err:  # noqa: BLE001 - a stored spec this version cannot run
                log.exception("starting job %s", job_id)
                self._end_job(job_id, "failed", f"cannot start the job: {err}")

    def _reuse_stored(self, job_id: str, spec, retry_failed: bool = False) -> None:
        """Each pending point of a job just started whose result is stored is reused: taken
        from the ``points`` table, or read back from its file (written just before a crash,
        its record never reached the database).  The others wait for ``_feed``."""
        from sweep.storage import point_key

        pending = db.pending_job_points(self.con, job_id)
        # The keys were computed when the job was submitted; they are recomputed here only to
        # follow a change of the key's definition between versions (a stored job of an older
        # server), which changes every key: the first one tells.
        if pending and point_key(spec.point(pending[0]["idx"])) != pending[0]["key"]:
            for row in pending:
                db.set_job_point_key(self.con, job_id, row["idx"],
                                     point_key(spec.point(row["idx"])))
            pending = db.pending_job_points(self.con, job_id)
        reused, on_disk = [], {}
        for row in pending:
            key = row["key"]
            if self.engine.holds(key) or key in on_disk:
                continue  # already computing for another job (or listed twice)
            found = stored_record(self.settings.points_dir, key, retry_failed)
            if found is None:
                continue
            stored = db.point_row(self.con, key)
            if stored is not None and stored["status"] == found.status:  # its result is recorded
                reused.append((found.status, stored["message"], job_id, key))
            else:
                on_disk[key] = found
        if reused:
            db.mark_reused(self.con, reused)
        if on_disk:
            db.upsert_pending_points(self.con, on_disk, submitted=False)
            self._record([(k, job_id, rec) for k, rec in on_disk.items()])
        log.info("job %s: %d points, %d reused", job_id, spec.n_points,
                 len(reused) + len(on_disk))

    def _feed(self) -> None:
        """Hand the engine the pending points of the running jobs (it takes them in turn)."""
        jobs = db.running_jobs(self.con)
        for job_id in list(self.specs):
            if job_id not in {job["id"] for job in jobs}:
                del self.specs[job_id]
        sources = {job["id"]: self._source(job["id"]) for job in jobs if job["id"] in self.specs}
        self.engine.feed(sources)

    def _source(self, job_id: str):
        spec = self.specs[job_id]

        def next_points(n: int) -> list[tuple[str, object]]:
            rows = db.pending_job_points(self.con, job_id, n)
            waiting = {key for key, _, _ in self.unrecorded}
            return [(row["key"], spec.point(row["idx"])) for row in rows
                    if not self.engine.holds(row["key"]) and row["key"] not in waiting]
        return next_points

    def _collect(self) -> None:
        """Finished tasks (their results stored by the engine): record them."""
        records = self.engine.collect(wanted=lambda key: db.point_needed(self.con, key))
        if records or self.unrecorded:
            self._record(records)

    def _record(self, records) -> None:
        """Write point results to the database, with those an earlier write could not take;
        if this one fails too (a full disk), all are kept for the next pass."""
        self.unrecorded.extend(records)
        try:
            db.record_point_results(self.con, self.unrecorded)
        except Exception as err:
            if disk_full(err):
                self.disk_error = (f"{NO_SPACE}: the job database cannot take "
                                   f"{len(self.unrecorded)} point result(s); they are kept and "
                                   "written once there is room")
                log.error(self.disk_error)
                return
            raise
        self.unrecorded.clear()
        self.disk_error = None

    def _finish_jobs(self) -> None:
        """running -> done | failed, once no point of the job is pending."""
        from sweep.combine import DamagedPointFiles, write_sweep
        from sweep.grid import SweepSpec

        for job in db.running_jobs_without_pending_points(self.con):
            job_id = job["id"]
            if time.monotonic() < self._combine_after.get(job_id, 0.0):
                continue
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
                if disk_full(err):  # not the job's fault: it is combined once there is room
                    self._combine_after[job_id] = time.monotonic() + COMBINE_RETRY_S
                    self.disk_error = (f"{NO_SPACE}: the dataset of job {job_id} cannot be "
                                       "written; it is tried again once there is room")
                    log.error(self.disk_error)
                    continue
                log.exception("combining job %s", job_id)
                self._end_job(job_id, "failed", f"combining the points failed: "
                                                f"{type(err).__name__}: {err}")
                continue
            self._combine_after.pop(job_id, None)
            if counts.get("ok", 0) == 0:
                first = db.first_failure_message(self.con, job_id)
                self._end_job(job_id, "failed", f"all {job['n_points']} points failed; first: "
                                                f"{first or 'unknown'}")
            else:
                self._end_job(job_id, "done", None)

    def _recompute_damaged(self, job_id: str, spec, keys: list[str], damaged: list[str]) -> None:
        """Point files of a job found unusable when combining (moved aside): their points are
        pending again, at most ``MAX_DAMAGED_RECOMPUTES`` times each (``_feed`` submits them)."""
        over = self.engine.allow_recompute(damaged)
        if over:
            self._end_job(job_id, "failed", f"the file of point {over[0]} was unusable after "
                                            f"{MAX_DAMAGED_RECOMPUTES} recomputations (see "
                                            "points/damaged/)")
            return
        log.warning("job %s: %d point file(s) unusable, computing them again", job_id,
                    len(damaged))
        db.reopen_job_points(self.con, job_id, damaged)

    def _end_job(self, job_id: str, status: str, error: str | None) -> None:
        error = None if error is None else one_line_message(error)
        db.end_job(self.con, job_id, status, error)
        log.info("job %s %s%s", job_id, status, f": {error}" if error else "")
