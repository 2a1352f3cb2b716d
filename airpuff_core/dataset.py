"""netCDF files: atomic writing, the parameters a file was made with, and the CF attributes every
file of the project shares (run, sweep point, ``sweep.nc``).

The run's dataset itself is made by ``RunResult.to_dataset`` (``result.py``); its run parameters
are scalar coordinates and global attributes, the full set as the JSON attribute
``parameters_json``.

CF-1.10 (checked with the IOOS compliance-checker, ``tools/cf_check.py``): a coordinate named
``time`` is a CF time coordinate, so its units are ``milliseconds since <reference>``.  The
simulated puff has no calendar date: the reference instant ``TIME_REFERENCE`` stands for t = 0, the
start of the run.  ``open_dataset`` keeps ``time`` in milliseconds; plain ``xarray.open_dataset``
decodes it into ``datetime64[ns]`` dates, exactly (``time_coordinate``).
"""

from __future__ import annotations

import json
import os
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import xarray as xr

from .atomic import atomic_write
from .params import RunParams
from .version import __version__

CONVENTIONS = "CF-1.10"
TIME_REFERENCE = "1970-01-01 00:00:00"  # stands for t = 0: a simulation has no calendar date
# "milliseconds", not "ms": xarray decodes "ms since" through cftime, to whole microseconds (a
# run with output_interval 1e-5 ms read back 1,001 distinct times out of 100,001), and
# "milliseconds since" with pandas, to nanoseconds.
TIME_UNITS = f"milliseconds since {TIME_REFERENCE}"


def decodable_ms(values_ms) -> np.ndarray:
    """Times [ms] that xarray's default decoding turns into the nearest nanosecond exactly.

    xarray decodes a float time t [ms] as ``int64(t * 1e6)`` nanoseconds: a truncation, so a
    product that falls just below its integer (t = 153 * 0.0137 ms gives 2096099.9999999998 ns)
    loses a whole nanosecond.  Such a t is raised by a few units in its last place (relative
    1e-16) until ``t * 1e6`` is not below round(t * 1e6); every other t is kept bit for bit."""
    t = np.array(values_ms, dtype=float)
    nanoseconds = np.round(t * 1e6)
    for _ in range(16):
        low = t * np.int64(1_000_000) < nanoseconds
        if not low.any():
            break
        t[low] = np.nextafter(t[low], np.inf)
    return t


def time_coordinate(values_ms) -> tuple:
    """The ``time`` coordinate [ms since the start of the run], as CF-1.10 wants a time axis:
    standard_name ``time``, axis ``T``, units ``milliseconds since <reference>`` and a calendar
    (the writer adds no _FillValue to it, ``write_netcdf``); values as ``decodable_ms`` makes
    them."""
    return ("time", decodable_ms(values_ms),
            {"units": TIME_UNITS, "calendar": "proleptic_gregorian", "standard_name": "time",
             "axis": "T", "long_name": "time since the start of the run (the reference date "
                                       "stands for t = 0)"})


def history_entry(action: str) -> str:
    """One line of the CF ``history`` attribute: UTC time stamp, software and version, action."""
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    return f"{stamp} airpuff {__version__}: {action}"


def global_attributes(title: str, action: str) -> dict:
    """The global attributes every file of the project carries (CF-1.10 and provenance)."""
    return {"Conventions": CONVENTIONS, "title": title, "software": "airpuff",
            "software_version": __version__, "history": history_entry(action)}


def open_dataset(path: str | os.PathLike, **kwargs) -> xr.Dataset:
    """``xarray.open_dataset`` for the project's files, with ``time`` kept as numbers [ms]
    (not decoded into dates from its CF reference)."""
    return xr.open_dataset(path, decode_times=False, **kwargs)


def params_from_dataset(ds: xr.Dataset) -> RunParams:
    """The RunParams a dataset was produced with (from its ``parameters_json`` attribute)."""
    return RunParams.from_dict(json.loads(ds.attrs["parameters_json"]))


def write_netcdf(ds: xr.Dataset, path: str | os.PathLike) -> Path:
    """Write ``ds`` to ``path`` atomically (``atomic.atomic_write``: a temporary file in the same
    folder, then a rename), floating-point arrays compressed.

    A reader never sees a half-written file, and a crash leaves at most a stray ``.tmp`` file.
    """
    encoding = {v: {"zlib": True, "complevel": 4} for v in ds.data_vars
                if ds[v].dtype.kind == "f" and ds[v].ndim > 0}
    # CF 2.5.1: a coordinate variable has no missing values, so no _FillValue
    encoding.update({c: {"_FillValue": None} for c in ds.dims if c in ds.coords})
    return atomic_write(path, lambda tmp: ds.to_netcdf(tmp, engine="netcdf4", encoding=encoding))
