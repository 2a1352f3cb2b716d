"""Figures of a combined sweep dataset (``sweep.nc``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

# (variable, axis label) of the panels of plot_metrics_vs_iop
PANELS = (("IOPg", "IOPg [mmHg]"), ("CH", "CH [mmHg]"), ("DA", "DA [mm]"))


def plot_metrics_vs_iop(ds, path, thickness=None, pmax=None) -> Path:
    """IOPg, CH and DA against IOP, one line per E0, written as a PNG to ``path``.

    Lines are drawn at one thickness and one pmax (default: the first of each axis; a title says
    which).  Failed points and missing metrics are NaN and leave gaps; failed points are marked
    with an x on the IOP axis so a gap is not mistaken for a plotting error.
    """
    import matplotlib

    matplotlib.use("Agg")  # files only; works without a display
    import matplotlib.pyplot as plt

    thickness = float(ds["thickness"].values[0]) if thickness is None else thickness
    pmax = float(ds["pmax"].values[0]) if pmax is None else pmax
    sub = ds.sel(thickness=thickness, pmax=pmax)
    fig, axes = plt.subplots(1, len(PANELS), figsize=(4.2 * len(PANELS), 3.6), constrained_layout=True)
    for ax, (name, label) in zip(axes, PANELS):
        for e0 in sub["E0"].values:
            line = sub[name].sel(E0=e0)
            ax.plot(sub["IOP"].values, line.values, "o-", label=f"E0 = {e0:g} MPa")
            failed = sub["status"].sel(E0=e0).values == "failed"
            if failed.any():
                ax.plot(sub["IOP"].values[failed], np.zeros(failed.sum()), "x", color="red",
                        transform=ax.get_xaxis_transform(), clip_on=False)
        ax.set_xlabel("IOP [mmHg]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize="small")
    fig.suptitle(f"air-puff sweep: thickness {thickness:g} mm, pmax {pmax:g} kPa, "
                 f"resolution {ds.attrs.get('param_resolution', '?')}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
