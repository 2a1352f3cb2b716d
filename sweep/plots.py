"""Figures of a sweep: metrics against IOP (one line per E0) and heat maps over (IOP, E0).

``plot_metrics_vs_iop`` draws them from a combined dataset (``sweep.nc``, ``make demo``); the
results pages of the HTTP service (``api.figures``) draw the same panels from the job database
with ``draw_metric_vs_iop`` and ``draw_heatmap``, on figures made by ``new_figure`` (no pyplot
state, so request threads can draw at the same time).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

# (variable, axis label) of the panels of plot_metrics_vs_iop
PANELS = (("IOPg", "IOPg [mmHg]"), ("CH", "CH [mmHg]"), ("DA", "DA [mm]"))


def new_figure(width_in: float, height_in: float):
    """A matplotlib Figure with an Agg canvas, independent of pyplot (thread-safe per figure)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), constrained_layout=True)
    FigureCanvasAgg(fig)
    return fig


def draw_metric_vs_iop(ax, iop, lines: dict[float, np.ndarray], failed: dict[float, np.ndarray],
                       label: str) -> None:
    """One panel: a metric against IOP [mmHg], one line per E0 [MPa].

    ``lines`` maps E0 to the metric at each IOP of ``iop`` (NaN where missing: a gap); ``failed``
    maps E0 to a boolean mask of failed points, marked by a red x on the IOP axis so that a gap is
    not mistaken for a plotting error.
    """
    iop = np.asarray(iop, float)
    for e0, values in lines.items():
        ax.plot(iop, values, "o-", label=f"E0 = {e0:g} MPa")
        mask = np.asarray(failed.get(e0, np.zeros(iop.size, bool)), bool)
        if mask.any():
            ax.plot(iop[mask], np.zeros(mask.sum()), "x", color="red",
                    transform=ax.get_xaxis_transform(), clip_on=False)
    ax.set_xlabel("IOP [mmHg]")
    ax.set_ylabel(label)
    ax.grid(alpha=0.3)


def draw_heatmap(fig, ax, iop, e0, values: np.ndarray, label: str) -> None:
    """A metric over the (IOP [mmHg], E0 [MPa]) grid as coloured cells, one cell per grid point
    centred on its values (``values[i, j]`` at E0 ``e0[i]``, IOP ``iop[j]``), each labelled with
    its value; missing points (NaN) stay blank."""
    iop, e0 = np.asarray(iop, float), np.asarray(e0, float)
    values = np.ma.masked_invalid(np.asarray(values, float))
    mesh = ax.pcolormesh(_cell_edges(iop), _cell_edges(e0), values, shading="flat",
                         cmap="viridis")
    fig.colorbar(mesh, ax=ax, label=label)
    if values.size <= 100:
        for i, y in enumerate(e0):
            for j, x in enumerate(iop):
                if not values.mask[i, j]:
                    r, g, b, _ = mesh.cmap(mesh.norm(values[i, j]))
                    light = 0.299 * r + 0.587 * g + 0.114 * b > 0.5  # perceived brightness
                    ax.text(x, y, f"{values[i, j]:.3g}", ha="center", va="center", fontsize=7,
                            color="black" if light else "white")
    if iop.size <= 12:
        ax.set_xticks(iop)
    if e0.size <= 12:
        ax.set_yticks(e0)
    ax.set_xlabel("IOP [mmHg]")
    ax.set_ylabel("E0 [MPa]")


def _cell_edges(centres: np.ndarray) -> np.ndarray:
    """Edges of cells centred on sorted ``centres`` (midpoints; the outer cells symmetric)."""
    if centres.size == 1:
        return np.array([centres[0] - 0.5, centres[0] + 0.5])
    mid = 0.5 * (centres[1:] + centres[:-1])
    return np.concatenate([[2 * centres[0] - mid[0]], mid, [2 * centres[-1] - mid[-1]]])


def plot_metrics_vs_iop(datasets, path, thickness=None, pmax=None) -> Path:
    """IOPg, CH and DA against IOP, one line per E0, written as a PNG to ``path``.

    ``datasets``: one sweep dataset, or a mapping {label: dataset} drawn as one row of panels
    per dataset (e.g. the paper's and the clinical model side by side).  Lines are drawn at one
    thickness and one pmax (default: the first of each axis; a title says which).  Failed points
    and missing metrics are NaN and leave gaps; failed points are marked with an x on the IOP
    axis so a gap is not mistaken for a plotting error.
    """
    rows = datasets if isinstance(datasets, dict) else {"": datasets}
    first = next(iter(rows.values()))
    thickness = float(first["thickness"].values[0]) if thickness is None else thickness
    pmax = float(first["pmax"].values[0]) if pmax is None else pmax
    fig = new_figure(4.2 * len(PANELS), 3.4 * len(rows))
    axes = fig.subplots(len(rows), len(PANELS), squeeze=False)
    resolutions = {ds.attrs.get("param_resolution", "?") for ds in rows.values()}
    for row_axes, (title, ds) in zip(axes, rows.items()):
        if title and len(resolutions) > 1:  # rows at different resolutions: each row says its own
            title = f"{title} ({ds.attrs.get('param_resolution', '?')})"
        sub = ds.sel(thickness=thickness, pmax=pmax)
        e0s = [float(e0) for e0 in sub["E0"].values]
        failed = {e0: sub["status"].sel(E0=e0).values == "failed" for e0 in e0s}
        for ax, (name, label) in zip(row_axes, PANELS):
            lines = {e0: sub[name].sel(E0=e0).values for e0 in e0s}
            draw_metric_vs_iop(ax, sub["IOP"].values, lines, failed,
                               f"{title}: {label}" if title else label)
        row_axes[0].legend(fontsize="small")
    fig.suptitle(f"air-puff sweep: thickness {thickness:g} mm, pmax {pmax:g} kPa"
                 + (f", resolution {resolutions.pop()}" if len(resolutions) == 1 else ""))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    return path


def plot_calibration(data: dict, path) -> Path:
    """The reference sweep of a calibration (``sweep.calibration.make_calibration``'s object):
    the raw P1, P2, IOPg and the calibrated IOPg, IOPnc against the true IOP (left), and the
    calibrated readings' errors with the 0.3 mmHg band (right); written as PNG to ``path``."""
    ref = data["reference_sweep"]
    iop = np.asarray(ref["IOP"], float)
    p1, p2 = np.asarray(ref["P1_raw"], float), np.asarray(ref["P2_raw"], float)
    fig = new_figure(10.0, 4.2)
    left, right = fig.subplots(1, 2)
    left.plot(iop, p1, "^--", color="tab:red", label="P1 (raw)")
    left.plot(iop, p2, "v--", color="tab:blue", label="P2 (raw)")
    left.plot(iop, 0.5 * (p1 + p2), "s--", color="tab:gray", label="IOPg (raw)")
    left.plot(iop, ref["IOPg_cal"], "o-", color="black", label="IOPg_cal")
    left.plot(iop, ref["IOPnc_cal"], "x:", color="tab:green", label="IOPnc_cal")
    left.plot(iop, iop, "-", color="tab:orange", lw=0.8, label="true IOP")
    left.set_xlabel("true IOP [mmHg]")
    left.set_ylabel("reading [mmHg]")
    left.legend(fontsize=8)
    for name, style in (("IOPg_cal", "o-"), ("IOPnc_cal", "x:"), ("IOPcc_ora_cal", "d-.")):
        right.plot(iop, np.asarray(ref[name], float) - iop, style, label=f"{name} - IOP")
    right.axhspan(-0.3, 0.3, color="tab:orange", alpha=0.15, label="+-0.3 mmHg")
    right.axhline(0.0, color="black", lw=0.6)
    right.set_xlabel("true IOP [mmHg]")
    right.set_ylabel("calibrated reading - true IOP [mmHg]")
    right.legend(fontsize=8)
    eye = data["reference_eye"]
    fig.suptitle(f"calibration of instrument {data['instrument']} ({data['model']} model, "
                 f"{data['resolution']} resolution, model version {data['model_version']}): "
                 f"reference eye CCT {eye['thickness']:g} mm, E0 {eye['E0']:g} MPa, "
                 f"R {eye['R']:g} mm", fontsize=9)
    fig.savefig(str(path), dpi=110, format="png")
    return Path(path)
