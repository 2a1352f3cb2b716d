"""The sweep engine: how points are computed on Dask, shared by `airpuff sweep` and the service.

``sweep.runner`` (the CLI, one sweep, blocking) and ``api.runner`` (the service's thread, many jobs)
both hand their points to a :class:`PointEngine`; the policy lives here, once:

* **reuse** (:func:`stored_record`): a point whose file is stored is not computed again; a stored
  failure of the model is reused unless ``retry_failed``, one of the infrastructure never; an
  unreadable file is moved aside and counts as missing (``sweep.storage.open_point``);
* **submission**: one ``sweep.worker.compute_point`` task per point (``pure=False``: it has side
  effects; Dask ``retries`` for a worker that died), fed to Dask a *window* at a time
  (:meth:`PointEngine.feed`), taking points from the engine's owners (the service's jobs) in turn,
  the one served least recently first, so a small job is not starved behind a large one;
* **storage**: the result file comes back through Dask as bytes and is written here
  (``sweep.storage.save_point``), after checking that the worker runs this model version; a
  result that a full disk does not let us write is kept (it counts in the window, so nothing
  new is submitted meanwhile) and written on each :meth:`PointEngine.collect` until there is
  room, ``storage_error`` saying why;
* **retries**: a failure of the infrastructure (a lost worker, a write error) is submitted again
  up to ``INFRASTRUCTURE_RETRIES`` times; a task cancelled under us (a scheduler that restarted)
  up to ``MAX_LOST_RESUBMITS`` times; a point whose stored file proves unusable when the sweep is
  combined is computed again up to ``MAX_DAMAGED_RECOMPUTES`` times
  (:meth:`PointEngine.allow_recompute`);
* **stopping**: a task running longer than its wall-clock limit, or one cancelled while it runs,
  is stopped by ending its worker process, which the worker's nanny replaces (a running Python
  thread cannot be stopped otherwise); a point over its limit is recorded as failed
  (``TimeLimitExceeded``).

The engine holds only the points in flight (at most the window); what waits is the caller's
(a list in the CLI, the job database in the service).  It is used from one thread.
"""

from __future__ import annotations

import logging
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Hashable, Iterable

from airpuff_core.provenance import model_version
from airpuff_core.result import METRICS

from .record import PointRecord
from .storage import (INFRASTRUCTURE_RETRIES, NO_SPACE, disk_full, one_line_message, read_point,
                      reusable, save_point, write_failure)

log = logging.getLogger("airpuff.engine")

# Tasks cancelled under us (the scheduler restarted) are submitted again this often.
MAX_LOST_RESUBMITS = 3
# A point whose stored file proves unusable when its sweep is combined is computed again this often.
MAX_DAMAGED_RECOMPUTES = 2
# Tasks in Dask at once per worker thread: one running, one ready to start.
WINDOW_PER_THREAD = 2


# owner -> a function that returns up to n (key, RunParams) it waits for, in its order
Sources = dict[Hashable, Callable[[int], list[tuple[str, object]]]]


def stored_record(points_dir, key: str, retry_failed: bool = False) -> PointRecord | None:
    """The stored record of ``key`` if it stands instead of computing the point (see the module's
    reuse rule), else None."""
    record = read_point(points_dir, key)  # None if missing or unusable (moved aside)
    return record if reusable(record, retry_failed) else None


@dataclass
class _Task:
    future: object
    params: object
    owner: Hashable
    infrastructure_retries: int = 0
    lost: int = 0


async def _end_this_worker() -> None:
    """(On a worker, through ``Client.run``; a coroutine, so that the call need not wait for
    an answer that never comes) end this process at once; its nanny restarts it."""
    import os
    import signal

    os.kill(os.getpid(), signal.SIGKILL)


def executing_tasks(dask_worker=None) -> dict[str, float]:
    """(On a worker, through ``Client.run``) Dask key -> seconds it has been running."""
    from time import time

    return {str(ts.key): time() - ts.start_time for ts in dask_worker.state.executing
            if ts.start_time is not None}


class PointEngine:
    """Computes points on the Dask cluster of ``client`` and stores them in ``points_dir``.

    ``retries``: Dask's re-runs of a task whose worker died; ``window``: tasks in Dask at once
    (default ``WINDOW_PER_THREAD`` per worker thread); ``on_submit(keys)``: called for every
    submission, re-submissions included (the service counts them); ``time_limit_s``: wall-clock
    limit of one task [s] (None: none), enforced by :meth:`enforce_time_limit`.
    """

    def __init__(self, client, points_dir, retries: int = 2, window: int | None = None,
                 on_submit: Callable[[list[str]], None] | None = None,
                 time_limit_s: float | None = None):
        self.client = client
        self.time_limit_s = time_limit_s
        self._stopped: list[tuple[str, Hashable, PointRecord]] = []  # over their time limit
        self._last_check = 0.0
        self.points_dir = Path(points_dir)
        self.retries = retries
        self._window = window
        self.on_submit = on_submit
        self.tasks: dict[str, _Task] = {}  # point key -> its task in flight
        # point key -> (task, record, netCDF bytes): results that a full disk did not let us
        # store yet; kept, counted in the window, and stored again on each collect
        self.unstored: dict[str, tuple[_Task, PointRecord, bytes | None]] = {}
        self.storage_error: str | None = None  # why results wait to be stored, if they do
        self.recomputes: dict[str, int] = {}  # point key -> recomputes after an unusable file
        self._served: dict[Hashable, int] = {}  # owner -> when it last had a point submitted
        self._turn = 0

    # -- feeding ------------------------------------------------------------------------------
    def window(self) -> int:
        if self._window is not None:
            return self._window
        try:
            threads = sum(self.client.nthreads().values())
        except Exception:  # noqa: BLE001 - a scheduler that is not reachable right now
            threads = 1
        return WINDOW_PER_THREAD * max(1, threads)

    def feed(self, sources: Sources) -> list[str]:
        """Fill the window with points of ``sources``, one owner at a time, the owner served
        least recently first; returns the keys submitted.  A key already in flight (asked for by
        another owner too) is not submitted twice."""
        free = self.window() - len(self.tasks) - len(self.unstored)
        if free <= 0 or not sources:
            return []
        candidates = {owner: list(fetch(free + len(self.tasks)))
                      for owner, fetch in sources.items()}
        order = sorted(candidates, key=lambda owner: self._served.get(owner, -1))
        submitted: list[str] = []
        while free > 0 and any(candidates.values()):
            for owner in order:
                queue = candidates[owner]
                while queue and self.holds(queue[0][0]):
                    queue.pop(0)
                if not queue or free <= 0:
                    continue
                key, params = queue.pop(0)
                self._submit(key, _Task(None, params, owner))
                self._turn += 1
                self._served[owner] = self._turn
                submitted.append(key)
                free -= 1
        if submitted and self.on_submit:
            self.on_submit(submitted)
        return submitted

    def holds(self, key: str) -> bool:
        """Whether the point ``key`` is in flight, or computed and waiting to be stored."""
        return key in self.tasks or key in self.unstored

    def _submit(self, key: str, task: _Task) -> None:
        from .worker import compute_point

        task.future = self.client.submit(
            compute_point, task.params, key, pure=False, retries=self.retries,
            key=f"airpuff-point-{key}-{uuid.uuid4().hex[:8]}")  # unique per submission
        self.tasks[key] = task

    def _resubmit(self, key: str, task: _Task) -> None:
        self._submit(key, task)
        if self.on_submit:
            self.on_submit([key])

    # -- collecting ---------------------------------------------------------------------------
    def wait(self, timeout: float | None = None) -> None:
        """Block until a task in flight has finished (or ``timeout`` [s] has passed)."""
        from distributed import wait

        if not self.tasks:
            return
        try:
            wait([t.future for t in self.tasks.values()], timeout=timeout,
                 return_when="FIRST_COMPLETED")
        except TimeoutError:
            pass

    def collect(self, wanted: Callable[[str], bool] | None = None
                ) -> list[tuple[str, Hashable, PointRecord]]:
        """The finished tasks as ``(key, owner, record)``, each result stored.  A failure of the
        infrastructure, or a task lost with the scheduler, is submitted again (within its
        limits) instead of being returned, if ``wanted(key)`` (default: always)."""
        self.enforce_time_limit()
        out, self._stopped = self._stopped, []
        for key, (task, record, data) in list(self.unstored.items()):
            stored = self._store(key, record, data)
            if stored is None:
                break  # still no room: the others wait too
            del self.unstored[key]
            out.append((key, task.owner, stored))
        if not self.unstored:
            self.storage_error = None
        for key, task in list(self.tasks.items()):
            fut = task.future
            if not fut.done():
                continue
            del self.tasks[key]
            again = wanted is None or wanted(key)
            if fut.status == "finished":
                record = self._result(key, fut)
                if record.ok or record.failed and record.kind == "model":
                    data = fut.result()[1] if record.ok else None
                    stored = self._store(key, record, data)
                    if stored is None:  # a full disk: keep the result, store it later
                        self.unstored[key] = (task, record, data)
                        fut.release()
                        continue
                    record = stored
                else:
                    self._store_failure(record)
            elif fut.status == "cancelled":  # lost with the scheduler: not the point's fault
                if again and task.lost < MAX_LOST_RESUBMITS:
                    task.lost += 1
                    self._resubmit(key, task)
                    continue
                record = self._failure(key, task.params,
                                       RuntimeError("the task was lost repeatedly"))
            else:  # the task raised (e.g. KilledWorker: the point crashed workers repeatedly)
                record = self._failure(key, task.params, fut.exception())
            fut.release()
            if (record.failed and record.failure_kind() == "infrastructure" and again
                    and task.infrastructure_retries < INFRASTRUCTURE_RETRIES):
                task.infrastructure_retries += 1
                log.warning("point %s: %s; submitting it again (%d of %d)", key, record.message,
                            task.infrastructure_retries, INFRASTRUCTURE_RETRIES)
                self._resubmit(key, task)
                continue
            out.append((key, task.owner, record))
        return out

    def _result(self, key: str, fut) -> PointRecord:
        """The record that came back through Dask, checked: a worker of another model version
        gives a failure of the infrastructure."""
        record, _ = fut.result()
        if record.key != key:  # the workers run another version of airpuff
            log.warning("point %s came back under key %s: do the workers run the same "
                        "airpuff version as this process?", key, record.key)
        if record.ok and record.model_version != model_version():
            return self._failed_to_store(key, RuntimeError(
                f"the worker runs model version {record.model_version}, this process "
                f"{model_version()}: install the same airpuff on the workers"))
        return record

    def _store(self, key: str, record: PointRecord, data: bytes | None) -> PointRecord | None:
        """Write a point's result (its file, or its failure record) into ``points_dir``;
        returns the record, a failure of the infrastructure if it cannot be stored, or None if
        the disk is full (the caller keeps the result and tries again; ``storage_error`` says
        why)."""
        try:
            record = save_point(self.points_dir, key, record, data)
            self.storage_error = None
            return record
        except Exception as err:  # noqa: BLE001 - e.g. a full disk: the infrastructure's
            if disk_full(err):
                self.storage_error = (f"{NO_SPACE} in the points folder: "
                                      f"{len(self.unstored) + 1} computed point(s) wait to be "
                                      "stored; free space and they are stored")
                log.error("point %s: %s; its result is kept and stored once there is room",
                          key, NO_SPACE)
                return None
            log.exception("storing point %s", key)
            record = self._failed_to_store(key, err)
            self._store_failure(record)
            return record

    @staticmethod
    def _failed_to_store(key: str, err: BaseException) -> PointRecord:
        message = one_line_message(f"could not store the result: {type(err).__name__}: {err}")
        return PointRecord(key=key, status="failed", message=message, kind="infrastructure",
                           error_type=type(err).__name__, metrics={name: None for name in METRICS},
                           model_version=model_version())

    def _failure(self, key: str, params, err: BaseException) -> PointRecord:
        """Record (and store) a point whose task died outside its own error handling."""
        from .worker import failure_record

        record = failure_record(key, params, err, None)
        record.message = f"the task could not complete: {record.message}"
        self._store_failure(record)
        return record

    def _store_failure(self, record: PointRecord) -> None:
        """Store a failure record if the disk lets us (it is the record's only copy besides
        the caller's; a failure of the infrastructure is never reused, only shown)."""
        try:
            write_failure(self.points_dir, record.key, record)
        except OSError as err:
            log.error("point %s: could not store its failure record: %s", record.key, err)

    # -- stopping -----------------------------------------------------------------------------
    def cancel(self, keys: Iterable[str]) -> list[str]:
        """Cancel the tasks of ``keys`` that are in flight, and restart the workers that are
        running any of them (a running task cannot be stopped otherwise); returns the keys
        cancelled."""
        cancelled = [k for k in keys if k in self.tasks]
        if not cancelled:
            return []
        dask_keys = {self.tasks[k].future.key: k for k in cancelled}
        running = self._running()
        self.client.cancel([self.tasks[k].future for k in cancelled])
        for k in cancelled:
            self.tasks.pop(k).future.release()
        self._restart([addr for addr, tasks in running.items()
                       if any(key in dask_keys for key in tasks)])
        return cancelled

    def enforce_time_limit(self, every_s: float = 1.0) -> None:
        """Stop the tasks running longer than ``time_limit_s`` (checked at most every
        ``every_s`` seconds): each is cancelled, its worker restarted (the only way to stop a
        running task), and its point recorded as failed (``TimeLimitExceeded``, a failure of
        the model: the same point would overrun again) for the next :meth:`collect`."""
        now = time.monotonic()
        if self.time_limit_s is None or not self.tasks or now - self._last_check < every_s:
            return
        self._last_check = now
        by_dask_key = {t.future.key: k for k, t in self.tasks.items()}
        over: dict[str, str] = {}  # point key -> worker address
        for addr, tasks in self._running().items():
            for dask_key, seconds in tasks.items():
                if seconds > self.time_limit_s and dask_key in by_dask_key:
                    over[by_dask_key[dask_key]] = addr
        if not over:
            return
        self.client.cancel([self.tasks[k].future for k in over])
        for key, addr in over.items():
            task = self.tasks.pop(key)
            task.future.release()
            record = PointRecord(
                key=key, status="failed", kind="model", error_type="TimeLimitExceeded",
                message=f"stopped after the wall-clock limit of {self.time_limit_s:g} s per "
                        "point (its worker was restarted); a smaller t_end or a coarser "
                        "resolution runs faster",
                metrics={name: None for name in METRICS}, params=task.params.to_dict(),
                model_version=model_version())
            log.warning("point %s: over its time limit of %g s on %s; worker restarted", key,
                        self.time_limit_s, addr)
            self._store_failure(record)
            self._stopped.append((key, task.owner, record))
        self._restart(sorted(set(over.values())))

    def _running(self) -> dict[str, dict[str, float]]:
        """Worker address -> {Dask key: seconds running} of the tasks executing now."""
        try:
            return self.client.run(executing_tasks)
        except Exception as err:  # noqa: BLE001 - a worker that is going away: next time
            log.warning("could not ask the workers what they run: %s", err)
            return {}

    def _restart(self, addresses: list[str]) -> None:
        """End the worker processes at ``addresses``; their nannies start new ones (as after
        any crash of a worker).  Not ``Client.restart_workers``: it waits for the new process,
        and a nanny asked to restart a worker that was itself just restarted closed instead
        (distributed 2026.8, seen in the tests)."""
        if not addresses:
            return
        try:
            self.client.run(_end_this_worker, workers=addresses, wait=False)
        except Exception as err:  # noqa: BLE001 - a worker that is going away anyway
            log.error("could not stop workers %s: %s", addresses, err)

    def allow_recompute(self, keys: Iterable[str]) -> list[str]:
        """Count one more recompute of each of ``keys`` (point files found unusable); returns
        the keys already recomputed ``MAX_DAMAGED_RECOMPUTES`` times (not counted again)."""
        over = []
        for k in keys:
            if self.recomputes.get(k, 0) >= MAX_DAMAGED_RECOMPUTES:
                over.append(k)
            else:
                self.recomputes[k] = self.recomputes.get(k, 0) + 1
        return over
