"""Running a sweep: find the missing points, compute them on Dask, combine.

The order of events that makes a sweep cheap and restartable:

1. validate the whole grid before anything runs (bad input never reaches a worker);
2. look at the points folder: a point with a usable stored record is not computed again (resume;
   the reuse rule is ``sweep.engine.stored_record``);
3. warm the Numba cache in this process with one tiny run, *then* start the workers, so that no
   worker compiles and no two processes compile into one empty cache; then call the optional
   ``on_cluster_ready(client)`` (e.g. ``cluster.warm_workers``, or a benchmark's clock);
4. hand the missing points to a ``sweep.engine.PointEngine`` (the one engine of the CLI and the
   service: submission a window at a time, storage of the results, retries of the
   infrastructure's failures) and wait for them;
5. write ``DIR/sweep.nc`` from the point files (also when some points failed); point files found
   unusable then are computed again (``PointEngine.allow_recompute``).

A worker that dies for an outside reason is restarted by its Nanny and its task is re-run
elsewhere; nothing is lost, because results live in files, not in the scheduler.

Interface used by ``airpuff sweep`` and ``sweep.demo``: ``run_sweep(...) -> SweepOutcome``.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path
from typing import Callable

from airpuff_core.params import RunParams
from airpuff_core.provenance import model_version

from .cluster import check_workers, close_client, make_client
from .combine import DamagedPointFiles, write_sweep
from .engine import PointEngine, stored_record
from .grid import SweepSpec
from .numba_cache import warm_numba_cache
from .record import PointRecord
from .storage import POINTS_SUBDIR, SWEEP_FILE, point_key, write_spec


@dataclass
class SweepOutcome:
    """What a call of :func:`run_sweep` did.

    ``computed``: points simulated by this call (ok or failed); ``reused``: points found stored
    and not recomputed; ``failed``: points whose status is failed (new or stored);
    ``records``: one ``PointRecord`` per grid point in C order; ``path``: the combined
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
    records: list[PointRecord | None] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    model_version: str = field(default_factory=model_version)

    @property
    def ok(self) -> int:
        return self.n_points - self.failed


ProgressFn = Callable[[PointRecord | None, dict], None]
ClusterReadyFn = Callable[[object], None]


def run_sweep(spec: SweepSpec, out_dir, client=None, workers: int = 2, scheduler: str | None = None,
              progress: ProgressFn | None = None, retry_failed: bool = False,
              points_dir=None, on_cluster_ready: ClusterReadyFn | None = None,
              time_limit_s: float | None = None) -> SweepOutcome:
    """Run every missing point of ``spec`` and write ``out_dir/sweep.nc``.

    ``client``: an existing ``distributed.Client`` (left open); otherwise one is made with
    ``make_client(workers, scheduler)`` and closed (with its LocalCluster) at the end, also on
    Ctrl-C.  No cluster is started if every point is already stored.  ``retry_failed``: re-run
    points stored as failed by the model (by default they keep their recorded failure; failures
    of the infrastructure are always re-run).  ``time_limit_s``: wall-clock limit of one point
    [s] (``sweep.engine``; None: none).  ``points_dir``: where
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
    records: dict[str, PointRecord] = {}
    todo: list[tuple[str, RunParams]] = []
    for key, p in zip(keys, points):
        rec = stored_record(points_dir, key, retry_failed)
        if rec is not None:
            records[key] = rec
        else:
            todo.append((key, p))

    counts = {"total": len(points), "done": len(records), "computed": 0, "reused": len(records),
              "failed": sum(r.failed for r in records.values()), "elapsed_s": 0.0,
              "workers": None}
    if progress:
        progress(None, dict(counts))

    warmup_s = None
    warnings: list[str] = []
    box = {"client": client, "own": client is None, "checked": False}
    engine = PointEngine(client, points_dir, time_limit_s=time_limit_s)
    try:
        if todo:
            warmup_s = _compute(spec, todo, engine, box, workers, scheduler,
                                on_cluster_ready, warnings, records, counts, progress, t_start)
        by_key = dict(zip(keys, points))
        while True:
            try:
                path = write_sweep(spec, points_dir, out_dir / SWEEP_FILE, keys)
                break
            except DamagedPointFiles as err:  # files damaged since they were written
                if engine.allow_recompute(err.keys):
                    raise
                for k in err.keys:
                    old = records.pop(k, None)
                    if old is not None:
                        counts["done"] -= 1
                        counts["computed" if old.computed else "reused"] -= 1
                _compute(spec, [(k, by_key[k]) for k in err.keys], engine, box, workers,
                         scheduler, on_cluster_ready, warnings, records, counts, progress,
                         t_start)
    finally:
        if box["own"] and box["client"] is not None:
            close_client(box["client"])
    ordered = [records.get(key) for key in keys]
    return SweepOutcome(
        n_points=len(points), computed=counts["computed"], reused=counts["reused"],
        failed=sum(r is not None and r.failed for r in ordered), path=path,
        out_dir=out_dir, wall_s=time.perf_counter() - t_start, warmup_s=warmup_s,
        records=ordered, warnings=warnings)


def _compute(spec, todo, engine: PointEngine, box: dict, workers: int, scheduler,
             on_cluster_ready, warnings: list, records: dict, counts: dict, progress,
             t_start: float) -> float:
    """Compute ``todo`` (``(key, RunParams)`` pairs) with ``engine``, starting the cluster if
    needed (kept in ``box``); fills ``records`` and ``counts`` and reports progress.  Returns
    the Numba warm-up time in this process [s]."""
    # the sweep's options at the default E0, IOP, thickness and pmax: an ordinary point that
    # runs through every kernel (the first missing point might fail at once, e.g. a 10 um cornea)
    warmup_s = warm_numba_cache(RunParams.from_dict(spec.options), fallback=todo[0][1])
    if box["client"] is None:
        box["client"] = make_client(workers=workers, scheduler=scheduler)
    client = engine.client = box["client"]
    if not box["checked"]:
        box["checked"] = True
        warnings.extend(check_workers(client))
        if on_cluster_ready:
            on_cluster_ready(client)
    counts["workers"] = max(1, len(client.scheduler_info().get("workers", {})))
    waiting = OrderedDict(todo)
    source = {"sweep": lambda n: list(islice(waiting.items(), n))}
    while waiting or engine.tasks:
        for key in engine.feed(source):
            del waiting[key]
        engine.wait(timeout=1.0)
        for _, _, rec in engine.collect():
            records[rec.key] = rec
            counts["done"] += 1
            counts["computed" if rec.computed else "reused"] += 1
            counts["failed"] += rec.failed
            counts["elapsed_s"] = time.perf_counter() - t_start
            if progress:
                progress(rec, dict(counts))
    return warmup_s
