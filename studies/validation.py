"""Clinical validation of the cornea models: IOPg and CH against CCT, E0 and the true IOP.

    python -m studies.validation --out validation                       # coarse, both corneas
    python -m studies.validation --out validation_paper --resolution paper --cornea shell
    python -m studies.validation --out validation_clinical --model clinical
    python -m studies.validation --out validation_clinical --model clinical_kirchhoff --model clinical
    python -m studies.validation --out validation --reuse               # read back finished runs

Three one-parameter studies about the normal eye (E0 0.5 MPa, IOP 16 mmHg, CCT 0.54 mm, the
paper's geometry and jet), for each cornea model asked for:

- CCT (thickness) 0.45-0.65 mm: slope of IOPg in mmHg per 100 um;
- E0 0.3-0.9 MPa: slope of IOPg in mmHg per 0.1 MPa;
- true IOP 10-25 mmHg: slope of IOPg against IOP (1 = IOPg follows the true IOP).

and, with ``--model clinical`` (the clinical preset: shell, viscoelasticity, compliant globe), the
viscoelastic parameters too:

- ve_g 0.15-0.45 and ve_tau 3-30 ms about the preset's 0.3 and 10 ms;
- the transverse shear modulus 6.56-12.4 kPa (the published mean 9.48 +- one SD).

``--model clinical_kirchhoff`` is the clinical preset with the Kirchhoff-Love shell (rigid in
transverse shear), for comparison.

Slopes (of IOPg and of CH) are least-squares lines through the points.  Each run is one ``simulate()`` call in this
process, kept as ``<out>/<name>.nc`` (``--reuse`` reads back a run made with the same parameters).
Writes ``validation.csv``/``.json``, ``validation.png`` and prints a markdown table with the
clinical numbers beside it (Goldmann: +2.8 mmHg per 100 um of CCT in population studies, more for
air-puff tonometers; CH of normal eyes about 10.5 mmHg).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from airpuff_core import RunParams
from studies.common import run_variant, write_tables

NORMAL_EYE = {"E0": 0.5, "IOP": 16.0, "thickness": 0.54}
STUDIES = {
    "thickness": (0.45, 0.50, 0.55, 0.60, 0.65),
    "E0": (0.3, 0.5, 0.7, 0.9),
    "IOP": (10.0, 13.0, 16.0, 19.0, 22.0, 25.0),
}
# studies of the viscoelastic parameters, run for the clinical models only
VISCOELASTIC_STUDIES = {"ve_g": (0.15, 0.3, 0.45), "ve_tau": (3.0, 10.0, 30.0)}
# the transverse shear modulus of the clinical preset's shell: Petsche et al.'s (IOVS 53 (2012)
# 873) full-thickness mean 9.48 kPa and one standard deviation (2.92 kPa) either side
SHEAR_STUDY = {"transverse_shear_modulus": (6.56, 9.48, 12.4)}
# the model presets this script studies (--model): the clinical preset, and the same with the
# Kirchhoff-Love shell (rigid in transverse shear, the clinical preset before the shear)
PRESETS = {"clinical": {"model": "clinical"},
           "clinical_kirchhoff": {"model": "clinical", "transverse_shear_modulus": 0.0}}
# the slope is given per this change of the swept parameter, in its user unit
SLOPE_PER = {"thickness": (0.1, "mmHg per 100 um"), "E0": (0.1, "mmHg per 0.1 MPa"),
             "IOP": (1.0, "mmHg per mmHg"), "ve_g": (0.1, "mmHg per 0.1"),
             "ve_tau": (10.0, "mmHg per 10 ms"),
             "transverse_shear_modulus": (1.0, "mmHg per kPa")}
CLINICAL = {"thickness": "+2.8 (Goldmann, population studies); more for air-puff tonometers",
            "E0": "rises with stiffness (finite-element studies of Goldmann tonometry)",
            "IOP": "0.8-1.2 (aim)", "ve_g": "-", "ve_tau": "-", "transverse_shear_modulus": "-"}
METRICS = ("IOPg", "P1", "P2", "CH", "CRF", "DA", "t_A1", "t_A2")


def slope(x, y):
    """Least-squares slope dy/dx of the finite points."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 2:
        return math.nan
    return float(np.polyfit(x[ok], y[ok], 1)[0])


def studies_of(model: str) -> dict:
    """The one-parameter studies of a model: the viscoelastic ones for the clinical presets, the
    transverse shear modulus for the clinical preset's shear-deformable shell."""
    return {**STUDIES, **(VISCOELASTIC_STUDIES if model in PRESETS else {}),
            **(SHEAR_STUDY if model == "clinical" else {})}


def run_studies(out: Path, resolution: str, models, reuse: bool, only=None) -> list[dict]:
    """``models``: {label: RunParams options}, e.g. {"shell": {"cornea": "shell"}}; ``only``: the
    names of the studies to run (default all of each model's)."""
    rows = []
    for model, options in models.items():
        for name, values in studies_of(model).items():
            if only and name not in only:
                continue
            for v in values:
                point = {**NORMAL_EYE, name: v}
                params = RunParams(resolution=resolution, **options, **point)
                label = f"{model}_{name}_{v:g}"
                row = run_variant(label, params, out, reuse)
                rows.append({"cornea": model, "study": name, "value": v, **point, **row})
    return rows


def summary(rows: list[dict], corneas, only=None) -> list[dict]:
    lines = []
    for cornea in corneas:
        for name in studies_of(cornea):
            if only and name not in only:
                continue
            pts = [r for r in rows if r["cornea"] == cornea and r["study"] == name
                   and r["status"] == "ok"]
            per, unit = SLOPE_PER[name]
            x = [r["value"] for r in pts]
            lines.append({"cornea": cornea, "study": name, "unit": unit,
                          "slope": slope(x, [r["IOPg"] for r in pts]) * per,
                          "slope_CH": slope(x, [r["CH"] for r in pts]) * per,
                          "IOPg": [round(r["IOPg"], 2) for r in pts],
                          "CH": [round(r["CH"], 2) for r in pts], "values": x})
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
    out += ["", "| cornea | CH against | values | CH [mmHg] | slope |", "|---|---|---|---|---|"]
    for ln in lines:
        out.append(f"| {ln['cornea']} | {ln['study']} | "
                   f"{', '.join(f'{v:g}' for v in ln['values'])} | "
                   f"{', '.join(f'{v:.2f}' for v in ln['CH'])} | {ln['slope_CH']:+.2f} "
                   f"{ln['unit']} |")
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


# the clinic's corneal hysteresis of normal eyes (UK Biobank mean; TwinsUK 10.3 +- 1.4), drawn as
# a band in the CH panels
CH_NORMAL = (10.6, 8.9, 11.7)


def figure(rows: list[dict], corneas, path: Path, resolution: str) -> None:
    """IOPg (top row) and CH (bottom row) against CCT, E0 and the true IOP, one line per model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(13, 7.5), squeeze=False)
    labels = {"thickness": "CCT [mm]", "E0": "E0 [MPa]", "IOP": "true IOP [mmHg]"}
    for row_axes, metric in zip(axes, ("IOPg", "CH")):
        for ax, name in zip(row_axes, STUDIES):
            for cornea, marker in zip(corneas, "os^Dv"):
                pts = [r for r in rows if r["cornea"] == cornea and r["study"] == name
                       and r["status"] == "ok"]
                ax.plot([r["value"] for r in pts], [r[metric] for r in pts], marker=marker,
                        label=f"{cornea}")
            v = np.array(STUDIES[name])
            if metric == "IOPg" and name == "IOP":
                ax.plot(v, v, "k:", label="IOPg = IOP")
            if metric == "IOPg" and name == "thickness":
                pts = [r for r in rows if r["cornea"] == corneas[-1] and r["study"] == name
                       and r["status"] == "ok" and r["value"] == 0.55]
                if pts:
                    ax.plot(v, pts[0]["IOPg"] + 28.0 * (v - 0.55), "k:",
                            label="clinic: +2.8 mmHg/100 um")
            if metric == "CH":
                ax.axhspan(CH_NORMAL[1], CH_NORMAL[2], color="0.85", label="clinic: normal CH")
            ax.set_xlabel(labels[name])
            ax.set_ylabel(f"{metric} [mmHg]")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    fig.suptitle(f"IOPg and CH about the normal eye ({resolution} resolution)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output folder (netCDF per run, CSV, JSON, PNG)")
    ap.add_argument("--resolution", default="coarse", choices=("coarse", "paper", "fine"))
    ap.add_argument("--cornea", action="append", choices=("membrane", "shell"),
                    help="cornea model(s) to study (default: both)")
    ap.add_argument("--model", action="append", choices=tuple(PRESETS),
                    help="also (or, without --cornea, only) study this model preset "
                         "(clinical_kirchhoff: the clinical preset with the Kirchhoff-Love shell)")
    ap.add_argument("--reuse", action="store_true", help="read back runs already in --out")
    ap.add_argument("--study", action="append",
                    choices=(*STUDIES, *VISCOELASTIC_STUDIES, *SHEAR_STUDY),
                    help="run only this study (repeatable; default all)")
    args = ap.parse_args(argv)
    corneas = args.cornea or ([] if args.model else ["membrane", "shell"])
    models = {**{c: {"cornea": c} for c in corneas},
              **{m: PRESETS[m] for m in (args.model or [])}}
    corneas = list(models)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = run_studies(out, args.resolution, models, args.reuse, args.study)
    write_tables(rows, out, "validation")
    lines = summary(rows, corneas, args.study)
    figure(rows, corneas, out / "validation.png", args.resolution)
    print(markdown(lines, rows, args.resolution))


if __name__ == "__main__":
    main()
