"""The task of one sweep point, as it runs on a Dask worker: simulate, account, record.

:func:`compute_point` is what the sweep engine (``sweep.engine``, behind ``airpuff sweep`` and the
HTTP service) submits: the point's netCDF file travels back through Dask as bytes and the engine
writes it (``sweep.storage.save_point``), so the workers need no file system shared with the
process that runs the sweep.

It receives the point as a validated ``RunParams`` (pickled by Dask, not re-validated) and its key
(computed once, where the point entered the system).  A failure of any kind -- the solver's own
``SimulationError`` (blow-up, no convergence) or any other exception -- is caught, because it
must not kill the worker, and becomes a failure record.  Every record says which process ran the
point and how many Numba kernels it compiled or loaded from the cache during the call (the JIT
accounting behind the cold/warm start figures of docs/performance.md).
"""

from __future__ import annotations

import os
import socket
import tempfile
import time
from pathlib import Path

from airpuff_core import __version__
from airpuff_core.params import RunParams
from airpuff_core.result import METRICS

from .numba_cache import jit_counts, jit_delta
from .record import PointRecord
from .storage import json_safe_metrics, notes_message, one_line_message, point_key, write_dataset

# Points started in this process: lets a record say whether it paid the per-process start-up
# (imports, Numba cache loading or compiling), which is what the cold/warm start figures are about.
_points_run_in_this_process = 0


def compute_point(params: RunParams, key: str | None = None) -> tuple[PointRecord, bytes | None]:
    """Run one grid point and return its record and its result file as bytes.

    Why the bytes travel back through Dask instead of the worker writing into the sweep's folder:
    workers in other containers, on other hosts, in batch jobs or in Kubernetes pods then need no
    file system shared with the process running the sweep (no shared volume, no matching user
    ids, no NFS caching delays, no path that must mean the same on both sides), and the points
    folder has exactly one writer.  A point file is about 0.1 MB at coarse resolution, small
    beside what Dask moves routinely.  The netCDF is written to a private temporary folder of
    this process (by the project's one netCDF writer), read back and deleted.

    Returns ``(record, netcdf)``: the record (``computed`` True) and the complete point file
    (bytes) if the status is ``"ok"``, else None.  The caller stores both with
    ``sweep.storage.save_point``.  (A pair rather than the bytes inside the record: Dask
    estimates the size of a container from a sample of its values, and would often miss the
    file in its memory accounting.)
    """
    key = key or point_key(params)
    blob: dict[str, bytes] = {}

    def store_ok(ds):
        with tempfile.TemporaryDirectory(prefix="airpuff-point-") as tmp:
            path = write_dataset(ds, Path(tmp) / f"{key}.nc")
            blob["netcdf"] = path.read_bytes()

    record = _simulate_point(params, key, store_ok)
    return record, (blob["netcdf"] if record.ok else None)


def _simulate_point(params: RunParams, key: str, store_ok) -> PointRecord:
    """Simulate one point; ``store_ok(dataset)`` keeps a finished one.  Any exception (of the
    solver or of ``store_ok``) becomes a failed record."""
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
        # Which machine (container) computed the point: a deployment's check that the workers,
        # not the service, ran it (tests/deploy/test_docker.py).
        ds.attrs["computed_on_host"] = socket.gethostname()
        store_ok(ds)
        record = PointRecord(key=key, status="ok", message=notes_message(result.metric_notes),
                             metrics=json_safe_metrics(result.metrics), wall_s=wall,
                             model_version=ds.attrs["model_version"])
    except Exception as err:  # noqa: BLE001 - every failure is recorded, the worker lives on
        record = failure_record(key, params, err, time.perf_counter() - t0)
    compiled, loaded = jit_delta(jit_before, jit_counts())
    record.params = params.to_dict()
    record.pid = os.getpid()
    record.first_in_process = first
    record.jit_compiled, record.jit_loaded = compiled, loaded
    return record


def failure_record(key: str, params: RunParams, err: BaseException,
                   wall: float | None) -> PointRecord:
    """The record of a point that raised ``err``; its message is one line.  Its ``kind`` is
    ``model`` for the solver's own verdicts (``SimulationError``, ``ParameterError``), else
    ``infrastructure``."""
    from airpuff_core.errors import SimulationError
    from airpuff_core.params import ParameterError
    from airpuff_core.provenance import model_version

    model = isinstance(err, (SimulationError, ParameterError))
    if model:
        message = str(err)
    else:  # not the solver's own verdict: name the exception type so a bug is recognisable
        message = f"{type(err).__name__}: {err}"
    message = one_line_message(message) or type(err).__name__
    return PointRecord(
        key=key, status="failed", message=message, error_type=type(err).__name__,
        kind="model" if model else "infrastructure",
        time_ms=None if getattr(err, "time_ms", None) is None else float(err.time_ms),
        reason=None if getattr(err, "reason", None) is None else str(err.reason),
        metrics={name: None for name in METRICS}, wall_s=wall, params=params.to_dict(),
        software_version=__version__, model_version=model_version())
