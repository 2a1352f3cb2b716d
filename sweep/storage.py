"""Where the results of a sweep live: point keys, file names, atomic writes, point records.

Layout of a sweep folder ``DIR``::

    DIR/sweep.json                the SweepSpec (user units), written when the sweep starts
    DIR/points/<key>.nc           a finished point: the per-run netCDF (docs/model.md, section 7)
    DIR/points/<key>.failed.json  a failed point: parameters, reason, error type, kind of failure
    DIR/points/damaged/           point files that could not be read, moved aside, each with a
                                  record of why (<key>.<time>.nc and <key>.<time>.json)
    DIR/sweep.nc                  the combined file (dims E0, IOP, thickness, pmax): sweep.combine

Why one file per point: netCDF4/HDF5 cannot take writes from several processes into one file
(measured: 65 % of concurrent appends fail), so each point file is written to a temporary name
and renamed into place (``airpuff_core.atomic``), and only one process combines.  A point file
that exists was therefore complete when written; one that can no longer be read (a disk that
filled up, a file truncated or overwritten afterwards) or that another model version wrote
counts as missing: :func:`open_point` moves it aside to ``damaged/`` with a record, and the point
is computed again.  A stored point is never rewritten in place.

The key of a point (:func:`point_key`) is a hash of its full parameter set and of the model
version (``airpuff_core.provenance.model_version``, a hash of the numerical source code), so
identical parameters map to the same file, whichever sweep or job asked for them, as long as
the solver is the same; a changed solver computes its points anew.  The key is computed once
per point, where the point enters the system (``sweep.runner`` or the API's ``POST /sweeps``),
and passed along with the point from there on.

A point's record is a ``sweep.record.PointRecord``; a failure record says which kind of failure it
was (``model`` or ``infrastructure``), which decides whether it is reused (:func:`reusable`).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import math
import os
import re
import time
from pathlib import Path
from typing import Any

import xarray as xr

from airpuff_core.atomic import atomic_write
from airpuff_core.dataset import open_dataset
from airpuff_core.provenance import model_version
from airpuff_core.result import METRICS

from .record import PointRecord

POINTS_SUBDIR = "points"
DAMAGED_SUBDIR = "damaged"
SWEEP_FILE = "sweep.nc"
SPEC_FILE = "sweep.json"

# Automatic re-runs of a point whose failure is the infrastructure's (a lost worker, a write
# error), after the first attempt (``sweep.engine``).
INFRASTRUCTURE_RETRIES = 2

# The first bytes of a netCDF file: HDF5 (netCDF-4) or classic netCDF (CDF1 / CDF2).
NETCDF_MAGIC = (b"\x89HDF", b"CDF\x01", b"CDF\x02")


# -- names ---------------------------------------------------------------------------------------
def point_key(params) -> str:
    """Stable identifier of a parameter set (a ``RunParams``) computed by this model: first 16
    hex digits of the SHA-256 of the sorted JSON of ``params.to_dict()`` and the model version.
    Identical parameters give identical keys in any process running the same solver code."""
    text = json.dumps({"parameters": params.to_dict(), "model_version": model_version()},
                      sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def point_path(points_dir: str | os.PathLike, key: str) -> Path:
    """File of a finished point: ``points_dir/<key>.nc``."""
    return Path(points_dir) / f"{key}.nc"


def failed_path(points_dir: str | os.PathLike, key: str) -> Path:
    """Record of a failed point: ``points_dir/<key>.failed.json``."""
    return Path(points_dir) / f"{key}.failed.json"


# -- writes --------------------------------------------------------------------------------------
def write_json(path: str | os.PathLike, record: dict) -> Path:
    """``record`` as indented, key-sorted JSON, written atomically."""
    text = json.dumps(record, indent=1, sort_keys=True) + "\n"
    return atomic_write(path, lambda tmp: tmp.write_text(text))


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


def disk_full(err: BaseException) -> bool:
    """Whether ``err`` says the disk is full: ENOSPC (or EDQUOT, a quota), SQLite's "database
    or disk is full", or HDF5's "No space left on device" in the message of a netCDF write."""
    if isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    text = str(err)
    return "No space left on device" in text or "disk is full" in text


NO_SPACE = "no space left on the device (ENOSPC)"


# -- point records -------------------------------------------------------------------------------
def json_safe_metrics(metrics: dict[str, Any]) -> dict[str, float | None]:
    """Every metric of ``METRICS`` as a float, or None where missing or not finite."""
    out = {}
    for name in METRICS:
        v = metrics.get(name)
        out[name] = None if v is None or not math.isfinite(float(v)) else float(v)
    return out


# An absolute path in a message (at least two components): a server's layout is nobody's business.
_ABSOLUTE_PATH = re.compile(r"(?<![\w.~-])/(?:[^\s'\"/:]+/)+([^\s'\"/:]*)")


def one_line_message(text: str) -> str:
    """``text`` on one line, each absolute path shortened to ``.../<last component>``: messages
    of points and jobs are shown to clients and stored in shared files."""
    return " ".join(_ABSOLUTE_PATH.sub(r".../\1", str(text)).split())


def notes_message(notes: dict[str, str]) -> str:
    """One line from the reasons why metrics are missing (empty if all are present)."""
    by_reason: dict[str, list[str]] = {}
    for name, note in (notes or {}).items():
        if note:
            by_reason.setdefault(" ".join(str(note).split()), []).append(name)
    return "; ".join(f"{', '.join(names)}: {reason}" for reason, names in by_reason.items())


def write_failure(points_dir: str | os.PathLike, key: str, record: PointRecord) -> Path:
    """Store the failure record of a point (its stored form: without the per-call fields)."""
    return write_json(failed_path(points_dir, key), record.stored())


def save_point(points_dir: str | os.PathLike, key: str, record: PointRecord,
               data: bytes | None = None) -> PointRecord:
    """Store a point's outcome under ``key`` in ``points_dir``: the netCDF bytes ``data``
    atomically at ``point_path`` if the point is ok (any older failure record is removed), else
    the failure record at ``failed_path``.  Returns the record.  ``key`` is the caller's, so the
    file lands where the caller will look for it."""
    if record.ok:
        if not isinstance(data, (bytes, bytearray, memoryview)) or bytes(data[:4]) not in NETCDF_MAGIC:
            raise ValueError(f"point {key}: the result carries no netCDF file")
        atomic_write(point_path(points_dir, key), lambda tmp: tmp.write_bytes(bytes(data)))
        failed_path(points_dir, key).unlink(missing_ok=True)
    else:
        write_failure(points_dir, key, record)
    return record


def reusable(record: PointRecord | None, retry_failed: bool = False) -> bool:
    """Whether a stored record stands instead of computing the point: a finished point always; a
    failure of the model unless ``retry_failed``; a failure of the infrastructure never."""
    if record is None:
        return False
    if record.ok:
        return True
    return record.failure_kind() == "model" and not retry_failed


def set_aside(points_dir: str | os.PathLike, key: str, path: Path, reason: str) -> Path | None:
    """Move an unreadable point file (or failure record) ``path`` to ``points_dir/damaged/``,
    next to a JSON record of why; returns the new path (None if the file had gone already)."""
    damaged = Path(points_dir) / DAMAGED_SUBDIR
    damaged.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime()) + f"-{time.time_ns() % 10**9:09d}"
    target = damaged / f"{path.name}.{stamp}"
    try:
        size = path.stat().st_size
        os.replace(path, target)
    except FileNotFoundError:  # set aside by another reader meanwhile
        return None
    write_json(damaged / f"{path.name}.{stamp}.json",
               {"key": key, "file": path.name, "moved_to": target.name, "size_bytes": size,
                "reason": one_line_message(reason), "moved_at": stamp})
    import logging

    logging.getLogger("airpuff.storage").warning(
        "point %s: %s could not be used (%s); moved to %s/%s, it will be computed again",
        key, path.name, one_line_message(reason), DAMAGED_SUBDIR, target.name)
    return target


def open_point(points_dir: str | os.PathLike, key: str, full: bool = True) -> xr.Dataset | None:
    """The finished point ``key`` as a dataset in memory, or None if it has no file, or if its
    file cannot be read or was made by another model version: such a file is moved aside
    (:func:`set_aside`) and the point counts as missing.  ``full``: read every variable (what
    combining does; damage anywhere in the file shows); otherwise the metrics and attributes
    only (a truncated or overwritten file shows already when it is opened), which is what
    deciding to reuse a point costs for each point of a new sweep."""
    path = point_path(points_dir, key)
    if not path.is_file():  # nothing (or something that is not a file: it is not set aside)
        return None
    try:
        with open_dataset(path, engine="netcdf4") as ds:
            missing = [name for name in METRICS if name not in ds]
            if missing:
                raise ValueError(f"no variable {missing[0]}")
            ds = ds.load() if full else ds[list(METRICS)].load()
        json.loads(ds.attrs["parameters_json"])
    except Exception as err:  # noqa: BLE001 - any reason to distrust the file: set it aside
        set_aside(points_dir, key, path, f"unreadable: {type(err).__name__}: {err}")
        return None
    found = ds.attrs.get("model_version")
    if found != model_version():
        set_aside(points_dir, key, path, f"made by model version {found or 'unknown'}, not "
                                         f"{model_version()}")
        return None
    return ds


def read_point(points_dir: str | os.PathLike, key: str) -> PointRecord | None:
    """The stored record of a point (``computed`` False), or None if the point has not been run
    or its file is unusable (moved aside by :func:`open_point`).  A finished point wins over a
    failure record."""
    ds = open_point(points_dir, key, full=False)
    if ds is not None:
        metrics = {name: float(ds[name].values) for name in METRICS}
        notes = {name: ds[name].attrs.get("comment", "") for name in METRICS}
        return PointRecord(key=key, status="ok", message=notes_message(notes),
                           metrics=json_safe_metrics(metrics),
                           wall_s=float(ds.attrs.get("wall_time_s", float("nan"))),
                           params=json.loads(ds.attrs["parameters_json"]),
                           model_version=ds.attrs.get("model_version"), computed=False)
    fpath = failed_path(points_dir, key)
    if fpath.is_file():
        try:
            stored = json.loads(fpath.read_text())
            if not isinstance(stored, dict) or stored.get("status") != "failed":
                raise ValueError("not a failure record")
            return PointRecord.from_dict({"key": key, **stored}, computed=False)
        except (ValueError, TypeError, UnicodeDecodeError) as err:
            set_aside(points_dir, key, fpath, f"unreadable: {type(err).__name__}: {err}")
            return None
    return None


def write_spec(spec, out_dir: str | os.PathLike) -> Path:
    """Record the sweep's definition next to its results (``DIR/sweep.json``)."""
    return write_json(Path(out_dir) / SPEC_FILE, spec.to_dict())
