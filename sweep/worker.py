"""The task of one sweep point, as it runs on a Dask worker: simulate, account, record.

Two entry points, one code path (:func:`_simulate_point`):

* :func:`run_point` -- what ``airpuff sweep`` submits: the worker writes the point's file into the
  sweep folder itself (the folder must be visible to the workers);
* :func:`compute_point` -- what the HTTP service's runner submits: the point's netCDF file travels
  back through Dask as bytes and the service writes it (``sweep.storage.save_point``), so the
  workers need no file system shared with the service.

Both receive the point as a validated ``RunParams`` (pickled by Dask, not re-validated) and its key
(computed once, where the point entered the system).  A failure of any kind -- the solver's own
``SimulationError`` (blow-up, no convergence) or any other exception -- is caught, because it
must not kill the worker, and becomes a failure record.  Every record says which process ran the
point and how many Numba kernels it compiled or loaded from the cache during the call (the JIT
accounting behind the cold/warm start figures of docs/performance.md).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from airpuff_core import __version__
from airpuff_core.params import RunParams
from airpuff_core.result import METRICS

from .numba_cache import jit_counts, jit_delta
from .storage import (failed_path, json_safe_metrics, notes_message, one_line_message, point_key,
                      point_path, read_point, reusable, write_dataset, write_failure)

# Points started in this process: lets a record say whether it paid the per-process start-up
# (imports, Numba cache loading or compiling), which is what the cold/warm start figures are about.
_points_run_in_this_process = 0


def run_point(params: RunParams, points_dir: str, retry_failed: bool = False,
              key: str | None = None) -> dict:
    """Run one grid point and store it in ``points_dir``; the task ``airpuff sweep`` submits.

    If the point is already stored it is read back, not recomputed (a finished point is never
    rewritten; a failure of the model is re-run only with ``retry_failed``, one of the
    infrastructure always: ``sweep.storage.reusable``).  Otherwise the solver runs and
    the result is written atomically to ``point_path`` (or the failure to ``failed_path``).
    ``key`` is the point's key (``point_key(params)`` if not given).

    Returns a JSON-safe record::

        {"key": str, "status": "ok" | "failed", "message": str,
         "metrics": {name: float | None},        # None where missing (always None if failed)
         "wall_s": float,                         # run time of simulate [s] (of the original run if reused)
         "computed": bool,                        # False if read back from an existing file
         "model_version": str,                    # airpuff_core.provenance.model_version()
         "kind": "model" | "infrastructure",      # failed only: sweep.storage.failure_kind
         "params": dict, "pid": int, "first_in_process": bool,
         "jit_compiled": int, "jit_loaded": int}  # Numba compiles / cache loads during this call
    """
    key = key or point_key(params)
    existing = read_point(points_dir, key)
    if reusable(existing, retry_failed):
        existing.update(computed=False, pid=os.getpid(), first_in_process=False,
                        jit_compiled=0, jit_loaded=0)
        return existing

    def store_ok(ds):
        write_dataset(ds, point_path(points_dir, key))
        failed_path(points_dir, key).unlink(missing_ok=True)  # a retried point that now succeeded

    return _simulate_point(params, key, store_ok,
                           lambda record: write_failure(points_dir, key, record))


def compute_point(params: RunParams, key: str | None = None) -> tuple[dict, bytes | None]:
    """Run one grid point and return its result file as bytes; the task the HTTP service's runner
    submits.

    Why the bytes travel back through Dask instead of the worker writing into the service's data
    directory: workers in other containers, on other hosts, in batch jobs or in Kubernetes pods
    then need no file system shared with the service (no shared volume, no matching user ids, no
    NFS caching delays, no path that must mean the same on both sides), and the service's data
    directory has exactly one writer.  A point file is about 0.1 MB at coarse resolution, small
    beside what Dask moves routinely.  The netCDF is written to a private temporary folder of
    this process (by the same writer as :func:`run_point`, so the bytes are those of the file it
    would write), read back and deleted.

    Returns ``(record, netcdf)``: the record of :func:`run_point` (``computed`` is always True)
    and the complete point file (bytes) if the status is ``"ok"``, else None.  The caller stores
    both with ``sweep.storage.save_point``.  (A pair rather than the bytes inside the record: Dask
    estimates the size of a dict of more than 10 values from a sample of them, and would often
    miss the file in its memory accounting.)
    """
    key = key or point_key(params)
    blob: dict[str, bytes] = {}

    def store_ok(ds):
        with tempfile.TemporaryDirectory(prefix="airpuff-point-") as tmp:
            path = write_dataset(ds, Path(tmp) / f"{key}.nc")
            blob["netcdf"] = path.read_bytes()

    record = _simulate_point(params, key, store_ok, lambda record: None)
    return record, (blob["netcdf"] if record["status"] == "ok" else None)


def _simulate_point(params: RunParams, key: str, store_ok, store_failed) -> dict:
    """Simulate one point; ``store_ok(dataset)`` or ``store_failed(record)`` keeps the outcome.
    Any exception (of the solver or of ``store_ok``) becomes a failed record."""
    global _points_run_in_this_process

    first = _points_run_in_this_process == 0
    _points_run_in_this_process += 1
    jit_before = jit_counts()
    t0 = time.perf_counter()
    try:
        from airpuff_core import simulate

        result = simulate(params, threads=1)  # the sweep keeps every core busy with a point
        ds = result.to_dataset()
        wall = time.perf_counter() - t0
        ds.attrs["sweep_point_key"] = key
        ds.attrs["wall_time_s"] = wall
        store_ok(ds)
        record = {"key": key, "status": "ok", "message": notes_message(result.metric_notes),
                  "metrics": json_safe_metrics(result.metrics), "wall_s": wall,
                  "model_version": ds.attrs["model_version"]}
    except Exception as err:  # noqa: BLE001 - every failure is recorded, the worker lives on
        record = failure_record(key, params, err, time.perf_counter() - t0)
        store_failed(record)
    compiled, loaded = jit_delta(jit_before, jit_counts())
    record.update(computed=True, params=params.to_dict(), pid=os.getpid(), first_in_process=first,
                  jit_compiled=compiled, jit_loaded=loaded)
    return record


def failure_record(key: str, params: RunParams, err: BaseException, wall: float | None) -> dict:
    """The record of a point that raised ``err``; its message is one line.  Its ``kind`` is
    ``model`` for the solver's own verdicts (``SimulationError``, ``ParameterError``), else
    ``infrastructure`` (``sweep.storage.failure_kind``)."""
    from airpuff_core.errors import SimulationError
    from airpuff_core.params import ParameterError
    from airpuff_core.provenance import model_version

    model = isinstance(err, (SimulationError, ParameterError))
    if model:
        message = str(err)
    else:  # not the solver's own verdict: name the exception type so a bug is recognisable
        message = f"{type(err).__name__}: {err}"
    message = one_line_message(message) or type(err).__name__
    return {"key": key, "status": "failed", "message": message,
            "error_type": type(err).__name__, "kind": "model" if model else "infrastructure",
            "time_ms": None if getattr(err, "time_ms", None) is None else float(err.time_ms),
            "reason": None if getattr(err, "reason", None) is None else str(err.reason),
            "metrics": {name: None for name in METRICS}, "wall_s": wall,
            "params": params.to_dict(), "software_version": __version__,
            "model_version": model_version()}


def failure_from_exception(points_dir: str | os.PathLike, params: RunParams, err: BaseException,
                           key: str | None = None) -> dict:
    """Record (and store) a point whose task died outside the task's own error handling, e.g.
    ``KilledWorker``: the point crashed worker processes repeatedly.  Called by the runners."""
    key = key or point_key(params)
    record = failure_record(key, params, err, None)
    record["message"] = f"the task could not complete: {record['message']}"
    write_failure(points_dir, key, record)
    record.update(computed=True, pid=None, first_in_process=False, jit_compiled=0, jit_loaded=0)
    return record
