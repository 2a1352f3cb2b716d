"""Sensitivity of P1, P2, CH, DA, t_A1, t_A2 to the choices the paper leaves open
(docs/reproduction.md section 4).

    python -m studies.sensitivity --resolution coarse --out sens_coarse
    python -m studies.sensitivity --resolution paper --out sens_paper \
        --variants default,hv_half,c_fixed_30

Every variant is the default run (``RunParams()``) with one change, run as its own ``simulate()``
call, one after the other in this process.  Writes ``<out>/sensitivity_<resolution>.csv`` and
``.json`` (one row per variant, failed runs with their message), keeps each run's netCDF in
``<out>``, and prints a markdown table.  ``--reuse`` reads back runs whose netCDF already exists
with the same parameters (resume an interrupted study).  Nothing here is fitted to the paper.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from airpuff_core import RunParams
from studies.common import PAPER, SHOWN, fmt, run_variant, write_tables

_GAMMA = RunParams().hyperviscosity  # the default stabilisation strength

# name -> (what it tests, changes to the defaults)
VARIANTS: dict[str, tuple[str, dict]] = {
    "default": (f"defaults (running-max c, gamma {_GAMMA:g}, mu 7.5e-4, sector, isotropic)", {}),
    # sound-speed rule, c = c0 + 20 v_max
    "c_per_step": ("c rule per step (the paper's literal rule)", {"c_rule": "per_step"}),
    "c_fixed_10": ("c fixed at 10 m/s", {"c_rule": "fixed", "c0": 10.0}),
    "c_fixed_20": ("c fixed at 20 m/s", {"c_rule": "fixed", "c0": 20.0}),
    "c_fixed_30": ("c fixed at 30 m/s", {"c_rule": "fixed", "c0": 30.0}),
    "c_fixed_50": ("c fixed at 50 m/s (the SPH value the paper quotes)",
                   {"c_rule": "fixed", "c0": 50.0}),
    # stabilisation strength gamma: relative to the default, and a few absolute values
    "hv_half": (f"hyperviscosity halved (gamma {_GAMMA / 2:g})", {"hyperviscosity": _GAMMA / 2}),
    "hv_double": (f"hyperviscosity doubled (gamma {2 * _GAMMA:g})", {"hyperviscosity": 2 * _GAMMA}),
    "hv_x4": (f"hyperviscosity x4 (gamma {4 * _GAMMA:g})", {"hyperviscosity": 4 * _GAMMA}),
    "hv_0.05": ("hyperviscosity gamma 0.05", {"hyperviscosity": 0.05}),
    "hv_0.075": ("hyperviscosity gamma 0.075", {"hyperviscosity": 0.075}),
    "hv_0.1": ("hyperviscosity gamma 0.1", {"hyperviscosity": 0.1}),
    "hv_0.15": ("hyperviscosity gamma 0.15", {"hyperviscosity": 0.15}),
    "hv_0.2": ("hyperviscosity gamma 0.2", {"hyperviscosity": 0.2}),
    # viscosity (default 7.5e-4 Pa s, water at body temperature)
    "mu_0": ("inviscid (mu 0)", {"mu": 0.0}),
    "mu_3e-3": ("mu 3e-3 Pa s (4x water)", {"mu": 3e-3}),
    "mu_0.1": ("mu 0.1 Pa s (an artificial viscosity, 130x water)", {"mu": 0.1}),
    "mu_1": ("mu 1 Pa s (an artificial viscosity, 1300x water)", {"mu": 1.0}),
    "mu_2.5": ("mu 2.5 Pa s (an artificial viscosity, 3300x water)", {"mu": 2.5}),
    "mu_1_c_fixed_30": ("mu 1 Pa s and c fixed at 30 m/s",
                        {"mu": 1.0, "c_rule": "fixed", "c0": 30.0}),
    # chamber and nodes
    "geometry_cap": ("cap geometry (flat rigid plane through the limbus)", {"geometry": "cap"}),
    "layout_polar": ("the paper's polar lattice", {"layout": "polar"}),
    # Fung exponent (default 240)
    "fung_k_0": ("Fung exponent 0 (Saint Venant-Kirchhoff)", {"fung_k": 0.0}),
    "fung_k_1": ("Fung exponent 1", {"fung_k": 1.0}),
    "fung_k_10": ("Fung exponent 10", {"fung_k": 10.0}),
    "fung_k_100": ("Fung exponent 100", {"fung_k": 100.0}),
    "fung_k_1000": ("Fung exponent 1000", {"fung_k": 1000.0}),
}


def markdown(rows: list[dict], resolution: str) -> str:
    ref = next((r for r in rows if r["variant"] == "default" and r["status"] == "ok"), None)
    head = ("| variant | change | P1 | P2 | CH | DA | t_A1 | t_A2 | dP1 | dP2 | sign changes |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|")
    lines = [f"Resolution `{resolution}`; P1, P2, CH in mmHg, DA in mm, t_A1, t_A2 in ms; "
             "dP1, dP2 relative to the default run; sign changes = convex->concave / "
             "concave->convex crossings of the apex curvature (1/1 is a clean puff; A1 is the "
             "first, A2 the last).", "", head]
    lines.append("| paper | (Montanino et al.) | " + " | ".join(
        fmt(PAPER[k]) for k in SHOWN) + " | | | |")
    for r in rows:
        desc = VARIANTS.get(r["variant"], ("", {}))[0]
        if r["status"] != "ok":
            lines.append(f"| {r['variant']} | {desc} | failed: {r['message']} |" + " |" * 8)
            continue
        vals = [fmt(r[k], 3 if k == "DA" else 2) for k in SHOWN]
        d = ["", ""]
        if ref is not None:
            d = [f"{r[k] - ref[k]:+.2f}" if math.isfinite(r[k]) and math.isfinite(ref[k]) else "-"
                 for k in ("P1", "P2")]
        sc = "/".join(fmt(r.get(k, math.nan), 0) for k in ("applanation_crossings_down",
                                                            "applanation_crossings_up"))
        lines.append(f"| {r['variant']} | {desc} | " + " | ".join(vals + d + [sc]) + " |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", choices=("coarse", "paper", "fine"), default="coarse")
    ap.add_argument("--out", required=True, help="output folder (netCDF per run, CSV, JSON)")
    ap.add_argument("--variants", default="all",
                    help="comma-separated variant names, or 'all': " + ", ".join(VARIANTS))
    ap.add_argument("--reuse", action="store_true",
                    help="read back runs whose netCDF exists with the same parameters")
    args = ap.parse_args(argv)
    names = list(VARIANTS) if args.variants == "all" else args.variants.split(",")
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        ap.error(f"unknown variant(s): {', '.join(unknown)}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"sensitivity_{args.resolution}"
    rows = []
    t0 = time.perf_counter()
    for name in names:
        params = RunParams(resolution=args.resolution).replace(**VARIANTS[name][1])
        rows.append(run_variant(name, params, out, args.reuse))
        write_tables(rows, out, stem)  # after every run: a partial study is still a table
    md = markdown(rows, args.resolution)
    (out / f"{stem}.md").write_text(md + "\n")
    print(md)
    print(f"\n{len(rows)} variants in {time.perf_counter() - t0:.0f} s; tables in {out}/{stem}.*")


if __name__ == "__main__":
    main()
