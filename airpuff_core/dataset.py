"""netCDF files of runs: atomic writing, and the parameters a file was made with.

The dataset itself is made by ``RunResult.to_dataset`` (``result.py``); its run parameters are
scalar coordinates and global attributes, the full set as the JSON attribute ``parameters_json``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import xarray as xr

from .atomic import atomic_write
from .params import RunParams


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
    return atomic_write(path, lambda tmp: ds.to_netcdf(tmp, engine="netcdf4", encoding=encoding))
