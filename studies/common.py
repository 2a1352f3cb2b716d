"""Shared helpers of the reproduction studies (studies/sensitivity.py, convergence.py).

Each variant is one ``simulate()`` call in this process (one core, one run at a time).  Every
finished run is kept as ``<out>/<name>.nc``; with ``--reuse`` a variant whose netCDF already exists
and was produced with exactly the same parameters is read back instead of re-run, so an
interrupted study can be resumed.  A run that fails (blow-up, coupling, conditioning) is a result
too: it is recorded with its message.
"""

from __future__ import annotations

import csv
import json
import math
import time
import traceback
from pathlib import Path

import xarray as xr

from airpuff_core import RunParams, SimulationError, simulate
from airpuff_core.dataset import params_from_dataset, write_netcdf

# the paper's baseline (section 5); t_A1, t_A2 are where its P1, P2 sit on the jet of eq. (11)
PAPER = {"P1": 21.96, "P2": 6.82, "CH": 15.14, "IOPg": 14.39, "IOPcc": 19.03,
         "t_A1": 8.35, "t_A2": 24.3, "DA": math.nan}

SHOWN = ("P1", "P2", "CH", "DA", "t_A1", "t_A2")
EXTRA = ("IOPg", "IOPcc", "CRF", "IOPcc_ora", "t_HC", "v_in_max", "v_out_max")
DIAG = ("fluid_pressure_apex_at_A1", "fluid_pressure_apex_at_A2", "applanation_crossings_down",
        "applanation_crossings_up", "max_volume_mismatch", "steps", "dt_mean_us", "n_fluid",
        "n_cornea", "wall_s")
UNITS = {"P1": "mmHg", "P2": "mmHg", "CH": "mmHg", "DA": "mm", "t_A1": "ms", "t_A2": "ms"}


def _row_from_dataset(ds) -> dict:
    row = {k: float(ds[k]) for k in SHOWN + EXTRA}
    for k in DIAG:
        v = ds.attrs.get(f"solver_{k}")
        row[k] = float(v) if v is not None else math.nan
    return row


def run_variant(name: str, params: RunParams, out_dir: Path, reuse: bool, log=print) -> dict:
    """Run (or, with ``reuse``, read back) one variant; return its table row."""
    nc = out_dir / f"{name}.nc"
    base = {"variant": name, "resolution": params.resolution}
    if reuse and nc.exists():
        with xr.open_dataset(nc) as ds:
            if params_from_dataset(ds).to_dict() == params.to_dict():
                log(f"[{name}] reused {nc.name}")
                return {**base, "status": "ok", "message": "", **_row_from_dataset(ds)}
            log(f"[{name}] {nc.name} has other parameters: re-running")
    log(f"[{name}] running ({params.resolution}) ...")
    t0 = time.perf_counter()
    try:
        result = simulate(params)
    except SimulationError as err:
        wall = time.perf_counter() - t0
        log(f"[{name}] FAILED after {wall:.0f} s: {err}")
        row = {**base, "status": "failed", "message": str(err), "wall_s": wall}
        (out_dir / f"{name}.failed.json").write_text(json.dumps(
            {"params": params.to_dict(), "message": str(err), "time_ms": err.time_ms,
             "reason": err.reason}, indent=1))
        return row
    except Exception as err:  # an unexpected error is recorded, not hidden
        log(f"[{name}] ERROR: {err!r}\n{traceback.format_exc()}")
        return {**base, "status": "error", "message": repr(err)}
    ds = result.to_dataset()
    write_netcdf(ds, nc)
    row = {**base, "status": "ok", "message": "", **_row_from_dataset(ds)}
    log(f"[{name}] done in {row['wall_s']:.0f} s: " + ", ".join(
        f"{k} {row[k]:.3f}" for k in SHOWN))
    return row


def fmt(v, nd=2):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.{nd}f}"


def write_tables(rows: list[dict], out_dir: Path, stem: str) -> None:
    """``<stem>.csv`` and ``<stem>.json`` in ``out_dir``."""
    keys = []
    for r in rows:
        for k in r:
            if k not in keys:
                keys.append(k)
    with open(out_dir / f"{stem}.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, "") for k in keys})
    clean = [{k: (None if isinstance(v, float) and not math.isfinite(v) else v)
              for k, v in r.items()} for r in rows]
    (out_dir / f"{stem}.json").write_text(json.dumps(clean, indent=1))
