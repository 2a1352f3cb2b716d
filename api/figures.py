"""The figures of a job's page, drawn by the server as PNG from the stored results.

- ``ora-<metric>``: an ORA metric (P1, P2, CH, IOPg, IOPcc) against IOP, one line per E0, from
  the job's point records in the database (``api.jobs.point_records``); when the points have a
  calibration, also the calibrated IOPg_cal (with the line where it equals the true IOP) and
  CH_cal;
- ``heatmap-<metric>``: DA and CH over the (IOP, E0) grid, when it has at least two values of each;
- ``history-<index>``: apex displacement and jet pressure against time of one point, from the
  point's own netCDF file.

Lines and heat maps are drawn at one thickness and one pmax: the first value of each axis.

A finished job's figures never change, so they are drawn once and kept next to the job's results
(``DATA_DIR/jobs/<id>/figures/<name>.png``); a point's history comes from its immutable point file
and is kept in the same folder.  While the job runs, the line and heat-map figures are drawn on
each request from the current records.

Why the history is drawn in a child process (``python -m api.figures POINT.nc OUT.png``): the
API process must not open netCDF files, because netCDF4/HDF5 is not thread-safe and the runner
thread writes them in this process (see ``api.app``).
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import textwrap
import threading
from pathlib import Path
from typing import Any

import numpy as np

from airpuff_core.atomic import TEMP_SUFFIX, atomic_write
from airpuff_core.calibration import CALIBRATED
from airpuff_core.result import METRICS

from .settings import Settings
from .status import ENDED_JOB_STATUSES

ORA_METRICS = ("P1", "P2", "CH", "IOPg", "IOPcc")
# Drawn beside the raw ones when the job's points have a calibration (docs/calibration.md).
CALIBRATED_METRICS = ("IOPg_cal", "CH_cal")
HEATMAP_METRICS = ("DA", "CH")
NAME_RE = re.compile(r"^(ora-(%s)|heatmap-(%s)|history-\d{1,9})$"
                     % ("|".join(ORA_METRICS + CALIBRATED_METRICS), "|".join(HEATMAP_METRICS)))
_DESCRIBED = {**METRICS, **CALIBRATED}  # name -> (unit, long name)
HISTORY_TIMEOUT_S = 120.0
UNREADABLE_EXIT = 3  # exit code of ``python -m api.figures`` when the point file cannot be read
DPI = 100

# Matplotlib's font and text caches are shared by all figures of a process: one drawing at a time.
_draw_lock = threading.Lock()


class FigureUnavailable(LookupError):
    """The figure does not exist for this job (wrong name, too small a grid, no such point)."""


def grid_slice(records: list[dict[str, Any]]) -> tuple[float, float] | None:
    """(thickness [mm], pmax [kPa]) of the lines and heat maps: the first value of each axis."""
    if not records:
        return None
    return records[0]["thickness"], records[0]["pmax"]


def _sliced(records):
    thickness, pmax = grid_slice(records)
    sub = [r for r in records if r["thickness"] == thickness and r["pmax"] == pmax]
    e0 = sorted({r["E0"] for r in sub})
    iop = sorted({r["IOP"] for r in sub})
    return sub, e0, iop


def _table(sub, e0, iop, name) -> np.ndarray:
    """values[i, j] of metric ``name`` at (e0[i], iop[j]); NaN where missing."""
    values = np.full((len(e0), len(iop)), np.nan)
    for r in sub:
        v = r[name]
        if v is not None and math.isfinite(v):
            values[e0.index(r["E0"]), iop.index(r["IOP"])] = v
    return values


def available(records: list[dict[str, Any]]) -> list[str]:
    """Names of the line and heat-map figures this job can show now (one point ok at least;
    heat maps need two E0 and two IOP values)."""
    if not any(r["status"] == "ok" for r in records):
        return []
    names = [f"ora-{m}" for m in ORA_METRICS]
    names += [f"ora-{m}" for m in CALIBRATED_METRICS
              if any(r.get(m) is not None and math.isfinite(r[m]) for r in records)]
    _, e0, iop = _sliced(records)
    if len(e0) >= 2 and len(iop) >= 2:
        names += [f"heatmap-{m}" for m in HEATMAP_METRICS]
    return names


def history_point(records: list[dict[str, Any]], index: int | None) -> dict[str, Any] | None:
    """The point whose history is shown: ``index`` if that point is ok, else the first ok point."""
    ok = [r for r in records if r["status"] == "ok"]
    chosen = [r for r in ok if r["index"] == index]
    return (chosen or ok or [None])[0]


def _label(name: str) -> str:
    return f"{name} [{_DESCRIBED[name][0]}]"


def draw(name: str, records: list[dict[str, Any]]) -> bytes:
    """PNG of the line or heat-map figure ``name`` from the job's point records."""
    from sweep.plots import draw_heatmap, draw_metric_vs_iop, new_figure

    if name not in available(records):
        raise FigureUnavailable(name)
    kind, metric = name.split("-", 1)
    sub, e0, iop = _sliced(records)
    values = _table(sub, e0, iop, metric)
    thickness, pmax = grid_slice(records)
    with _draw_lock:
        fig = new_figure(4.0, 3.0)
        ax = fig.subplots()
        if kind == "ora":
            failed = np.zeros_like(values, bool)
            for r in sub:
                if r["status"] == "failed":
                    failed[e0.index(r["E0"]), iop.index(r["IOP"])] = True
            draw_metric_vs_iop(ax, iop, {v: values[i] for i, v in enumerate(e0)},
                               {v: failed[i] for i, v in enumerate(e0)}, _label(metric))
            if metric == "IOPg_cal":  # where a calibrated reading equals the eye's true IOP
                ax.plot(iop, iop, "--", color="grey", lw=1, label="= true IOP")
            ax.legend(fontsize="x-small")
        else:
            draw_heatmap(fig, ax, iop, e0, values, _label(metric))
        ax.set_title(textwrap.fill(f"{metric}: {_DESCRIBED[metric][1]}", 52)
                     + f"\nthickness {thickness:g} mm, pmax {pmax:g} kPa", fontsize=8)
        return _png(fig)


def _png(fig) -> bytes:
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def cache_path(settings: Settings, job_id: str, name: str) -> Path:
    """Where a figure of a job is kept (``job_id`` comes from the database, ``name`` matches
    NAME_RE: the path stays inside the job's folder)."""
    if not NAME_RE.match(name):
        raise FigureUnavailable(name)
    return settings.jobs_dir / job_id / "figures" / f"{name}.png"


def job_figure(settings: Settings, job: dict[str, Any], records: list[dict[str, Any]],
               name: str) -> tuple[bytes, bool]:
    """(PNG, final) of figure ``name`` of ``job`` (``api.jobs.job_info``); ``final`` says the
    figure will not change (it was read from or written to the cache)."""
    path = cache_path(settings, job["id"], name)
    if name.startswith("history-"):
        index = int(name.split("-", 1)[1])
        point = history_point(records, index)
        if point is None or point["index"] != index:  # not a finished point of this job
            raise FigureUnavailable(name)
        if not path.is_file():
            _draw_history(settings, point["key"], path)
        return path.read_bytes(), True
    final = job["status"] in ENDED_JOB_STATUSES
    if final and path.is_file():
        return path.read_bytes(), True
    data = draw(name, records)
    if final:
        atomic_write(path, lambda tmp: tmp.write_bytes(data))
    return data, final


def _draw_history(settings: Settings, key: str, out: Path) -> None:
    """Draw the history of the point ``key`` into ``out`` (a child process reads its file).  A
    point file the child cannot read is set aside (``sweep.storage.set_aside``: the next job
    that needs the point computes it again) and the figure is unavailable, saying so."""
    from sweep.storage import DAMAGED_SUBDIR, point_path, set_aside

    nc = point_path(settings.points_dir, key)
    if not nc.is_file():
        raise FigureUnavailable(f"the file of point {key} is missing")
    out.parent.mkdir(parents=True, exist_ok=True)
    # named as atomic_write names its temporary files, so that a start-up clears it if left
    tmp = out.with_name(f".{out.name}.{os.getpid()}-{threading.get_ident()}{TEMP_SUFFIX}")
    try:
        proc = subprocess.run([sys.executable, "-m", "api.figures", str(nc), str(tmp)],
                              capture_output=True, text=True, timeout=HISTORY_TIMEOUT_S,
                              cwd=Path(__file__).resolve().parents[1])
        if proc.returncode == UNREADABLE_EXIT:
            reason = (proc.stderr.strip().splitlines() or ["unreadable"])[-1]
            set_aside(settings.points_dir, key, nc, reason)
            raise FigureUnavailable(f"the file of point {key} could not be read; it was moved "
                                    f"to points/{DAMAGED_SUBDIR}/ and the next job that needs "
                                    "the point computes it again")
        if proc.returncode != 0 or not tmp.is_file():
            raise RuntimeError(f"drawing the history of point {key} failed: "
                               + (proc.stderr.strip().splitlines() or ["no output"])[-1])
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)


def main(argv: list[str]) -> int:
    """``python -m api.figures POINT.nc OUT.png``: apex displacement and jet pressure against
    time of one run (the ``apex_and_jet.png`` figure of ``airpuff plot``)."""
    from airpuff_core.dataset import open_dataset
    from airpuff_core.plots import plot_apex_and_jet

    nc, out = argv
    try:
        with open_dataset(nc, engine="netcdf4") as ds:  # time in ms, not decoded into dates
            ds = ds.load()
    except Exception as err:  # noqa: BLE001 - any reason the file cannot be read
        sys.stderr.write(f"unreadable: {type(err).__name__}: {' '.join(str(err).split())}\n")
        return UNREADABLE_EXIT
    plot_apex_and_jet(ds, out)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
