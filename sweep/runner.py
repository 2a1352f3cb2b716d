"""Running a sweep: find the missing points, fan them out on Dask, collect, combine.

The runner owns the order of events that makes a sweep cheap and restartable:

1. validate the whole grid before anything runs (bad input never reaches a worker);
2. look at the points folder: a point with a file is done and is not submitted again (resume);
3. warm the Numba cache in this process with one tiny run, *then* start the workers, so that no
   worker compiles and no two processes compile into one empty cache; then call the optional
   ``on_cluster_ready(client)`` (e.g. ``cluster.warm_workers``, or a benchmark's clock);
4. submit the missing points (``pure=False``: each call has side effects; ``retries=2``), keep every
   future referenced (Dask cancels work nobody holds), and collect them with ``as_completed``;
5. write ``DIR/sweep.nc`` from the point files (also when some points failed).

A point that fails is recorded by ``sweep.worker.run_point`` on the worker; a point whose task dies anyway (it
crashed its worker process three times: ``KilledWorker``) is recorded here.  A failure of the
infrastructure (``sweep.storage.failure_kind``: anything but the solver's verdict) is submitted
again, up to ``INFRASTRUCTURE_RETRIES`` times, and a stored one is never reused; a failure of the
model is kept unless ``retry_failed``.  A point file that cannot be read, at the start or when
combining, counts as missing (``sweep.storage.open_point`` moves it aside) and is computed again.  A worker that dies for
an outside reason is restarted by its Nanny and its task is re-run elsewhere; nothing is lost,
because results live in files, not in the scheduler.

Interface used by the HTTP API (issue 5): ``run_sweep(...) -> SweepOutcome``.
"""

from __future__ import annotations

import concurrent.futures
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from airpuff_core.params import RunParams

from .cluster import check_workers, close_client, make_client
from airpuff_core.provenance import model_version

from .combine import DamagedPointFiles, write_sweep
from .grid import SweepSpec
from .numba_cache import warm_numba_cache
from .storage import (INFRASTRUCTURE_RETRIES, POINTS_SUBDIR, SWEEP_FILE, failure_kind, point_key,
                      read_point, reusable, write_spec)
from .worker import failure_from_exception, run_point


@dataclass
class SweepOutcome:
    """What a call of :func:`run_sweep` did.

    ``computed``: points simulated by this call (ok or failed); ``reused``: points found stored
    and not recomputed; ``failed``: points whose status is failed (new or stored);
    ``records``: one ``run_point`` record per grid point in C order; ``path``: the combined
    ``sweep.nc``; ``wall_s``: wall time of the call [s]; ``warmup_s``: the Numba warm-up in the
    client [s] (None if nothing needed computing); ``warnings``: problems seen in the workers'
    set-up (threads, Numba cache).
    """

    n_points: int
    computed: int
    reused: int
    failed: int
    path: Path
    out_dir: Path
    wall_s: float
    warmup_s: float | None
    records: list[dict] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    model_version: str = field(default_factory=model_version)

    @property
    def ok(self) -> int:
        return self.n_points - self.failed


ProgressFn = Callable[[dict | None, dict], None]
ClusterReadyFn = Callable[[object], None]


def run_sweep(spec: SweepSpec, out_dir, client=None, workers: int = 2, scheduler: str | None = None,
              progress: ProgressFn | None = None, retry_failed: bool = False,
              points_dir=None, on_cluster_ready: ClusterReadyFn | None = None) -> SweepOutcome:
    """Run every missing point of ``spec`` and write ``out_dir/sweep.nc``.

    ``client``: an existing ``distributed.Client`` (left open); otherwise one is made with
    ``make_client(workers, scheduler)`` and closed (with its LocalCluster) at the end, also on
    Ctrl-C.  No cluster is started if every point is already stored.  ``retry_failed``: re-run
    points stored as failed by the model (by default they keep their recorded failure; failures
    of the infrastructure are always re-run).  ``points_dir``: where
    the point files live (default ``out_dir/points``); sweeps may share one, since a point's file
    name is the hash of its parameters.

    ``progress(record, counts)`` is called once before submitting (``record`` None) and once per
    finished point, with ``counts = {"total", "done", "failed", "computed", "reused",
    "elapsed_s", "workers"}`` (done includes reused points; workers is the number of Dask workers,
    once known).  Raises ``ParameterError`` for an invalid spec; a ``KeyboardInterrupt``
    propagates after the cluster is shut down (finished points stay stored).

    ``on_cluster_ready(client)`` is called once the client is connected and the workers are
    checked, right before the points are submitted (not at all if nothing needs computing): the
    place to warm the workers (``sweep.cluster.warm_workers``) or to start the clock of the
    steady-state throughput, which then excludes the cluster's start-up.
    """
    t_start = time.perf_counter()
    points = spec.validated_points()
    out_dir = Path(out_dir)
    points_dir = Path(points_dir) if points_dir is not None else out_dir / POINTS_SUBDIR
    points_dir.mkdir(parents=True, exist_ok=True)
    write_spec(spec, out_dir)

    keys = [point_key(p) for p in points]  # the one hash of each point; passed on from here
    records: dict[str, dict] = {}
    todo: list[tuple[str, RunParams]] = []
    for key, p in zip(keys, points):
        rec = read_point(points_dir, key)  # an unreadable file is moved aside: None
        if reusable(rec, retry_failed):
            rec["computed"] = False
            records[key] = rec
        else:
            todo.append((key, p))

    counts = {"total": len(points), "done": len(records), "computed": 0, "reused": len(records),
              "failed": sum(r["status"] == "failed" for r in records.values()), "elapsed_s": 0.0,
              "workers": None}
    if progress:
        progress(None, dict(counts))

    warmup_s = None
    warnings: list[str] = []
    client_box = {"client": client, "own": client is None}
    try:
        if todo:
            warmup_s = _compute(spec, todo, points_dir, retry_failed, client_box, workers,
                                scheduler, on_cluster_ready, warnings, records, counts, progress,
                                t_start)
        try:
            path = write_sweep(spec, points_dir, out_dir / SWEEP_FILE, keys)
        except DamagedPointFiles as err:  # files damaged since they were written: once more
            by_key = dict(zip(keys, points))
            again = [(k, by_key[k]) for k in err.keys]
            for k, _ in again:
                old = records.pop(k, None)
                if old is not None:
                    counts["done"] -= 1
                    counts["computed" if old.get("computed", True) else "reused"] -= 1
            _compute(spec, again, points_dir, retry_failed, client_box, workers, scheduler,
                     on_cluster_ready, warnings, records, counts, progress, t_start)
            path = write_sweep(spec, points_dir, out_dir / SWEEP_FILE, keys)
    finally:
        if client_box["own"] and client_box["client"] is not None:
            close_client(client_box["client"])
    ordered = [records.get(key) for key in keys]
    return SweepOutcome(
        n_points=len(points), computed=counts["computed"], reused=counts["reused"],
        failed=sum(r is not None and r["status"] == "failed" for r in ordered), path=path,
        out_dir=out_dir, wall_s=time.perf_counter() - t_start, warmup_s=warmup_s,
        records=ordered, warnings=warnings)


def _compute(spec, todo, points_dir: Path, retry_failed: bool, client_box: dict, workers: int,
             scheduler, on_cluster_ready, warnings: list, records: dict, counts: dict,
             progress, t_start: float) -> float:
    """Compute ``todo`` (``(key, RunParams)`` pairs) on the cluster, starting it if needed (kept
    in ``client_box``); fills ``records`` and ``counts`` and reports progress.  A failure of the
    infrastructure is submitted again up to ``INFRASTRUCTURE_RETRIES`` times.  Returns the
    Numba warm-up time in this process [s]."""
    from distributed import as_completed

    # the sweep's options at the default E0, IOP, thickness and pmax: an ordinary point that
    # runs through every kernel (the first missing point might fail at once, e.g. a 10 um cornea)
    warmup_s = warm_numba_cache(RunParams.from_dict(spec.options), fallback=todo[0][1])
    if client_box["client"] is None:
        client_box["client"] = make_client(workers=workers, scheduler=scheduler)
    client = client_box["client"]
    if not client_box.get("checked"):
        client_box["checked"] = True
        warnings.extend(check_workers(client))
        if on_cluster_ready:
            on_cluster_ready(client)
    counts["workers"] = max(1, len(client.scheduler_info().get("workers", {})))
    futures = _submit(client, todo, points_dir, retry_failed)
    attempts = {key: 0 for key, _ in todo}
    pending = as_completed(list(futures))
    for fut in pending:
        key, params = futures.pop(fut)
        rec = _collect(fut, key, params, points_dir)
        if (rec["status"] == "failed" and failure_kind(rec) == "infrastructure"
                and attempts[key] < INFRASTRUCTURE_RETRIES):
            attempts[key] += 1  # the infrastructure's fault: once more (its record is not kept)
            more = _submit(client, [(key, params)], points_dir, retry_failed)
            futures.update(more)
            pending.update(more)
            continue
        records[rec["key"]] = rec
        counts["done"] += 1
        # normally computed; read back if another task stored it first (a re-run after
        # a lost worker that had already written its file)
        counts["computed" if rec.get("computed", True) else "reused"] += 1
        counts["failed"] += rec["status"] == "failed"
        counts["elapsed_s"] = time.perf_counter() - t_start
        if progress:
            progress(rec, dict(counts))
    return warmup_s


def _submit(client, todo, points_dir: Path, retry_failed: bool) -> dict:
    """Submit one task per missing ``(key, RunParams)``; returns future -> (key, RunParams) (keeps
    the futures alive)."""
    futures = {}
    batch = uuid.uuid4().hex[:8]  # task keys must be unique per submission (pure=False)
    for key, p in todo:
        fut = client.submit(run_point, p, str(points_dir), retry_failed, key,
                            key=f"airpuff-point-{key}-{batch}", pure=False, retries=2)
        futures[fut] = (key, p)
    return futures


def _collect(fut, key: str, params: RunParams, points_dir: Path) -> dict:
    """The record of a finished task.  ``run_point`` catches the solver's failures itself; an
    exception here means the task could not run at all (e.g. ``KilledWorker`` after the point
    crashed three worker processes), which is recorded as that point's failure."""
    try:
        return fut.result()
    except concurrent.futures.CancelledError:  # cancelled from outside (client restart): not the point's fault
        return {"key": key, "status": "failed", "computed": True,
                "message": "task cancelled; re-run the sweep to compute this point",
                "metrics": {}, "wall_s": None, "params": params.to_dict()}
    except Exception as err:  # noqa: BLE001
        return failure_from_exception(points_dir, params, err, key)
    finally:
        fut.release()
