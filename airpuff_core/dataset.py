"""RunResult <-> CF-annotated xarray.Dataset, and atomic netCDF writing.

The names, dimensions and units are the contract of SPEC section 7.  Run parameters are scalar
coordinates (user units, with a ``units`` attribute) and are repeated as global attributes.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np
import xarray as xr

from . import __version__
from .params import CHOICES, PARAMETERS, RunParams
from .result import HISTORIES, METRICS, SNAPSHOT_FIELDS, SNAPSHOT_LABELS, RunResult


def result_to_dataset(result: RunResult) -> xr.Dataset:
    """Build the per-run dataset of SPEC section 7 from a RunResult."""
    data_vars = {}
    for name, (unit, long_name) in HISTORIES.items():
        data_vars[name] = xr.Variable(("time",), np.asarray(result.histories[name], dtype=float),
                                      {"units": unit, "long_name": long_name})
    for name, (dim, unit, long_name) in SNAPSHOT_FIELDS.items():
        data_vars[name] = xr.Variable(("snapshot", dim), np.asarray(result.snapshots[name], float),
                                      {"units": unit, "long_name": long_name})
    for name, (unit, long_name) in METRICS.items():
        attrs = {"units": unit, "long_name": long_name}
        note = result.metric_notes.get(name)
        if note:
            attrs["comment"] = note
        data_vars[name] = xr.Variable((), float(result.metrics.get(name, np.nan)), attrs)

    coords = {
        "time": ("time", np.asarray(result.time, float), {"units": "ms", "long_name": "time"}),
        "snapshot": ("snapshot", np.arange(len(SNAPSHOT_LABELS)), {"long_name": "snapshot index"}),
        "snapshot_label": ("snapshot", np.array(SNAPSHOT_LABELS, dtype=object),
                           {"long_name": "instant of the snapshot"}),
        "snapshot_time": ("snapshot", np.asarray(result.snapshot_time, float),
                          {"units": "ms", "long_name": "time of the snapshot"}),
    }
    p = result.params
    for name, spec in PARAMETERS.items():
        coords[name] = ((), float(getattr(p, name)), {"units": spec.unit, "long_name": spec.description})

    attrs = {
        "Conventions": "CF-1.10",
        "title": "airpuff: coupled membrane / MFPM simulation of the corneal air-puff test",
        "software": "airpuff",
        "software_version": __version__,
        "parameters_json": json.dumps(p.to_dict(), sort_keys=True),
    }
    for name in CHOICES:
        attrs[name] = getattr(p, name)
    for name, spec in PARAMETERS.items():
        attrs[f"param_{name}"] = float(getattr(p, name))
    for k, v in result.diagnostics.items():
        if isinstance(v, (int, float, str, np.integer, np.floating)):
            attrs[f"solver_{k}"] = v if not isinstance(v, np.generic) else v.item()
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)


def params_from_dataset(ds: xr.Dataset) -> RunParams:
    """The RunParams a dataset was produced with (from its ``parameters_json`` attribute)."""
    return RunParams.from_dict(json.loads(ds.attrs["parameters_json"]))


def write_netcdf(ds: xr.Dataset, path: str | os.PathLike) -> Path:
    """Write ``ds`` to ``path`` atomically: a temporary file in the same folder, then a rename.

    A reader never sees a half-written file, and a crash leaves at most a stray ``.tmp`` file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        encoding = {v: {"zlib": True, "complevel": 4} for v in ds.data_vars
                    if ds[v].dtype.kind == "f" and ds[v].ndim > 0}
        ds.to_netcdf(tmp, engine="netcdf4", encoding=encoding)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
