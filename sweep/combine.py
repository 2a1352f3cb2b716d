"""Combining the point files of a sweep into one ``sweep.nc`` (client side, one writer).

The combined file has dimensions ``E0, IOP, thickness, pmax`` (coordinates in MPa, mmHg, mm, kPa)
and ``time`` [ms].  Variables: every metric of ``airpuff_core.result.METRICS`` (NaN where missing
or failed), ``status`` ("ok", "failed", or "missing" for a point not run yet -- a file combined
after an interruption), ``message`` (why a point failed, or why some of its metrics are missing),
``point_key`` (the per-point file with the shapes and fluid fields is ``<points_dir>/<point_key>.nc``,
named in the ``point_files`` attribute relative to the combined file's folder), the calibrated
readings ``<name>_cal`` of ``airpuff_core.calibration.CALIBRATED`` (computed at combine time
from the raw P1 and P2), ``model_version`` and ``provenance`` (per point: the model version, and
the JSON of the provenance attributes of the point's own file: airpuff version, git commit,
library versions), ``wall_time`` [s], and the histories of ``SWEEP_HISTORIES`` on one common
``time`` axis.  The non-swept run options are scalar coordinates (numbers, with units) and global
attributes (all of them, as JSON too).  The
per-point files it refers to are described in docs/model.md, section 7.

A point file that cannot be read (or was made by another model version) is moved aside by
``sweep.storage.open_point``; :func:`combine` then raises :class:`DamagedPointFiles` naming those
points, so that the caller computes them again instead of writing a file with holes.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from airpuff_core.atomic import remove_stale_temp_files
from airpuff_core.calibration import (apply_coefficients, find_calibration, load_calibrations,
                                      nan_readings, variable_attrs)
from airpuff_core.dataset import global_attributes, time_coordinate
from airpuff_core.params import PARAMETERS, SWEPT
from airpuff_core.provenance import PROVENANCE_ATTRS, model_version, provenance
from airpuff_core.result import HISTORIES, METRICS, RAW_READINGS

from .storage import notes_message, open_point, point_key, point_path, read_point, write_dataset

# Temporary files of a combined file older than this are left by a killed process: no combine
# takes this long.
STALE_TEMP_S = 3600.0


class DamagedPointFiles(RuntimeError):
    """Point files of a sweep that could not be used (moved aside): ``keys`` must be computed
    again before the sweep can be combined."""

    def __init__(self, keys: list[str]):
        self.keys = list(keys)
        super().__init__(f"{len(self.keys)} point file(s) could not be read and were moved "
                         f"aside; compute them again: {', '.join(self.keys)}")

# Histories copied into the combined file (the others stay in the per-point files).
SWEEP_HISTORIES = ("apex_displacement", "jet_pressure_apex")


@dataclass
class _Grid:
    """The per-point values of a sweep, as arrays of the grid's shape (filled by :func:`_read`)."""

    shape: tuple[int, ...]
    metrics: dict[str, np.ndarray] = field(init=False)
    status: np.ndarray = field(init=False)
    message: np.ndarray = field(init=False)
    keys: np.ndarray = field(init=False)
    wall: np.ndarray = field(init=False)
    # grid index -> (time [ms], {history name: values}) of each finished point
    series: dict[tuple, tuple[np.ndarray, dict[str, np.ndarray]]] = field(default_factory=dict)
    history_attrs: dict[str, dict] = field(default_factory=dict)

    def __post_init__(self):
        self.metrics = {name: np.full(self.shape, np.nan) for name in METRICS}
        self.status = np.full(self.shape, "missing", dtype=object)
        self.message = np.full(self.shape, "not run yet", dtype=object)
        self.keys = np.full(self.shape, "", dtype=object)
        self.model_version = np.full(self.shape, "", dtype=object)
        self.provenance = np.full(self.shape, "", dtype=object)
        self.damaged: list[str] = []
        self.wall = np.full(self.shape, np.nan)


def combine(spec, points_dir: str | os.PathLike, keys: list[str] | None = None,
            point_files: str = "points") -> xr.Dataset:
    """The combined dataset of a sweep (layout in the module docstring), built from the point
    files in ``points_dir``.  ``keys``: the point keys in the C order of ``spec.points()``, as
    the caller computed them when the points entered the system (computed here if None).
    ``point_files``: the points folder as the ``point_files`` attribute names it (relative to
    the combined file: no path of this machine goes into a file that is shared)."""
    points_dir = Path(points_dir)
    grid = _read(spec, points_dir, keys)
    if grid.damaged:
        raise DamagedPointFiles(grid.damaged)
    time_axis = _common_time([t for t, _ in grid.series.values()])
    data_vars = _data_vars(grid, time_axis)
    data_vars.update(_calibrated_vars(spec, grid))
    return xr.Dataset(data_vars, coords=_coords(spec, time_axis),
                      attrs=_attrs(spec, grid, point_files))


def write_sweep(spec, points_dir: str | os.PathLike, path: str | os.PathLike,
                keys: list[str] | None = None) -> Path:
    """Combine the point files of ``spec`` and write ``path`` atomically (temp file + rename).
    Temporary files of earlier combines killed midway are removed first.  Raises
    :class:`DamagedPointFiles` if point files had to be moved aside."""
    path = Path(path)
    remove_stale_temp_files(path.parent, STALE_TEMP_S)
    point_files = os.path.relpath(Path(points_dir).resolve(), path.parent.resolve())
    return write_dataset(combine(spec, points_dir, keys, point_files), path)


def _read(spec, points_dir: Path, keys: list[str] | None) -> _Grid:
    """Read every point of ``spec``: a point file, a failure record, or nothing yet."""
    grid = _Grid(spec.shape)
    if keys is None:
        keys = [point_key(p) for p in spec.points()]
    for idx, key in zip(np.ndindex(*spec.shape), keys):  # C order, as spec.points()
        grid.keys[idx] = key
        if point_path(points_dir, key).is_file():
            ds = open_point(points_dir, key)  # None: unusable, moved aside
            if ds is None:
                grid.damaged.append(key)
            else:
                _read_point_file(grid, idx, ds)
            continue
        record = read_point(points_dir, key)
        if record is not None:  # a failure record
            grid.status[idx] = record.status
            grid.message[idx] = record.message
            grid.wall[idx] = np.nan if record.wall_s is None else float(record.wall_s)
    return grid


def _read_point_file(grid: _Grid, idx: tuple, ds: xr.Dataset) -> None:
    grid.status[idx] = "ok"
    grid.model_version[idx] = str(ds.attrs.get("model_version", ""))
    grid.provenance[idx] = json.dumps({k: str(ds.attrs[k]) for k in PROVENANCE_ATTRS
                                       if k in ds.attrs}, sort_keys=True)
    grid.message[idx] = notes_message({m: ds[m].attrs.get("comment", "") for m in METRICS if m in ds})
    for name in METRICS:
        if name in ds:
            grid.metrics[name][idx] = float(ds[name].values)
    grid.wall[idx] = float(ds.attrs.get("wall_time_s", np.nan))
    grid.series[idx] = (np.asarray(ds["time"].values, float),
                        {h: np.asarray(ds[h].values, float) for h in SWEEP_HISTORIES})
    for h in SWEEP_HISTORIES:
        grid.history_attrs.setdefault(h, {k: v for k, v in ds[h].attrs.items()
                                          if k in ("units", "long_name")})


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


def _on_axis(t: np.ndarray, y: np.ndarray, time_axis: np.ndarray) -> np.ndarray:
    if t.shape == time_axis.shape and np.array_equal(t, time_axis):
        return y
    return np.interp(time_axis, t, y, left=np.nan, right=np.nan)


def _data_vars(grid: _Grid, time_axis: np.ndarray) -> dict[str, Any]:
    dims = SWEPT
    data_vars: dict[str, Any] = {}
    for name, (unit, long_name) in METRICS.items():
        attrs = {"units": unit, "long_name": long_name}
        if name in RAW_READINGS:
            attrs["calibration"] = "raw"
        data_vars[name] = (dims, grid.metrics[name], attrs)
    data_vars["status"] = (dims, grid.status.astype(str),
                           {"long_name": "outcome of the run at this point: ok, failed, or missing "
                                         "(not run yet)"})
    data_vars["message"] = (dims, grid.message.astype(str),
                            {"long_name": "why the point failed, or why some of its metrics are missing"})
    data_vars["point_key"] = (dims, grid.keys.astype(str),
                              {"long_name": "key of the point's own file, <point_key>.nc in the "
                                            "folder of the point_files attribute (shapes and "
                                            "fluid fields)"})
    data_vars["model_version"] = (dims, grid.model_version.astype(str),
                                  {"long_name": "model version (hash of the numerical source "
                                                "code) that computed the point"})
    data_vars["provenance"] = (dims, grid.provenance.astype(str),
                               {"long_name": "provenance of the point's own file as JSON: airpuff, "
                                             "model and library versions, git commit"})
    data_vars["wall_time"] = (dims, grid.wall, {"units": "s", "long_name": "wall time of the run at this point"})
    for h in SWEEP_HISTORIES:
        values = np.full(grid.shape + (time_axis.size,), np.nan)
        for idx, (t, ys) in grid.series.items():
            values[idx] = _on_axis(t, ys[h], time_axis)
        unit, long_name = HISTORIES[h]
        attrs = {"units": unit, "long_name": long_name, **grid.history_attrs.get(h, {})}
        data_vars[h] = (dims + ("time",), values, attrs)
    return data_vars


def _calibrated_vars(spec, grid: _Grid) -> dict[str, Any]:
    """The calibrated readings of every point (``airpuff_core.calibration``), computed now from
    the raw P1 and P2 with the calibrations of this installation (not read from the point files,
    which may predate the calibration).  The points of a sweep differ in E0, IOP, thickness
    (the eye: one calibration for all) and pmax (the instrument: one calibration each)."""
    calibrations = load_calibrations()
    values = nan_readings(grid.shape)
    labels, reasons = set(), set()
    for idx, params in zip(np.ndindex(*grid.shape), spec.points()):
        version = grid.model_version[idx] or model_version()
        cal, reason = find_calibration(params.to_dict(), version, calibrations)
        if cal is None:
            reasons.add(reason)
            continue
        labels.add(cal.label)
        point = apply_coefficients(cal.coefficients(), grid.metrics["P1"][idx],
                                   grid.metrics["P2"][idx])
        for name, v in point.items():
            values[name][idx] = v
    data_vars = {}
    for name, array in values.items():
        attrs = variable_attrs(name, None, "; ".join(sorted(reasons)))
        attrs["calibration"] = "; ".join(sorted(labels)) or "none"
        if not reasons:
            attrs.pop("comment")
        data_vars[name] = (SWEPT, array, attrs)
    return data_vars


def _coords(spec, time_axis: np.ndarray) -> dict[str, Any]:
    coords: dict[str, Any] = {}
    for name in SWEPT:
        p = PARAMETERS[name]
        coords[name] = (name, np.asarray(getattr(spec, name), float),
                        {"units": p.unit, "long_name": p.description})
    coords["time"] = time_coordinate(time_axis)
    for name, value in spec.run_options().items():
        if name in PARAMETERS:  # numeric options as scalar coordinates, as in a per-run file
            coords[name] = ((), float(value), {"units": PARAMETERS[name].unit,
                                                "long_name": PARAMETERS[name].description})
    return coords


def _attrs(spec, grid: _Grid, point_files: str) -> dict[str, Any]:
    options = spec.run_options()
    n_ok = int((grid.status == "ok").sum())
    n_failed = int((grid.status == "failed").sum())
    attrs: dict[str, Any] = global_attributes(
        "airpuff parameter sweep: corneal air-puff test over E0, IOP, thickness, pmax",
        "combined by sweep.combine from per-point files")
    attrs.update(provenance())  # of the combining process; each point's own: variable provenance
    attrs.update({
        "sweep_json": json.dumps(spec.to_dict(), sort_keys=True),
        "run_options_json": json.dumps(options, sort_keys=True),
        "n_points": spec.n_points,
        "n_ok": n_ok,
        "n_failed": n_failed,
        "n_missing": spec.n_points - n_ok - n_failed,
        "point_files": str(Path(point_files) / "<point_key>.nc"),
    })
    for name, value in options.items():
        attrs[f"param_{name}"] = value
    return attrs

