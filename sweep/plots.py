"""Figures of a combined sweep dataset (``sweep.nc``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

# (variable, axis label) of the panels of plot_metrics_vs_iop
PANELS = (("IOPg", "IOPg [mmHg]"), ("CH", "CH [mmHg]"), ("DA", "DA [mm]"))


def plot_metrics_vs_iop(datasets, path, thickness=None, pmax=None) -> Path:
    """IOPg, CH and DA against IOP, one line per E0, written as a PNG to ``path``.

    ``datasets``: one sweep dataset, or a mapping {label: dataset} drawn as one row of panels
    per dataset (e.g. the paper's and the clinical model side by side).  Lines are drawn at one
    thickness and one pmax (default: the first of each axis; a title says which).  Failed points
    and missing metrics are NaN and leave gaps; failed points are marked with an x on the IOP
    axis so a gap is not mistaken for a plotting error.
    """
    import matplotlib

    matplotlib.use("Agg")  # files only; works without a display
    import matplotlib.pyplot as plt

    rows = datasets if isinstance(datasets, dict) else {"": datasets}
    first = next(iter(rows.values()))
    thickness = float(first["thickness"].values[0]) if thickness is None else thickness
    pmax = float(first["pmax"].values[0]) if pmax is None else pmax
    fig, axes = plt.subplots(len(rows), len(PANELS), figsize=(4.2 * len(PANELS), 3.4 * len(rows)),
                             constrained_layout=True, squeeze=False)
    for row_axes, (title, ds) in zip(axes, rows.items()):
        sub = ds.sel(thickness=thickness, pmax=pmax)
        for ax, (name, label) in zip(row_axes, PANELS):
            for e0 in sub["E0"].values:
                line = sub[name].sel(E0=e0)
                ax.plot(sub["IOP"].values, line.values, "o-", label=f"E0 = {e0:g} MPa")
                failed = sub["status"].sel(E0=e0).values == "failed"
                if failed.any():
                    ax.plot(sub["IOP"].values[failed], np.zeros(failed.sum()), "x", color="red",
                            transform=ax.get_xaxis_transform(), clip_on=False)
            ax.set_xlabel("IOP [mmHg]")
            ax.set_ylabel(f"{title}: {label}" if title else label)
            ax.grid(alpha=0.3)
        row_axes[0].legend(fontsize="small")
    fig.suptitle(f"air-puff sweep: thickness {thickness:g} mm, pmax {pmax:g} kPa, "
                 f"resolution {first.attrs.get('param_resolution', '?')}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
