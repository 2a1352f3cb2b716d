"""The instruments' air pulses (issue 26) against their sources, and the ORA's peak against IOP.

Runs the clinical preset at the normal eye (thickness 0.54 mm, E0 0.5 MPa) under the ORA's pulse
at each IOP, and under the Corvis ST's and the paper's at IOP 16, and draws
docs/figures/pulses.png:

(a) the pulses on the apex against time: the paper's eq. (11); the Corvis ST's table
    (``loads/corvis.py``: Eliasy et al. 2023 as digitised) with the same group's earlier curve
    (Joda et al. 2016, the same digitiser, sampled below) beside it; the ORA's at IOP 16, with the
    applanation times of the two real ORA records (docs/sources.md section 1) it was calibrated on;
(b) the ORA's pulse at each IOP, its applanations marked: the pump's switch-off follows the
    applanation it detects, so a higher IOP gets a later switch-off and a higher peak;
(c) the ORA's peak on the apex and P1, P2 against IOP;
(d) the spatial profile exp(-a sin^2 phi) of every pulse against the distance from the axis.

    python -m studies.pulses --out /tmp/pulses                  # paper resolution, ~5 min
    python -m studies.pulses --out /tmp/pulses --resolution coarse --IOP 10,16,30

Every finished run is kept as <out>/<name>.nc; --reuse reads back a run whose file has the same
parameters.  The table goes to <out>/table.md and is printed.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from airpuff_core import RunParams, simulate
from airpuff_core.dataset import open_dataset, params_from_dataset, write_netcdf
from airpuff_core.loads.corvis import CORVIS_APEX_MMHG, CORVIS_START_MS, CORVIS_STEP_MS
from airpuff_core.params import MMHG_PA, PARAMETERS

NORMAL_EYE = {"model": "clinical", "thickness": 0.54, "E0": 0.5}
# The two real ORA records (docs/sources.md section 1): TimeIn, TimeOut [ms]
ORA_RECORDS = ((8.18, 18.75), (8.40, 18.98))
# Joda et al. 2016's Corvis pressure on the apex, as digitised in the public R package
# onEyeAirpuff (its first data version), sampled here every 1 ms from 5 ms [mmHg]: a second
# reading of the same group's curve, for comparison only
JODA_START_MS = 5.0
JODA_APEX_MMHG = (0.0, 12.64, 21.29, 29.35, 38.42, 47.56, 56.66, 64.55, 72.94, 79.64, 86.01,
                  91.09, 93.89, 95.08, 93.98, 90.27, 83.29, 73.20, 58.86, 41.56, 18.09, 0.0)
# the outer boundary of a non-contact tonometer's jet at the cornea (docs/model.md section 6):
# a 2.4 mm orifice at 11 mm, spreading at 8.4 deg
JET_OUTER_RADIUS_MM = 1.2 + 11.0 * math.tan(math.radians(8.4))


def run(name: str, params: RunParams, out: Path, reuse: bool):
    """The run's dataset (read back with ``reuse`` when its file has these parameters)."""
    nc = out / f"{name}.nc"
    if reuse and nc.exists():
        ds = open_dataset(nc)
        if params_from_dataset(ds).to_dict() == params.to_dict():
            print(f"[{name}] reused {nc.name}", flush=True)
            return ds.load()
        ds.close()
    t0 = time.perf_counter()
    ds = simulate(params).to_dataset()
    write_netcdf(ds, nc)
    print(f"[{name}] {time.perf_counter() - t0:.0f} s: t_A1 {float(ds.t_A1):.3f} ms, "
          f"t_A2 {float(ds.t_A2):.3f} ms, P1 {float(ds.P1):.2f}, P2 {float(ds.P2):.2f} mmHg",
          flush=True)
    return ds


def row_of(name: str, ds) -> dict:
    peak = ds.attrs.get("solver_pulse_peak_apex_mmHg", float(ds.jet_pressure_apex.max()))
    return {"run": name, "instrument": ds.attrs["instrument"], "IOP": float(ds.IOP),
            **{k: float(ds[k]) for k in ("P1", "P2", "CH", "IOPg", "t_A1", "t_A2", "t_HC", "DA")},
            "switch_off": float(ds.attrs.get("solver_pulse_switch_off_ms", math.nan)),
            "peak": float(peak)}


def table_md(rows: list[dict]) -> str:
    cols = [("run", "run", "{}"), ("IOP", "IOP [mmHg]", "{:g}"), ("t_A1", "t_A1 [ms]", "{:.2f}"),
            ("t_A2", "t_A2 [ms]", "{:.2f}"), ("switch_off", "switch-off [ms]", "{:.2f}"),
            ("peak", "peak on the apex [mmHg]", "{:.1f}"), ("P1", "P1 [mmHg]", "{:.2f}"),
            ("P2", "P2 [mmHg]", "{:.2f}"), ("CH", "CH [mmHg]", "{:.2f}"),
            ("IOPg", "IOPg [mmHg]", "{:.2f}"), ("t_HC", "t_HC [ms]", "{:.2f}"),
            ("DA", "DA [mm]", "{:.3f}")]
    lines = ["| " + " | ".join(c[1] for c in cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join("-" if isinstance(r[k], float) and not math.isfinite(r[k])
                                       else f.format(r[k]) for k, _, f in cols) + " |")
    return "\n".join(lines) + "\n"


def figure(ora: dict, corvis, paper, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5))
    a, b, c, d = axes.ravel()
    # (a) the three pulses against their sources
    a.plot(paper.time, paper.jet_pressure_apex, color="k", label="paper, eq. (11)")
    a.plot(corvis.time, corvis.jet_pressure_apex, color="tab:blue",
           label="Corvis ST (Eliasy 2023, digitised)")
    joda_t = JODA_START_MS + np.arange(len(JODA_APEX_MMHG))
    a.plot(joda_t, JODA_APEX_MMHG, "o", color="tab:blue", mfc="none", ms=5,
           label="Corvis ST, Joda 2016 (digitised)")
    corvis_t = CORVIS_START_MS + CORVIS_STEP_MS * np.arange(len(CORVIS_APEX_MMHG))
    a.plot(corvis_t[::4], np.asarray(CORVIS_APEX_MMHG)[::4], "x", color="tab:blue", ms=5,
           label="Corvis table (every 2 ms)")
    normal = ora[16.0]
    a.plot(normal.time, normal.jet_pressure_apex, color="tab:red",
           label="ORA, normal eye (calibrated)")
    for k, (t_in, t_out) in enumerate(ORA_RECORDS):
        for t in (t_in, t_out):
            a.axvline(t, color="tab:red", ls=":", lw=1,
                      label="ORA TimeIn, TimeOut: 2 records" if k == 0 and t == t_in
                      else None)
    a.plot([float(normal.t_A1), float(normal.t_A2)], [float(normal.P1), float(normal.P2)], "s",
           color="tab:red", mfc="none", label="model's A1, A2 (ORA)")
    a.set(xlabel="time [ms]", ylabel="pressure on the apex [mmHg]", xlim=(0, 35), ylim=(0, 150),
          title="(a) the pulses on the apex and their sources")
    a.legend(fontsize=6.5, loc="upper left", ncol=2)
    # (b) the ORA's pulse at each IOP
    cmap = plt.get_cmap("viridis")
    iops = sorted(ora)
    for k, iop in enumerate(iops):
        ds = ora[iop]
        col = cmap(k / max(1, len(iops) - 1))
        b.plot(ds.time, ds.jet_pressure_apex, color=col, label=f"IOP {iop:g} mmHg")
        b.plot([float(ds.t_A1), float(ds.t_A2)], [float(ds.P1), float(ds.P2)], "o", color=col,
               mfc="none")
    b.set(xlabel="time [ms]", ylabel="ORA pulse on the apex [mmHg]", xlim=(0, 35),
          title=f"(b) ORA at each IOP: off {float(normal.ora_delay):g} ms after its A1 (o: A1, A2)")
    b.legend(fontsize=7)
    # (c) the ORA's peak against IOP
    peaks = [ora[i].attrs["solver_pulse_peak_apex_mmHg"] for i in iops]
    c.plot(iops, peaks, "o-", color="tab:red", label="peak on the apex")
    c.plot(iops, [float(ora[i].P1) for i in iops], "s--", color="tab:orange", label="P1")
    c.plot(iops, [float(ora[i].P2) for i in iops], "^--", color="tab:green", label="P2")
    slope = np.polyfit(iops, peaks, 1)[0]
    c.set(xlabel="true IOP [mmHg]", ylabel="mmHg",
          title=f"(c) ORA: the peak rises with IOP ({slope:.2f} mmHg per mmHg)")
    c.legend(fontsize=8)
    # (d) the spatial profile
    R = PARAMETERS["R"].default
    a_decay = float(paper.a)
    r = np.linspace(0.0, R * math.sin(math.radians(PARAMETERS["alpha0"].default)), 200)
    d.plot(r, np.exp(-a_decay * (r / R) ** 2), color="k",
           label=f"exp(-a sin^2 phi), a = {a_decay:g}, R = {R:g} mm (every instrument)")
    d.axvline(R / math.sqrt(a_decay), color="gray", ls=":", label="1/e radius R / sqrt(a)")
    d.axvline(JET_OUTER_RADIUS_MM, color="tab:blue", ls="--",
              label="outer jet boundary: 2.4 mm orifice, 11 mm, 8.4 deg (CFD)")
    d.set(xlabel="distance from the axis R sin phi [mm]", ylabel="pressure / pressure on the apex",
          title="(d) the spatial profile")
    d.legend(fontsize=7)
    fig.suptitle("Air pulses of the instruments (clinical preset, normal eye: CCT 0.54 mm, "
                 f"E0 0.5 MPa; {paper.attrs['resolution']} resolution)", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, type=Path, help="folder of the runs' netCDF files")
    ap.add_argument("--resolution", default="paper", choices=("coarse", "paper", "fine"))
    ap.add_argument("--IOP", default="10,13,16,20,25,30", help="IOPs of the ORA runs [mmHg]")
    ap.add_argument("--figure", default=Path("docs/figures/pulses.png"), type=Path)
    ap.add_argument("--reuse", action="store_true")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    iops = sorted({float(v) for v in args.IOP.split(",")} | {16.0})
    base = {**NORMAL_EYE, "resolution": args.resolution}
    ora = {iop: run(f"ora_IOP{iop:g}", RunParams(**base, IOP=iop, instrument="ora"), args.out,
                    args.reuse) for iop in iops}
    corvis = run("corvis_IOP16", RunParams(**base, IOP=16.0, instrument="corvis"), args.out,
                 args.reuse)
    paper = run("paper_IOP16", RunParams(**base, IOP=16.0), args.out, args.reuse)
    rows = ([row_of(f"ora_IOP{i:g}", ora[i]) for i in iops]
            + [row_of("corvis_IOP16", corvis), row_of("paper_IOP16", paper)])
    text = table_md(rows)
    (args.out / "table.md").write_text(text)
    print(text)
    peaks = [ora[i].attrs["solver_pulse_peak_apex_mmHg"] for i in iops]
    print(f"ORA peak on the apex against IOP: {np.polyfit(iops, peaks, 1)[0]:.3f} mmHg/mmHg "
          f"(least squares over IOP {iops[0]:g}-{iops[-1]:g})")
    figure(ora, corvis, paper, args.figure)
    print(f"figure: {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
