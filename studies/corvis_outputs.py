"""The Corvis ST's outputs of the clinical preset's normal eye against the Corvis normals, DA's
slope against the IOP, and Kling's orbit against a measured whole-eye movement (docs/validation.md,
"The Corvis outputs"; docs/model.md section 14).

The clinical preset (CCT 0.54 mm, E0 0.5 MPa) with the whole eye on Kling's orbit
(``eye_motion = spring_damper``, its defaults), at each IOP; ``--set name=value`` adds any run
parameter (e.g. the instrument's pulse).  Per IOP: A1T, A2T, HC time, DA, the deflection amplitude,
WEM (max, time, at HC), the peak distance and the apex velocities at A1 and A2; then the least-
squares slope of DA and of the deflection amplitude against the IOP.  At IOP 16 the run's
recorded pulse force drives a 7.5 g eye on other orbits (``SpringDamperEye``): for each damper c,
the spring k whose WEM peaks at the measured 21.07 ms, the WEM it gives, and the eye's largest
acceleration as the pressure rho |a| L it would put across the chamber (depth L = R - r_post).

    python -m studies.corvis_outputs --out corvis_coarse
    python -m studies.corvis_outputs --out corvis_paper --resolution paper

Every finished run is kept as <out>/<name>.nc; --reuse reads back a run whose file has the same
parameters.  The tables go to <out>/table.md.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from airpuff_core import RunParams
from airpuff_core.dataset import open_dataset
from airpuff_core.globe.motion import SpringDamperEye
from airpuff_core.params import parse_decimal

from .common import run_variant

# Corvis ST normals, 1,304 healthy eyes (PMC7001013; docs/sources.md section 4)
NORMALS = {"t_A1": "7.36 +- 0.39", "t_A2": "20.13 +- 0.48", "t_HC": "16.84 +- 0.64",
           "DA": "1.05 +- 0.10", "peak_distance": "4.60 +- 1.01", "v_A1": "0.12 +- 0.04",
           "v_A2": "-0.67 +- 0.17", "t_WEM_max": "21.07 +- 0.51 (preprint, 68 eyes)",
           "WEM_max": "order 0.27 (knot, 1,640 eyes)"}
SHOWN = (("t_A1", "ms", 2), ("t_A2", "ms", 2), ("t_HC", "ms", 2), ("DA", "mm", 3),
         ("deflection_amplitude", "mm", 3), ("deflection_amplitude_HC", "mm", 3),
         ("WEM_max", "mm", 4), ("t_WEM_max", "ms", 2), ("WEM_HC", "mm", 4),
         ("peak_distance", "mm", 2), ("v_A1", "m/s", 3), ("v_A2", "m/s", 3),
         ("P1", "mmHg", 2), ("P2", "mmHg", 2))
WEM_PEAK_TIME = 21.07e-3  # s, the measured peak of the whole-eye movement
# N s/m; an undamped orbit (0) peaks again and again, and which peak falls at 21 ms is ambiguous
DAMPERS = (0.25, 0.5, 1.0, 2.0)


def eye_on_orbit(t, force, mass, spring, damper, dt=5e-6):
    """(peak displacement [m], its time [s], largest |acceleration| [m/s^2]) of a
    ``SpringDamperEye`` under the force history ``force`` [N] at times ``t`` [s]."""
    steps = np.arange(0.0, t[-1], dt)
    f = np.interp(steps, t, force)
    eye = SpringDamperEye(mass, spring, damper)
    eye.start(f[0])
    x, a = np.zeros_like(steps), np.zeros_like(steps)
    a[0] = eye.acceleration
    for i in range(1, steps.shape[0]):
        eye.advance(dt, lambda: f[i])
        x[i], a[i] = eye.displacement, eye.acceleration
    return float(x.max()), float(steps[np.argmax(x)]), float(np.abs(a).max())


def orbit_scan(ds) -> list[str]:
    """Lines of the table of orbits whose WEM peaks at the measured time (module docstring)."""
    from scipy.optimize import brentq

    t, force = ds.time.values * 1e-3, ds.pulse_force.values * 1e-3
    mass = float(ds.eye_mass) * 1e-3
    depth = (float(ds.R) - float(ds.r_post)) * 1e-3
    rho = float(ds.rho_fluid)
    lines = ["| c [N s/m] | k [N/m] | WEM max [mm] | at [ms] | max abs(a) [m/s^2] | "
             "rho a L [mmHg] |", "|---|---|---|---|---|---|"]
    kling = (float(ds.eye_damper), float(ds.eye_spring))
    for c, k in [(kling[0], kling[1])] + [(c, None) for c in DAMPERS]:
        if k is None:
            k = brentq(lambda s: eye_on_orbit(t, force, mass, s, c)[1] - WEM_PEAK_TIME,
                       50.0, 1500.0, xtol=0.5)
        x, tx, a = eye_on_orbit(t, force, mass, k, c)
        lines.append(f"| {c:g} | {k:.0f} | {x * 1e3:.4f} | {tx * 1e3:.2f} | {a:.2f} | "
                     f"{rho * a * depth / 133.322:.4f} |")
    impulse = float(np.trapezoid(force, t))
    lines.append(f"\npulse force: peak {force.max() * 1e3:.1f} mN at "
                 f"{t[np.argmax(force)] * 1e3:.2f} ms, impulse {impulse:.3e} N s")
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--resolution", default="coarse")
    ap.add_argument("--IOP", default="10,13,16,20,25,30", help="comma-separated IOPs [mmHg]")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="another run parameter (repeatable)")
    ap.add_argument("--reuse", action="store_true")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    extra = {}
    for item in args.set:
        name, value = item.split("=", 1)
        try:
            extra[name] = parse_decimal(value)
        except ValueError:
            extra[name] = value
    iops = [parse_decimal(v) for v in args.IOP.split(",")]
    rows = {}
    for iop in iops:
        params = RunParams(model="clinical", thickness=0.54, IOP=iop, eye_motion="spring_damper",
                           resolution=args.resolution, **extra)
        name = f"corvis_IOP{iop:g}"
        row = run_variant(name, params, args.out, args.reuse)
        if row["status"] == "ok":
            with open_dataset(args.out / f"{name}.nc") as ds:
                rows[iop] = {k: float(ds[k]) for k, _, _ in SHOWN}
                if iop == 16.0:
                    scan = orbit_scan(ds)
    head = "| IOP [mmHg] | " + " | ".join(f"{k} [{u}]" for k, u, _ in SHOWN) + " |"
    lines = [f"Clinical preset, CCT 0.54 mm, eye on Kling's orbit, resolution {args.resolution}"
             + (f", {extra}" if extra else ""), "", head,
             "|" + "---|" * (len(SHOWN) + 1)]
    for iop, row in rows.items():
        lines.append(f"| {iop:g} | " + " | ".join(
            "-" if not math.isfinite(row[k]) else f"{row[k]:.{nd}f}" for k, _, nd in SHOWN) + " |")
    lines.append("| Corvis normals | " + " | ".join(NORMALS.get(k, "") for k, _, _ in SHOWN) + " |")
    if len(rows) >= 2:
        lines.append("")
        x = np.array(list(rows))
        for k in ("DA", "deflection_amplitude", "t_A1", "t_A2", "t_HC"):
            y = np.array([rows[i][k] for i in rows])
            ok = np.isfinite(y)
            slope = np.polyfit(x[ok], y[ok], 1)[0]
            lines.append(f"- slope of {k} against IOP ({x[ok].min():g}-{x[ok].max():g} mmHg): "
                         f"{slope:+.4f} per mmHg")
    if 16.0 in rows:
        lines += ["", "Orbits under the IOP 16 run's pulse force (7.5 g eye): Kling's, then for "
                  "each damper the spring whose WEM peaks at 21.07 ms", ""] + scan
    text = "\n".join(lines) + "\n"
    (args.out / "table.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
