"""Storage of a sweep: one file per point, and the combined ``sweep.nc``.

Layout of a sweep folder ``DIR``::

    DIR/sweep.json                the SweepSpec (user units), written when the sweep starts
    DIR/points/<key>.nc           a finished point: the full per-run netCDF of SPEC section 7
    DIR/points/<key>.failed.json  a failed point: parameters, reason, error type
    DIR/sweep.nc                  the combined file (SPEC section 7, dims E0, IOP, thickness, pmax)

Why one file per point: netCDF4/HDF5 cannot take writes from several processes into one file
(measured: 65 % of concurrent appends fail), so each worker writes its own point file to a
temporary name and renames it into place (atomic on POSIX), and only the client combines.  A point
file that exists is therefore complete, which is what makes resuming safe: a point is done iff its
file exists, and it is never rewritten.

The key of a point is a hash of its full parameter set, so identical parameters always map to the
same file, whichever sweep asked for them.

Interface used by the HTTP API (issue 5): ``point_key``, ``point_path``, ``failed_path``,
``read_point``, ``combine``, ``write_sweep``, ``POINTS_SUBDIR``, ``SWEEP_FILE``; and (issue 6)
``compute_point`` on the workers with ``save_point`` in the service, so that a point's file
travels back through Dask and workers need no file system shared with the service.
``airpuff sweep`` submits ``run_point``, which writes the file on the worker.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from airpuff_core import __version__
from airpuff_core.dataset import global_attributes, open_dataset, time_coordinate
from airpuff_core.params import PARAMETERS, SWEPT, RunParams
from airpuff_core.result import METRICS

POINTS_SUBDIR = "points"
SWEEP_FILE = "sweep.nc"
SPEC_FILE = "sweep.json"

# Histories copied into the combined file (the others stay in the per-point files).
SWEEP_HISTORIES = ("apex_displacement", "jet_pressure_apex")

# Points started in this process: lets a record say whether it paid the per-process start-up
# (imports, Numba cache loading or compiling), which is what the cold/warm start figures are about.
_points_run_in_this_process = 0


# -- names ---------------------------------------------------------------------------------------
def point_key(params: RunParams) -> str:
    """Stable identifier of a parameter set: first 16 hex digits of the SHA-256 of the sorted JSON
    of ``params.to_dict()``.  Identical parameters give identical keys in any process."""
    text = json.dumps(params.to_dict(), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def point_path(points_dir: str | os.PathLike, key: str) -> Path:
    """File of a finished point: ``points_dir/<key>.nc``."""
    return Path(points_dir) / f"{key}.nc"


def failed_path(points_dir: str | os.PathLike, key: str) -> Path:
    """Record of a failed point: ``points_dir/<key>.failed.json``."""
    return Path(points_dir) / f"{key}.failed.json"


def _atomic_write_text(path: Path, text: str) -> None:
    _atomic_write_bytes(path, text.encode("utf-8"))


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write to a temporary file in the same folder, then rename: readers never see half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _json_safe(metrics: dict[str, Any]) -> dict[str, float | None]:
    out = {}
    for name in METRICS:
        v = metrics.get(name)
        out[name] = None if v is None or not math.isfinite(float(v)) else float(v)
    return out


@contextlib.contextmanager
def process_local_write_lock():
    """Make xarray guard a netCDF write with a lock of this process only.

    xarray picks the write lock after the active Dask scheduler; inside a worker (or in a process
    holding a Client) that is a ``distributed.Lock`` kept by the scheduler: a network round trip
    per file, and an exception ("ConnectionPool is closed") if the cluster shuts down during the
    write -- after Ctrl-C that would be recorded as a failure of the point.  Every file here has
    exactly one writer (the point's task, or the combining client), so a process-local lock is
    the right one.
    """
    import dask

    with dask.config.set(scheduler="synchronous"):
        yield


# -- one point (runs on a worker) -----------------------------------------------------------------
def run_point(params_dict: dict, points_dir: str, retry_failed: bool = False) -> dict:
    """Run one grid point and store it; the function ``airpuff sweep`` submits to Dask workers.

    ``params_dict`` is ``RunParams.to_dict()`` (user units).  If the point is already stored it is
    read back, not recomputed (a finished point is never rewritten; a failed one is re-run only
    with ``retry_failed``).  Otherwise ``airpuff_core.simulate`` runs, and the result is written
    atomically to ``point_path``; a failure of any kind (``SimulationError`` for blow-up or
    non-convergence, or any other exception) is caught -- it must not kill the worker -- and
    written to ``failed_path``.  The worker must therefore see ``points_dir``; the HTTP service
    uses :func:`compute_point` instead, which needs no shared file system.

    Returns a JSON-safe record::

        {"key": str, "status": "ok" | "failed", "message": str,
         "metrics": {name: float | None},        # None where missing (always None if failed)
         "wall_s": float,                         # run time of simulate [s] (of the original run if reused)
         "computed": bool,                        # False if read back from an existing file
         "params": dict, "pid": int, "first_in_process": bool,
         "jit_compiled": int, "jit_loaded": int}  # Numba compiles / cache loads during this call
    """
    params = RunParams.from_dict(params_dict)
    key = point_key(params)
    existing = read_point(points_dir, key)
    if existing is not None and (existing["status"] == "ok" or not retry_failed):
        existing.update(computed=False, pid=os.getpid(), first_in_process=False,
                        jit_compiled=0, jit_loaded=0)
        return existing

    def store_ok(ds):
        from airpuff_core.dataset import write_netcdf

        with process_local_write_lock():
            write_netcdf(ds, point_path(points_dir, key))
        failed_path(points_dir, key).unlink(missing_ok=True)  # a retried point that now succeeded

    def store_failed(record):
        _atomic_write_text(failed_path(points_dir, key),
                           json.dumps(record, indent=1, sort_keys=True))

    return _simulate_point(params, key, store_ok, store_failed)


def compute_point(params_dict: dict) -> tuple[dict, bytes | None]:
    """Run one grid point and return its result file as bytes; the function the HTTP service's
    runner submits to Dask workers.

    Why the bytes travel back through Dask instead of the worker writing into the service's data
    directory: workers in other containers, on other hosts, in batch jobs or in Kubernetes pods
    then need no file system shared with the service (no shared volume, no matching user ids, no
    NFS caching delays, no path that must mean the same on both sides), and the service's data
    directory has exactly one writer.  A point file is about 0.1 MB at coarse resolution, small
    beside what Dask moves routinely.  Nothing is written anywhere the caller can see: the
    netCDF is written to a private temporary folder of this process (by the same
    ``write_netcdf`` as :func:`run_point`, so the bytes are those of the file it would write),
    read back and deleted.

    Returns ``(record, netcdf)``: the record of :func:`run_point` (``computed`` is always True)
    and the complete point file (bytes) if the status is ``"ok"``, else None.  A failure of any
    kind is caught, as in :func:`run_point`.  The caller stores both with :func:`save_point`.
    (A pair rather than the bytes inside the record: Dask estimates the size of a dict of more
    than 10 values from a sample of them, and would often miss the file in its memory accounting.)
    """
    params = RunParams.from_dict(params_dict)
    key = point_key(params)
    blob: dict[str, bytes] = {}

    def store_ok(ds):
        from airpuff_core.dataset import write_netcdf

        with tempfile.TemporaryDirectory(prefix="airpuff-point-") as tmp:
            path = Path(tmp) / f"{key}.nc"
            with process_local_write_lock():
                write_netcdf(ds, path)
            blob["netcdf"] = path.read_bytes()

    record = _simulate_point(params, key, store_ok, lambda record: None)
    return record, (blob["netcdf"] if record["status"] == "ok" else None)


# Fields of a record that describe one call (which process, Numba activity), not the point.
_PER_CALL = ("computed", "pid", "first_in_process", "jit_compiled", "jit_loaded")


def save_point(points_dir: str | os.PathLike, key: str, record: dict,
               data: bytes | None = None) -> dict:
    """Store what :func:`compute_point` returned under ``key`` in ``points_dir`` (in the caller's
    process): the netCDF bytes ``data`` atomically at ``point_path`` if the point is ok (any older
    failure record is removed), else the failure record at ``failed_path``.  Returns the record.
    ``key`` is the caller's, so the file lands where the caller will look for it."""
    if record.get("status") == "ok":
        if not isinstance(data, (bytes, bytearray, memoryview)) or bytes(data[:4]) not in (
                b"\x89HDF", b"CDF\x01", b"CDF\x02"):
            raise ValueError(f"point {key}: the result carries no netCDF file")
        _atomic_write_bytes(point_path(points_dir, key), bytes(data))
        failed_path(points_dir, key).unlink(missing_ok=True)
    else:
        stored = {k: v for k, v in record.items() if k not in _PER_CALL}
        _atomic_write_text(failed_path(points_dir, key),
                           json.dumps(stored, indent=1, sort_keys=True))
    return record


def _simulate_point(params: RunParams, key: str, store_ok, store_failed) -> dict:
    """Simulate one point; ``store_ok(dataset)`` or ``store_failed(record)`` keeps the outcome.
    Any exception (of the solver or of ``store_ok``) becomes a failed record."""
    global _points_run_in_this_process
    from sweep.cluster import jit_counts

    first = _points_run_in_this_process == 0
    _points_run_in_this_process += 1
    jit_before = jit_counts()
    t0 = time.perf_counter()
    try:
        from airpuff_core import simulate

        result = simulate(params)
        ds = result.to_dataset()
        wall = time.perf_counter() - t0
        ds.attrs["sweep_point_key"] = key
        ds.attrs["wall_time_s"] = wall
        store_ok(ds)
        record = {"key": key, "status": "ok", "message": _notes_message(result.metric_notes),
                  "metrics": _json_safe(result.metrics), "wall_s": wall}
    except Exception as err:  # noqa: BLE001 - every failure is recorded, the worker lives on
        wall = time.perf_counter() - t0
        record = _failure_record(key, params, err, wall)
        store_failed(record)
    jit_after = jit_counts()
    record.update(computed=True, params=params.to_dict(), pid=os.getpid(), first_in_process=first,
                  jit_compiled=_delta(jit_before, jit_after, 1),
                  jit_loaded=_delta(jit_before, jit_after, 0))
    return record


def _delta(before: dict, after: dict, which: int) -> int:
    return int(sum(v[which] - before.get(k, (0, 0))[which] for k, v in after.items()))


def _failure_record(key: str, params: RunParams, err: BaseException, wall: float) -> dict:
    from airpuff_core.errors import SimulationError

    if isinstance(err, SimulationError):
        message = str(err)
    else:  # not the solver's own verdict: name the exception type so a bug is recognisable
        message = f"{type(err).__name__}: {err}"
    message = " ".join(message.split()) or type(err).__name__  # one line
    return {"key": key, "status": "failed", "message": message,
            "error_type": type(err).__name__,
            "time_ms": None if getattr(err, "time_ms", None) is None else float(err.time_ms),
            "reason": None if getattr(err, "reason", None) is None else str(err.reason),
            "metrics": {name: None for name in METRICS}, "wall_s": wall,
            "params": params.to_dict(), "software_version": __version__}


def failure_from_exception(points_dir: str | os.PathLike, params: RunParams, err: BaseException) -> dict:
    """Record (and store) a point whose task died outside ``run_point``'s own error handling,
    e.g. ``KilledWorker``: the point crashed worker processes repeatedly.  Called by the runner."""
    key = point_key(params)
    record = _failure_record(key, params, err, float("nan"))
    record["message"] = f"the task could not complete: {record['message']}"
    record["wall_s"] = None
    _atomic_write_text(failed_path(points_dir, key), json.dumps(record, indent=1, sort_keys=True))
    record.update(computed=True, pid=None, first_in_process=False, jit_compiled=0, jit_loaded=0)
    return record


def _notes_message(notes: dict[str, str]) -> str:
    """One line from the reasons why metrics are missing (empty if all are present)."""
    by_reason: dict[str, list[str]] = {}
    for name, note in (notes or {}).items():
        if note:
            by_reason.setdefault(" ".join(str(note).split()), []).append(name)
    return "; ".join(f"{', '.join(names)}: {reason}" for reason, names in by_reason.items())


def read_point(points_dir: str | os.PathLike, key: str) -> dict | None:
    """The stored record of a point (same fields as ``run_point`` returns, minus the per-call
    ones), or None if the point has not been run.  A finished point wins over a failure record."""
    path = point_path(points_dir, key)
    if path.exists():
        with xr.open_dataset(path, engine="netcdf4") as ds:
            metrics = {name: float(ds[name].values) for name in METRICS if name in ds}
            notes = {name: ds[name].attrs.get("comment", "") for name in METRICS if name in ds}
            params = json.loads(ds.attrs["parameters_json"])
            wall = float(ds.attrs.get("wall_time_s", float("nan")))
        return {"key": key, "status": "ok", "message": _notes_message(notes),
                "metrics": _json_safe(metrics), "wall_s": wall, "params": params}
    fpath = failed_path(points_dir, key)
    if fpath.exists():
        return json.loads(fpath.read_text())
    return None


# -- the combined file (client side) --------------------------------------------------------------
def _common_time(times: list[np.ndarray]) -> np.ndarray:
    """One time axis for all points [ms].  Runs of one sweep share t_end and the output
    interval, so normally all axes are identical and that axis is used.  Otherwise (a solver
    that stores its own steps, or a point file from another software version) the axis reaching
    furthest is used, and the other series are interpolated onto it, NaN beyond their ends."""
    if not times:
        return np.zeros(0)
    first = times[0]
    if all(t.shape == first.shape and np.array_equal(t, first) for t in times):
        return first
    return max(times, key=lambda t: (t[-1] if t.size else -np.inf, t.size))


def _on_axis(t: np.ndarray, y: np.ndarray, time: np.ndarray) -> np.ndarray:
    if t.shape == time.shape and np.array_equal(t, time):
        return y
    return np.interp(time, t, y, left=np.nan, right=np.nan)


def combine(spec, points_dir: str | os.PathLike) -> xr.Dataset:
    """The combined dataset of a sweep (SPEC section 7), built from the point files.

    Dimensions ``E0, IOP, thickness, pmax`` (coordinates in MPa, mmHg, mm, kPa) and ``time`` [ms].
    Variables: every metric of ``airpuff_core.result.METRICS`` (NaN where missing or failed),
    ``status`` ("ok", "failed", or "missing" for a point not run yet -- a file combined after an
    interruption), ``message`` (why a point failed, or why some of its metrics are missing),
    ``point_key`` (the per-point file with the shapes and fluid fields is
    ``<points_dir>/<point_key>.nc``, named in the ``point_files`` attribute), ``wall_time`` [s], and the histories ``apex_displacement`` and
    ``jet_pressure_apex`` on the common ``time`` axis.  The non-swept run options are scalar
    coordinates (numbers, with units) and global attributes (all of them, as JSON too).
    """
    spec.validate()
    points_dir = Path(points_dir)
    shape = spec.shape
    metrics = {name: np.full(shape, np.nan) for name in METRICS}
    status = np.full(shape, "missing", dtype=object)
    message = np.full(shape, "not run yet", dtype=object)
    keys = np.full(shape, "", dtype=object)
    wall = np.full(shape, np.nan)
    series: dict[tuple, tuple[np.ndarray, dict[str, np.ndarray]]] = {}
    hist_attrs: dict[str, dict] = {}

    for params in spec.points():
        idx = spec.index_of(params)
        key = point_key(params)
        keys[idx] = key
        path = point_path(points_dir, key)
        if path.exists():
            with open_dataset(path, engine="netcdf4") as ds:
                ds = ds.load()
            status[idx] = "ok"
            message[idx] = _notes_message({m: ds[m].attrs.get("comment", "") for m in METRICS if m in ds})
            for name in METRICS:
                if name in ds:
                    metrics[name][idx] = float(ds[name].values)
            wall[idx] = float(ds.attrs.get("wall_time_s", np.nan))
            series[idx] = (np.asarray(ds["time"].values, float),
                           {h: np.asarray(ds[h].values, float) for h in SWEEP_HISTORIES})
            for h in SWEEP_HISTORIES:
                hist_attrs.setdefault(h, {k: v for k, v in ds[h].attrs.items()
                                          if k in ("units", "long_name")})
            continue
        rec = read_point(points_dir, key)
        if rec is not None:  # a failure record
            status[idx] = rec["status"]
            message[idx] = rec.get("message", "")
            w = rec.get("wall_s")
            wall[idx] = np.nan if w is None else float(w)

    options = spec.run_options()
    time = _common_time([t for t, _ in series.values()])
    hist = {h: np.full(shape + (time.size,), np.nan) for h in SWEEP_HISTORIES}
    for idx, (t, ys) in series.items():
        for h in SWEEP_HISTORIES:
            hist[h][idx] = _on_axis(t, ys[h], time)

    dims = SWEPT
    data_vars: dict[str, Any] = {}
    for name, (unit, long_name) in METRICS.items():
        data_vars[name] = (dims, metrics[name], {"units": unit, "long_name": long_name})
    data_vars["status"] = (dims, status.astype(str),
                           {"long_name": "outcome of the run at this point: ok, failed, or missing "
                                         "(not run yet)"})
    data_vars["message"] = (dims, message.astype(str),
                            {"long_name": "why the point failed, or why some of its metrics are missing"})
    data_vars["point_key"] = (dims, keys.astype(str),
                              {"long_name": "key of the point's own file, <point_key>.nc in the "
                                            "folder of the point_files attribute (shapes and "
                                            "fluid fields)"})
    data_vars["wall_time"] = (dims, wall, {"units": "s", "long_name": "wall time of the run at this point"})
    from airpuff_core.result import HISTORIES

    for h in SWEEP_HISTORIES:
        unit, long_name = HISTORIES[h]
        attrs = {"units": unit, "long_name": long_name, **hist_attrs.get(h, {})}
        data_vars[h] = (dims + ("time",), hist[h], attrs)

    coords: dict[str, Any] = {}
    for name in SWEPT:
        p = PARAMETERS[name]
        coords[name] = (name, np.asarray(getattr(spec, name), float),
                        {"units": p.unit, "long_name": p.description})
    coords["time"] = time_coordinate(time)
    for name, value in options.items():
        if name in PARAMETERS:  # numeric options as scalar coordinates, as in a per-run file
            coords[name] = ((), float(value), {"units": PARAMETERS[name].unit,
                                                "long_name": PARAMETERS[name].description})

    n_ok = int((status == "ok").sum())
    n_failed = int((status == "failed").sum())
    attrs: dict[str, Any] = global_attributes(
        "airpuff parameter sweep: corneal air-puff test over E0, IOP, thickness, pmax",
        "combined by sweep.store.combine from per-point files")
    attrs.update({
        "sweep_json": json.dumps(spec.to_dict(), sort_keys=True),
        "run_options_json": json.dumps(options, sort_keys=True),
        "n_points": spec.n_points,
        "n_ok": n_ok,
        "n_failed": n_failed,
        "n_missing": spec.n_points - n_ok - n_failed,
        "point_files": str(points_dir / "<point_key>.nc"),
    })
    for name, value in options.items():
        attrs[f"param_{name}"] = value
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)


def write_sweep(spec, points_dir: str | os.PathLike, path: str | os.PathLike) -> Path:
    """Combine the point files of ``spec`` and write ``path`` atomically (temp file + rename)."""
    from airpuff_core.dataset import write_netcdf

    ds = combine(spec, points_dir)
    with process_local_write_lock():
        return write_netcdf(ds, path)


def write_spec(spec, out_dir: str | os.PathLike) -> Path:
    """Record the sweep's definition next to its results (``DIR/sweep.json``)."""
    path = Path(out_dir) / SPEC_FILE
    _atomic_write_text(path, json.dumps(spec.to_dict(), indent=1, sort_keys=True) + "\n")
    return path
