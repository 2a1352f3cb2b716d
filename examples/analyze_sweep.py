"""Sensitivity of the air-puff metrics to the swept parameters, from a sweep's ``sweep.nc``.

    python examples/analyze_sweep.py demo_out/sweep.nc [--out sensitivity.png]

For every metric m (IOPg, CH, DA, ...) and every swept parameter x with at least two values it
computes the normalised sensitivity (elasticity)

    S = (x / m) dm/dx    = d ln m / d ln x,

i.e. the % change of m per % change of x, with dm/dx by finite differences along the x axis
(xarray's ``differentiate``: central differences inside, one-sided at the ends), averaged over the
other axes.  |S| = 1 means proportional; S = 0 means insensitive.  S is a relative measure: for a
metric that is close to zero somewhere (CH can be), it is large and says little -- read the
metric's own curve then.  The figure shows S as a
metric x parameter heat map, next to each metric against its most influential parameter.

Only xarray, numpy and matplotlib are used: this is how you would read a sweep in your own script.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

SWEPT = ("E0", "IOP", "thickness", "pmax")
METRICS = ("IOPg", "CH", "P1", "P2", "DA", "t_A1", "t_A2", "v_in_max")


def elasticities(ds: xr.Dataset, metrics=METRICS) -> xr.DataArray:
    """Mean elasticity d ln m / d ln x, as a (metric, parameter) DataArray (NaN if undefined)."""
    axes = [x for x in SWEPT if ds.sizes.get(x, 0) >= 2]
    metrics = [m for m in metrics if m in ds]
    table = np.full((len(metrics), len(axes)), np.nan)
    for i, m in enumerate(metrics):
        # failed points are NaN already; a metric that is ~0 somewhere would blow up the ratio
        field = ds[m].where(ds["status"] == "ok")
        for j, x in enumerate(axes):
            s = (ds[x] / field) * field.differentiate(x)
            table[i, j] = float(s.where(np.isfinite(s)).mean())
    return xr.DataArray(table, dims=("metric", "parameter"),
                        coords={"metric": metrics, "parameter": axes},
                        attrs={"long_name": "mean elasticity d ln(metric) / d ln(parameter)", "units": "1"})


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sweep_nc", type=Path, help="the combined sweep file (sweep.nc)")
    parser.add_argument("--out", type=Path, default=None,
                        help="figure to write (default: sensitivity.png next to sweep.nc)")
    args = parser.parse_args(argv)
    out = args.out or args.sweep_nc.with_name("sensitivity.png")

    ds = xr.open_dataset(args.sweep_nc, decode_times=False).load()  # time in ms (CF time axis)
    n_ok = int((ds["status"] == "ok").sum())
    print(f"{args.sweep_nc}: {ds.sizes['E0']} x {ds.sizes['IOP']} x {ds.sizes['thickness']} x "
          f"{ds.sizes['pmax']} points, {n_ok} ok; resolution {ds.attrs.get('param_resolution')}")
    for label in ("failed", "missing"):
        bad = ds["status"] == label
        for idx in zip(*np.nonzero(bad.values)):
            point = {x: float(ds[x].values[i]) for x, i in zip(SWEPT, idx)}
            print(f"  {label}: {point}: {ds['message'].values[idx]}")

    S = elasticities(ds)
    if S.sizes["parameter"] == 0:
        print("every axis has a single value: nothing to differentiate")
        return 1
    print("\nmean elasticity d ln(metric) / d ln(parameter):")
    print("          " + "".join(f"{p:>11s}" for p in S["parameter"].values))
    for m in S["metric"].values:
        print(f"{m:10s}" + "".join(f"{v:11.3f}" for v in S.sel(metric=m).values))

    panel_metrics = [m for m in ("IOPg", "CH", "DA") if m in ds]
    fig, axes = plt.subplots(1, 1 + len(panel_metrics), figsize=(4.3 * (1 + len(panel_metrics)), 3.8),
                             constrained_layout=True)
    ax = axes[0]
    vmax = np.nanmax(np.abs(S.values)) if np.isfinite(S.values).any() else 1.0
    im = ax.imshow(S.values, cmap="RdBu_r", vmin=-vmax, vmax=vmax, aspect="auto")
    ax.set_xticks(range(S.sizes["parameter"]), S["parameter"].values)
    ax.set_yticks(range(S.sizes["metric"]), S["metric"].values)
    for (i, j), v in np.ndenumerate(S.values):
        ax.text(j, i, "--" if not np.isfinite(v) else f"{v:.2f}", ha="center", va="center", fontsize=8)
    fig.colorbar(im, ax=ax, label="d ln m / d ln x")
    ax.set_title("sensitivity")
    for ax, m in zip(axes[1:], panel_metrics):
        row = S.sel(metric=m)
        x = str(row["parameter"].values[int(np.nanargmax(np.abs(row.values)))]) \
            if np.isfinite(row.values).any() else str(S["parameter"].values[0])
        others = [d for d in SWEPT if d != x]
        mean = ds[m].where(ds["status"] == "ok").mean(others)
        lo = ds[m].where(ds["status"] == "ok").min(others)
        hi = ds[m].where(ds["status"] == "ok").max(others)
        ax.fill_between(ds[x].values, lo.values, hi.values, alpha=0.25, label="range over other axes")
        ax.plot(ds[x].values, mean.values, "o-", label="mean")
        ax.set_xlabel(f"{x} [{ds[x].attrs.get('units', '')}]")
        ax.set_ylabel(f"{m} [{ds[m].attrs.get('units', '')}]")
        ax.set_title(f"{m} against its strongest parameter")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
    fig.savefig(out, dpi=120)
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
