"""Identification round trip: synthetic measurements from direct solver runs, identified on a sweep.

    airpuff sweep --E0 0.3,0.5,0.7 --IOP 10,14,18,22 --thickness 0.45,0.5,0.55 --cornea shell \\
        --out shell_sweep
    python -m studies.identify_roundtrip --sweep shell_sweep/sweep.nc --out roundtrip

The truths (IOP 12, 16, 20 mmHg x E0 0.4, 0.6 MPa at thickness 0.5 mm, off the sweep's grid in
both directions) are run directly with the sweep's own run options (``run_options_json``, e.g.
the cornea model and the resolution) and kept as ``<out>/<name>.nc`` (``--reuse`` reads them back).
Their metrics, without added noise and with the default sigmas, are identified on the sweep for
four subsets of the measurable metrics.  Prints the solver's values at the truths and a markdown
table: estimate, 68 % interval, whether E0 is identified, the interval's share of the sweep's E0
range, and chi2_min; then the largest errors of the point estimates per subset.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from airpuff_core import RunParams
from studies.common import run_variant
from sweep.identification import IdentifyError, SweepTable, identify

TRUTHS = [(12.0, 0.4), (16.0, 0.4), (20.0, 0.4), (12.0, 0.6), (16.0, 0.6), (20.0, 0.6)]
SUBSETS = {"P1,P2": ("P1", "P2"), "P1,P2,DA": ("P1", "P2", "DA"),
           "DA,t_A1,t_A2": ("DA", "t_A1", "t_A2"), "all 5": ("P1", "P2", "DA", "t_A1", "t_A2")}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sweep", required=True, help="combined sweep.nc of `airpuff sweep`")
    ap.add_argument("--out", required=True, help="folder for the truth runs (netCDF)")
    ap.add_argument("--thickness", type=float, default=0.5, help="thickness of the truths [mm]")
    ap.add_argument("--reuse", action="store_true", help="read back truth runs already in --out")
    args = ap.parse_args(argv)
    table = SweepTable.from_netcdf(args.sweep)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    pmax = float(table.pmax[0])
    print(f"sweep: E0 {table.E0.tolist()} MPa, IOP {table.IOP.tolist()} mmHg, thickness "
          f"{table.thickness.tolist()} mm, options {json.dumps(table.run_options)}")
    rows = {}
    for IOP, E0 in TRUTHS:
        params = RunParams.from_dict({**table.run_options, "IOP": IOP, "E0": E0,
                                      "thickness": args.thickness, "pmax": pmax})
        rows[(IOP, E0)] = run_variant(f"truth_IOP{IOP:g}_E0{E0:g}", params, out, args.reuse)
    print("\n| truth IOP, E0 | P1 | P2 | DA | t_A1 | t_A2 |\n|---|---|---|---|---|---|")
    for (IOP, E0), r in rows.items():
        print(f"| {IOP:g}, {E0:g} | {r['P1']:.2f} | {r['P2']:.2f} | {r['DA']:.4f} | "
              f"{r['t_A1']:.3f} | {r['t_A2']:.3f} |")
    print("\n| subset | truth IOP, E0 | IOP est [68 % interval] | E0 est [68 % interval] | "
          "E0 identified | E0 interval / range | chi2_min |\n|---|---|---|---|---|---|---|")
    worst = {}
    for label, names in SUBSETS.items():
        for (IOP, E0), r in rows.items():
            try:
                est = identify(table, {n: r[n] for n in names}, thickness=args.thickness)
            except IdentifyError as err:
                print(f"| {label} | {IOP:g}, {E0:g} | error: {err} | | | | |")
                continue
            d = est.to_dict()
            print(f"| {label} | {IOP:g}, {E0:g} | {est.IOP:.2f} [{est.IOP_interval[0]:.2f}, "
                  f"{est.IOP_interval[1]:.2f}] | {est.E0:.3f} [{est.E0_interval[0]:.3f}, "
                  f"{est.E0_interval[1]:.3f}] | {'yes' if est.E0_identified else 'no'} | "
                  f"{d['E0_interval_fraction']:.2f} | {est.chi2_min:.2g} |")
            w = worst.setdefault(label, [0.0, 0.0])
            w[0] = max(w[0], abs(est.IOP - IOP))
            w[1] = max(w[1], abs(est.E0 - E0))
    print("\n| subset | max IOP error [mmHg] | max E0 error [MPa] |\n|---|---|---|")
    for label, (dp, de) in worst.items():
        print(f"| {label} | {dp:.2f} | {de:.3f} |")


if __name__ == "__main__":
    main()
