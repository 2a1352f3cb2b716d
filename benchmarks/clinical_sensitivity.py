"""How corneal hysteresis moves with CCT, IOP, E0, ve_g and ve_tau in the clinical model.

    python benchmarks/clinical_sensitivity.py [--resolution coarse] [--out DIR]

One run of the clinical preset (shell cornea, viscoelasticity, compliant globe) at the normal eye
of docs/validation.md (IOP 16 mmHg, CCT 0.54 mm, E0 0.5 MPa, the paper's geometry and jet), then
one parameter at a time below and above it.  Prints a markdown table of P1, P2, CH, IOPg, CRF,
DA and the applanation times, and the slope of CH, IOPg and CRF per unit of each parameter
(central differences), for docs/validation.md.  Each run is one ``simulate()`` in this process;
a failed run is printed with its message.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from airpuff_core import RunParams, SimulationError, simulate
from airpuff_core.dataset import write_netcdf

NORMAL_EYE = {"model": "clinical", "IOP": 16.0, "thickness": 0.54, "E0": 0.5}
# parameter -> (low, high, unit)
VARIATIONS = {
    "thickness": (0.44, 0.64, "mm"),
    "IOP": (12.0, 20.0, "mmHg"),
    "E0": (0.3, 0.7, "MPa"),
    "ve_g": (0.15, 0.45, "1"),
    "ve_tau": (3.0, 30.0, "ms"),
}
SHOWN = ("P1", "P2", "CH", "IOPg", "CRF", "IOPcc_ora", "DA", "t_A1", "t_A2")


def run(label, params, out):
    t0 = time.perf_counter()
    try:
        result = simulate(params)
    except SimulationError as err:
        print(f"| {label} | failed: {err} |", flush=True)
        return None
    if out is not None:
        write_netcdf(result.to_dataset(), out / f"{label.replace(' ', '_')}.nc")
    m = result.metrics
    cells = " | ".join(f"{m[k]:.2f}" if math.isfinite(m[k]) else "-" for k in SHOWN)
    print(f"| {label} | {cells} | {time.perf_counter() - t0:.0f} |", flush=True)
    return m


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", default="coarse", choices=("coarse", "paper", "fine"))
    ap.add_argument("--out", type=Path, default=None, help="keep each run's netCDF here")
    args = ap.parse_args(argv)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
    base = RunParams(**NORMAL_EYE, resolution=args.resolution)
    print(f"clinical preset, normal eye: {NORMAL_EYE}, resolution {args.resolution}, "
          f"ve_g = {base.ve_g:g}, ve_tau = {base.ve_tau:g} ms, globe = {base.globe}, "
          f"cornea = {base.cornea}\n")
    print("| run | " + " | ".join(SHOWN) + " | wall [s] |")
    print("|---|" + "---|" * (len(SHOWN) + 1))
    m0 = run("normal eye", base, args.out)
    slopes = []
    for name, (lo, hi, unit) in VARIATIONS.items():
        m_lo = run(f"{name} {lo:g}", base.replace(**{name: lo}), args.out)
        m_hi = run(f"{name} {hi:g}", base.replace(**{name: hi}), args.out)
        if m_lo is not None and m_hi is not None:
            slopes.append((name, unit, hi - lo, m_lo, m_hi))
    print("\n| parameter | dCH/dx | dIOPg/dx | dCRF/dx | per |")
    print("|---|---|---|---|---|")
    for name, unit, span, m_lo, m_hi in slopes:
        d = {k: (m_hi[k] - m_lo[k]) / span for k in ("CH", "IOPg", "CRF")}
        print(f"| {name} | {d['CH']:.3g} | {d['IOPg']:.3g} | {d['CRF']:.3g} | mmHg per {unit} |")
    if m0 is not None:
        print(f"\nnormal eye: CH = {m0['CH']:.2f} mmHg, IOPg = {m0['IOPg']:.2f} mmHg")


if __name__ == "__main__":
    main()
