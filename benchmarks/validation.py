"""Clinical validation of the cornea models: IOPg against CCT, E0 and the true IOP.

    python benchmarks/validation.py --out validation                       # coarse, both corneas
    python benchmarks/validation.py --out validation_paper --resolution paper --cornea shell
    python benchmarks/validation.py --out validation --reuse               # read back finished runs

Three one-parameter studies about the normal eye (E0 0.5 MPa, IOP 16 mmHg, CCT 0.54 mm, the
paper's geometry and jet), for each cornea model asked for:

- CCT (thickness) 0.45-0.65 mm: slope of IOPg in mmHg per 100 um;
- E0 0.3-0.9 MPa: slope of IOPg in mmHg per 0.1 MPa;
- true IOP 10-25 mmHg: slope of IOPg against IOP (1 = IOPg follows the true IOP).

Slopes are least-squares lines through the points.  Each run is one ``simulate()`` call in this
process, kept as ``<out>/<name>.nc`` (``--reuse`` reads back a run made with the same parameters).
Writes ``validation.csv``/``.json``, ``validation.png`` and prints a markdown table with the
clinical numbers beside it (Goldmann: +2.8 mmHg per 100 um of CCT in population studies, more for
air-puff tonometers; CH of normal eyes about 10.5 mmHg).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _study_common import run_variant, write_tables  # noqa: E402

from airpuff_core import RunParams  # noqa: E402

NORMAL_EYE = {"E0": 0.5, "IOP": 16.0, "thickness": 0.54}
STUDIES = {
    "thickness": (0.45, 0.50, 0.55, 0.60, 0.65),
    "E0": (0.3, 0.5, 0.7, 0.9),
    "IOP": (10.0, 13.0, 16.0, 19.0, 22.0, 25.0),
}
# the slope is given per this change of the swept parameter, in its user unit
SLOPE_PER = {"thickness": (0.1, "mmHg per 100 um"), "E0": (0.1, "mmHg per 0.1 MPa"),
             "IOP": (1.0, "mmHg per mmHg")}
CLINICAL = {"thickness": "+2.8 (Goldmann, population studies); more for air-puff tonometers",
            "E0": "rises with stiffness (finite-element studies of Goldmann tonometry)",
            "IOP": "0.8-1.2 (aim)"}
METRICS = ("IOPg", "P1", "P2", "CH", "DA")


def slope(x, y):
    """Least-squares slope dy/dx of the finite points."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 2:
        return math.nan
    return float(np.polyfit(x[ok], y[ok], 1)[0])


def run_studies(out: Path, resolution: str, corneas, reuse: bool) -> list[dict]:
    rows = []
    for cornea in corneas:
        for name, values in STUDIES.items():
            for v in values:
                point = {**NORMAL_EYE, name: v}
                params = RunParams(resolution=resolution, cornea=cornea, **point)
                label = f"{cornea}_{name}_{v:g}"
                row = run_variant(label, params, out, reuse)
                rows.append({"cornea": cornea, "study": name, "value": v, **point, **row})
    return rows


def summary(rows: list[dict], corneas) -> list[dict]:
    lines = []
    for cornea in corneas:
        for name in STUDIES:
            pts = [r for r in rows if r["cornea"] == cornea and r["study"] == name
                   and r["status"] == "ok"]
            per, unit = SLOPE_PER[name]
            s = slope([r["value"] for r in pts], [r["IOPg"] for r in pts]) * per
            lines.append({"cornea": cornea, "study": name, "slope": s, "unit": unit,
                          "IOPg": [round(r["IOPg"], 2) for r in pts],
                          "values": [r["value"] for r in pts]})
    return lines


def markdown(lines: list[dict], rows: list[dict], resolution: str) -> str:
    out = [f"Resolution {resolution}; about the normal eye E0 {NORMAL_EYE['E0']} MPa, IOP "
           f"{NORMAL_EYE['IOP']:g} mmHg, CCT {NORMAL_EYE['thickness']} mm.", "",
           "| cornea | IOPg against | values | IOPg [mmHg] | slope | clinic |",
           "|---|---|---|---|---|---|"]
    for ln in lines:
        out.append(f"| {ln['cornea']} | {ln['study']} | "
                   f"{', '.join(f'{v:g}' for v in ln['values'])} | "
                   f"{', '.join(f'{v:.2f}' for v in ln['IOPg'])} | {ln['slope']:+.2f} "
                   f"{ln['unit']} | {CLINICAL[ln['study']]} |")
    out += ["", "| cornea | point | " + " | ".join(METRICS) + " |",
            "|---|---|" + "---|" * len(METRICS)]
    for r in rows:
        if r["status"] != "ok":
            out.append(f"| {r['cornea']} | {r['study']} = {r['value']:g} | {r['status']}: "
                       f"{r['message']} |")
            continue
        out.append(f"| {r['cornea']} | {r['study']} = {r['value']:g} | "
                   + " | ".join(f"{r[k]:.3f}" if k == "DA" else f"{r[k]:.2f}" for k in METRICS)
                   + " |")
    return "\n".join(out)


def figure(rows: list[dict], corneas, path: Path, resolution: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    labels = {"thickness": "CCT [mm]", "E0": "E0 [MPa]", "IOP": "true IOP [mmHg]"}
    for ax, name in zip(axes, STUDIES):
        for cornea, marker in zip(corneas, "os^"):
            pts = [r for r in rows if r["cornea"] == cornea and r["study"] == name
                   and r["status"] == "ok"]
            ax.plot([r["value"] for r in pts], [r["IOPg"] for r in pts], marker=marker,
                    label=f"{cornea}")
        if name == "IOP":
            v = np.array(STUDIES["IOP"])
            ax.plot(v, v, "k:", label="IOPg = IOP")
        if name == "thickness":
            v = np.array(STUDIES["thickness"])
            pts = [r for r in rows if r["cornea"] == corneas[-1] and r["study"] == name
                   and r["status"] == "ok" and r["value"] == 0.55]
            if pts:
                ax.plot(v, pts[0]["IOPg"] + 28.0 * (v - 0.55), "k:",
                        label="clinic: +2.8 mmHg/100 um")
        ax.set_xlabel(labels[name])
        ax.set_ylabel("IOPg [mmHg]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"IOPg about the normal eye ({resolution} resolution)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output folder (netCDF per run, CSV, JSON, PNG)")
    ap.add_argument("--resolution", default="coarse", choices=("coarse", "paper", "fine"))
    ap.add_argument("--cornea", action="append", choices=("membrane", "shell"),
                    help="cornea model(s) to study (default: both)")
    ap.add_argument("--reuse", action="store_true", help="read back runs already in --out")
    args = ap.parse_args(argv)
    corneas = args.cornea or ["membrane", "shell"]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = run_studies(out, args.resolution, corneas, args.reuse)
    write_tables(rows, out, "validation")
    lines = summary(rows, corneas)
    figure(rows, corneas, out / "validation.png", args.resolution)
    print(markdown(lines, rows, args.resolution))


if __name__ == "__main__":
    main()
