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
  (``sweep.storage.save_point``), after checking that the worker runs this model version;
* **retries**: a failure of the infrastructure (a lost worker, a write error) is submitted again
  up to ``INFRASTRUCTURE_RETRIES`` times; a task cancelled under us (a scheduler that restarted)
  up to ``MAX_LOST_RESUBMITS`` times; a point whose stored file proves unusable when the sweep is
  combined is computed again up to ``MAX_DAMAGED_RECOMPUTES`` times
  (:meth:`PointEngine.allow_recompute`).

The engine holds only the points in flight (at most the window); what waits is the caller's
(a list in the CLI, the job database in the service).  It is used from one thread.
"""

from __future__ import annotations

import logging
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Hashable, Iterable

from airpuff_core.provenance import model_version
from airpuff_core.result import METRICS

from .record import PointRecord
from .storage import INFRASTRUCTURE_RETRIES, one_line_message, read_point, reusable, save_point, \
    write_failure

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


class PointEngine:
    """Computes points on the Dask cluster of ``client`` and stores them in ``points_dir``.

    ``retries``: Dask's re-runs of a task whose worker died; ``window``: tasks in Dask at once
    (default ``WINDOW_PER_THREAD`` per worker thread); ``on_submit(keys)``: called for every
    submission, re-submissions included (the service counts them).
    """

    def __init__(self, client, points_dir, retries: int = 2, window: int | None = None,
                 on_submit: Callable[[list[str]], None] | None = None):
        self.client = client
        self.points_dir = Path(points_dir)
        self.retries = retries
        self._window = window
        self.on_submit = on_submit
        self.tasks: dict[str, _Task] = {}  # point key -> its task in flight
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
        free = self.window() - len(self.tasks)
        if free <= 0 or not sources:
            return []
        candidates = {owner: list(fetch(free + len(self.tasks)))
                      for owner, fetch in sources.items()}
        order = sorted(candidates, key=lambda owner: self._served.get(owner, -1))
        submitted: list[str] = []
        while free > 0 and any(candidates.values()):
            for owner in order:
                queue = candidates[owner]
                while queue and queue[0][0] in self.tasks:
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
        out = []
        for key, task in list(self.tasks.items()):
            fut = task.future
            if not fut.done():
                continue
            del self.tasks[key]
            again = wanted is None or wanted(key)
            if fut.status == "finished":
                record = self._store(key, fut)
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

    def _store(self, key: str, fut) -> PointRecord:
        """Write the point file that came back through Dask into ``points_dir``."""
        try:
            record, data = fut.result()
            if record.key != key:  # the workers run another version of airpuff
                log.warning("point %s came back under key %s: do the workers run the same "
                            "airpuff version as this process?", key, record.key)
            if record.ok and record.model_version != model_version():
                raise RuntimeError(f"the worker runs model version {record.model_version}, "
                                   f"this process {model_version()}: install the same airpuff "
                                   "on the workers")
            return save_point(self.points_dir, key, record, data)
        except Exception as err:  # noqa: BLE001 - e.g. a full disk: the infrastructure's
            log.exception("storing point %s", key)
            message = one_line_message(f"could not store the result: {type(err).__name__}: {err}")
            record = PointRecord(key=key, status="failed", message=message,
                                 kind="infrastructure", error_type=type(err).__name__,
                                 metrics={name: None for name in METRICS},
                                 model_version=model_version())
            self._store_failure(record)
            return record

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
        """Cancel the tasks of ``keys`` that are in flight; returns those cancelled."""
        cancelled = [k for k in keys if k in self.tasks]
        if cancelled:
            self.client.cancel([self.tasks[k].future for k in cancelled])
            for k in cancelled:
                self.tasks.pop(k).future.release()
        return cancelled

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
