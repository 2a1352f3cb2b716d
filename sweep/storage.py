"""Where the results of a sweep live: point keys, file names, atomic writes, point records.

Layout of a sweep folder ``DIR``::

    DIR/sweep.json                the SweepSpec (user units), written when the sweep starts
    DIR/points/<key>.nc           a finished point: the per-run netCDF (docs/model.md, section 7)
    DIR/points/<key>.failed.json  a failed point: parameters, reason, error type
    DIR/sweep.nc                  the combined file (dims E0, IOP, thickness, pmax): sweep.combine

Why one file per point: netCDF4/HDF5 cannot take writes from several processes into one file
(measured: 65 % of concurrent appends fail), so each point file is written to a temporary name
and renamed into place (atomic on POSIX), and only one process combines.  A point file that
exists is therefore complete, which is what makes resuming safe: a point is done iff its file
exists, and it is never rewritten.

The key of a point (:func:`point_key`) is a hash of its full parameter set, so identical
parameters always map to the same file, whichever sweep or job asked for them.  It is computed
once per point, where the point enters the system (``sweep.runner`` or the API's ``POST
/sweeps``), and passed along with the point from there on.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import xarray as xr

from airpuff_core.result import METRICS

POINTS_SUBDIR = "points"
SWEEP_FILE = "sweep.nc"
SPEC_FILE = "sweep.json"

# Fields of a record that describe one call (which process, Numba activity), not the point.
PER_CALL_FIELDS = ("computed", "pid", "first_in_process", "jit_compiled", "jit_loaded")

# The first bytes of a netCDF file: HDF5 (netCDF-4) or classic netCDF (CDF1 / CDF2).
NETCDF_MAGIC = (b"\x89HDF", b"CDF\x01", b"CDF\x02")


# -- names ---------------------------------------------------------------------------------------
# Run options added after points were first stored, with the value that reproduces the runs made
# before them.  While an option holds that value it is left out of the key, so stored points keep
# their keys; any other value enters the key.
KEY_NEUTRAL = {"model": "paper", "cornea": "membrane", "limbus": "clamped",
               "hyperviscosity_operator": "brookshaw", "globe": "rigid", "ocular_rigidity": 0.0126,
               "ve_g": 0.0, "ve_tau": 10.0}


def point_key(params) -> str:
    """Stable identifier of a parameter set (a ``RunParams``): first 16 hex digits of the
    SHA-256 of the sorted JSON of ``params.to_dict()`` without the options of ``KEY_NEUTRAL``
    that hold their neutral value.  Identical parameters give identical keys in any process."""
    values = {k: v for k, v in params.to_dict().items()
              if not (k in KEY_NEUTRAL and v == KEY_NEUTRAL[k])}
    text = json.dumps(values, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def point_path(points_dir: str | os.PathLike, key: str) -> Path:
    """File of a finished point: ``points_dir/<key>.nc``."""
    return Path(points_dir) / f"{key}.nc"


def failed_path(points_dir: str | os.PathLike, key: str) -> Path:
    """Record of a failed point: ``points_dir/<key>.failed.json``."""
    return Path(points_dir) / f"{key}.failed.json"


# -- atomic writes -------------------------------------------------------------------------------
def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to a temporary file in the same folder, then rename: readers never see half
    a file.  (Datasets are written by ``airpuff_core.dataset.write_netcdf``, which does the same.)"""
    path = Path(path)
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
    return path


def write_json(path: str | os.PathLike, record: dict) -> Path:
    """``record`` as indented, key-sorted JSON, written atomically."""
    return atomic_write_bytes(path, (json.dumps(record, indent=1, sort_keys=True) + "\n").encode())


@contextlib.contextmanager
def process_local_write_lock():
    """Make xarray guard a netCDF write with a lock of this process only.

    xarray picks the write lock after the active Dask scheduler; inside a worker (or in a process
    holding a Client) that is a ``distributed.Lock`` kept by the scheduler: a network round trip
    per file, and an exception ("ConnectionPool is closed") if the cluster shuts down during the
    write -- after Ctrl-C that would be recorded as a failure of the point.  Every file here has
    exactly one writer (the point's task, or the combining process), so a process-local lock is
    the right one.
    """
    import dask

    with dask.config.set(scheduler="synchronous"):
        yield


def write_dataset(ds: xr.Dataset, path: str | os.PathLike) -> Path:
    """Write a dataset atomically with the project's one netCDF writer, under a process lock."""
    from airpuff_core.dataset import write_netcdf

    with process_local_write_lock():
        return write_netcdf(ds, path)


# -- point records -------------------------------------------------------------------------------
def json_safe_metrics(metrics: dict[str, Any]) -> dict[str, float | None]:
    """Every metric of ``METRICS`` as a float, or None where missing or not finite."""
    out = {}
    for name in METRICS:
        v = metrics.get(name)
        out[name] = None if v is None or not math.isfinite(float(v)) else float(v)
    return out


def notes_message(notes: dict[str, str]) -> str:
    """One line from the reasons why metrics are missing (empty if all are present)."""
    by_reason: dict[str, list[str]] = {}
    for name, note in (notes or {}).items():
        if note:
            by_reason.setdefault(" ".join(str(note).split()), []).append(name)
    return "; ".join(f"{', '.join(names)}: {reason}" for reason, names in by_reason.items())


def write_failure(points_dir: str | os.PathLike, key: str, record: dict) -> Path:
    """Store the failure record of a point (without the per-call fields)."""
    stored = {k: v for k, v in record.items() if k not in PER_CALL_FIELDS}
    return write_json(failed_path(points_dir, key), stored)


def save_point(points_dir: str | os.PathLike, key: str, record: dict,
               data: bytes | None = None) -> dict:
    """Store a point's outcome under ``key`` in ``points_dir``: the netCDF bytes ``data``
    atomically at ``point_path`` if the point is ok (any older failure record is removed), else
    the failure record at ``failed_path``.  Returns the record.  ``key`` is the caller's, so the
    file lands where the caller will look for it."""
    if record.get("status") == "ok":
        if not isinstance(data, (bytes, bytearray, memoryview)) or bytes(data[:4]) not in NETCDF_MAGIC:
            raise ValueError(f"point {key}: the result carries no netCDF file")
        atomic_write_bytes(point_path(points_dir, key), bytes(data))
        failed_path(points_dir, key).unlink(missing_ok=True)
    else:
        write_failure(points_dir, key, record)
    return record


def read_point(points_dir: str | os.PathLike, key: str) -> dict | None:
    """The stored record of a point (same fields as ``sweep.worker.run_point`` returns, minus the
    per-call ones), or None if the point has not been run.  A finished point wins over a failure
    record."""
    path = point_path(points_dir, key)
    if path.exists():
        with xr.open_dataset(path, engine="netcdf4") as ds:
            metrics = {name: float(ds[name].values) for name in METRICS if name in ds}
            notes = {name: ds[name].attrs.get("comment", "") for name in METRICS if name in ds}
            params = json.loads(ds.attrs["parameters_json"])
            wall = float(ds.attrs.get("wall_time_s", float("nan")))
        return {"key": key, "status": "ok", "message": notes_message(notes),
                "metrics": json_safe_metrics(metrics), "wall_s": wall, "params": params}
    fpath = failed_path(points_dir, key)
    if fpath.exists():
        return json.loads(fpath.read_text())
    return None


def write_spec(spec, out_dir: str | os.PathLike) -> Path:
    """Record the sweep's definition next to its results (``DIR/sweep.json``)."""
    return write_json(Path(out_dir) / SPEC_FILE, spec.to_dict())
