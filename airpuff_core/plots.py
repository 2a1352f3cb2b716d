"""The paper's figures from a run's netCDF (any run: the figures read only the dataset).

- ``apex_and_jet.png``      apex displacement and jet pressure against time (paper Fig. 8)
- ``hysteresis.png``        normalised apex displacement against normalised time and against
                            normalised jet pressure: the hysteresis loop (Fig. 6)
- ``applanation.png``       jet pressure and apex curvature against time, applanations marked (Fig. 7)
- ``shapes.png``            the six cornea shapes over the fluid pressure field (Fig. 10)
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .dataset import open_dataset  # noqa: E402

FIGURES = ("apex_and_jet.png", "hysteresis.png", "applanation.png", "shapes.png")


def _title(ds):
    return (f"E0 = {float(ds.E0):g} MPa, IOP = {float(ds.IOP):g} mmHg, "
            f"h = {float(ds.thickness):g} mm, pmax = {float(ds.pmax):g} kPa "
            f"({ds.attrs.get('resolution', '?')})")


def _save(fig, path, tight=True, dpi=120):
    """Write ``fig`` to ``path`` as PNG, whatever its name ends with (a temporary name too)."""
    if tight:
        fig.tight_layout()
    fig.savefig(path, dpi=dpi, format="png")
    plt.close(fig)


def _mark_applanations(ax, ds):
    for name, tname, color in (("P1", "t_A1", "tab:green"), ("P2", "t_A2", "tab:purple")):
        t = float(ds[tname])
        if math.isfinite(t):
            ax.axvline(t, color=color, ls="--", lw=1,
                       label=f"{'A1' if name == 'P1' else 'A2'}: t = {t:.2f} ms, "
                             f"{name} = {float(ds[name]):.2f} mmHg")


def plot_apex_and_jet(ds, path):
    fig, ax = plt.subplots(figsize=(7, 4.2))
    t = ds.time.values
    l1 = ax.plot(t, ds.apex_displacement, color="tab:blue", label="apex displacement (inward)")
    ax.set_xlabel("time [ms]")
    ax.set_ylabel("apex displacement [mm]", color="tab:blue")
    ax2 = ax.twinx()
    l2 = ax2.plot(t, ds.jet_pressure_apex, color="tab:red", label="air-jet pressure at the apex")
    ax2.set_ylabel("jet pressure [mmHg]", color="tab:red")
    da, thc = float(ds.DA), float(ds.t_HC)
    l3 = ax.plot([thc], [da], "o", color="tab:blue", label=f"DA = {da:.3f} mm at {thc:.2f} ms")
    ax.legend(handles=l1 + l2 + l3, loc="upper right", fontsize=8)
    ax.set_title("Apex displacement and air-jet pressure\n" + _title(ds), fontsize=9)
    _save(fig, path)


def plot_hysteresis(ds, path):
    t = ds.time.values
    d = ds.apex_displacement.values
    p = ds.jet_pressure_apex.values
    dn = d / np.nanmax(np.abs(d)) if np.nanmax(np.abs(d)) > 0 else d
    pn = p / np.nanmax(p) if np.nanmax(p) > 0 else p
    T = float(ds["T"])
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4.2))
    a.plot(t / T, dn, label="apex displacement / DA")
    a.plot(t / T, pn, label="jet pressure / peak", alpha=0.7)
    a.set_xlabel("normalised time t / T [-]")
    a.set_ylabel("normalised value [-]")
    a.legend(fontsize=8)
    a.set_title("(a) against normalised time", fontsize=9)
    i_peak = int(np.nanargmax(p))
    b.plot(pn[:i_peak + 1], dn[:i_peak + 1], color="tab:orange", lw=2, label="loading (jet rising)")
    b.plot(pn[i_peak:], dn[i_peak:], color="tab:blue", lw=1.2, ls="--",
           label="unloading (jet falling)")
    b.set_xlabel("normalised jet pressure [-]")
    b.set_ylabel("normalised apex displacement [-]")
    b.legend(fontsize=8)
    b.set_title("(b) hysteresis loop", fontsize=9)
    fig.suptitle("Normalised response\n" + _title(ds), fontsize=9)
    _save(fig, path)


def plot_applanation(ds, path):
    t = ds.time.values
    fig, ax = plt.subplots(figsize=(7, 4.2))
    l1 = ax.plot(t, ds.jet_pressure_apex, color="tab:red", label="jet pressure at the apex")
    l1 += ax.plot(t, ds.fluid_pressure_apex, color="tab:orange", alpha=0.8,
                  label="fluid pressure at the apex")
    ax.set_xlabel("time [ms]")
    ax.set_ylabel("pressure [mmHg]")
    ax2 = ax.twinx()
    l2 = ax2.plot(t, ds.apex_curvature, color="tab:blue", label="apex curvature (convex > 0)")
    ax2.axhline(0, color="tab:blue", lw=0.6, ls=":")
    ax2.set_ylabel("apex curvature [1/mm]", color="tab:blue")
    _mark_applanations(ax, ds)
    handles = l1 + l2 + [h for h in ax.get_lines() if h.get_label().startswith("A")]
    ax.legend(handles=handles, loc="upper right", fontsize=7)
    ax.set_title("Applanations: sign changes of the apex curvature\n" + _title(ds), fontsize=9)
    _save(fig, path)


def plot_shapes(ds, path):
    labels = [str(s) for s in ds.snapshot_label.values]
    pressure = ds.fluid_pressure.values
    vmin, vmax = np.nanmin(pressure), np.nanmax(pressure)
    fig, axes = plt.subplots(2, 3, figsize=(12, 5.6), sharex=True, sharey=True, layout="constrained")
    sc = None
    for k, ax in enumerate(axes.flat):
        t = float(ds.snapshot_time[k])
        if not math.isfinite(t):
            ax.set_title(f"{labels[k].replace('_', ' ')}: not reached", fontsize=9)
            continue
        x, y = ds.fluid_x.values[k], ds.fluid_y.values[k]
        p = pressure[k]
        # the meridian plane mirrored about the axis, as the eye is seen in section
        sc = ax.scatter(np.concatenate([x, -x]), np.concatenate([y, y]), c=np.concatenate([p, p]),
                        s=6, cmap="viridis", vmin=vmin, vmax=vmax)
        cx, cy = ds.cornea_x.values[k], ds.cornea_y.values[k]
        ax.plot(np.concatenate([-cx[::-1], cx]), np.concatenate([cy[::-1], cy]), "r-", lw=1.5,
                label="cornea")
        c0x, c0y = ds.cornea_x.values[0], ds.cornea_y.values[0]
        ax.plot(np.concatenate([-c0x[::-1], c0x]), np.concatenate([c0y[::-1], c0y]), "k:", lw=0.8,
                label="initial cornea")
        ax.set_aspect("equal")
        ax.set_title(f"({'abcdef'[k]}) {labels[k].replace('_', ' ')}, t = {t:.2f} ms", fontsize=9)
        if k == 0:
            ax.legend(fontsize=7, loc="lower center")
    for ax in axes[1]:
        ax.set_xlabel("x [mm] (distance from the axis)")
    for ax in axes[:, 0]:
        ax.set_ylabel("y [mm] (along the axis)")
    if sc is not None:
        cb = fig.colorbar(sc, ax=axes, shrink=0.9)
        cb.set_label("fluid pressure [mmHg]")
    fig.suptitle("Cornea shapes and fluid pressure\n" + _title(ds), fontsize=10)
    _save(fig, path, tight=False, dpi=110)  # constrained layout


def plot_run(nc_path, out_dir) -> list[Path]:
    """Write the four figures of a run's netCDF into ``out_dir``; return their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with open_dataset(nc_path) as ds:
        ds = ds.load()
    paths = []
    for name, fn in zip(FIGURES, (plot_apex_and_jet, plot_hysteresis, plot_applanation, plot_shapes)):
        fn(ds, out / name)
        paths.append(out / name)
    return paths
