"""Static applanation of the cornea alone: the jet amplitude that flattens the apex at a fixed IOP.

    python -m studies.static_applanation [--resolution coarse|paper] [--thickness 0.45,0.54,0.65]

No fluid and no time: the cornea (membrane or shell, the run's discrete model on the run's cornea
nodes) carries the IOP p0 inside and the jet's shape exp(-a sin^2 phi) outside, scaled by an
amplitude p_a.  The exact discrete equilibrium is found by Newton's method (continuation in p_a),
and p_a is bisected until the fitted apex curvature is zero.  For a membrane Imbert-Fick gives
p_a = p0; what the shell needs beyond p0 is its static bending stiffness, the part of
IOPg - IOP that owes nothing to the fluid or to inertia (docs/validation.md), for the
Kirchhoff-Love shell (rigid in transverse shear) and the shear-deformable one (``--shear``).
"""

from __future__ import annotations

import argparse

import numpy as np

from airpuff_core import RunParams
from airpuff_core.cornea.apex import apex_curvature, apex_fit_nodes
from airpuff_core.cornea.build import cornea_for_run
from airpuff_core.cornea.reference import static_equilibrium
from airpuff_core.geometry import build_chamber
from airpuff_core.params import MMHG_PA

STEP_MMHG = 5.0  # continuation step of the jet amplitude


def applanating_amplitude(params: RunParams, bisections: int = 30) -> tuple[float, float]:
    """(jet amplitude [mmHg] that makes the apex curvature zero, apex depth [mm] there)."""
    si = params.si()
    ch = build_chamber(params.geometry, params.layout, params.resolution, si.R_m, si.r_post_m,
                       si.alpha0_rad)
    phi = ch.phi_cornea
    model = cornea_for_run(params, phi)
    X0, Y0 = si.R_m * np.sin(phi), si.R_m * np.cos(phi)
    X, Y, _ = static_equilibrium(model, X0, Y0, np.full(phi.shape, si.p0_Pa))
    apex_rest = Y[0]
    n_fit = apex_fit_nodes(X)
    shape = np.exp(-si.a * np.sin(phi) ** 2)

    def solve(p_a, X, Y):
        Xs, Ys, _ = static_equilibrium(model, X, Y, si.p0_Pa - p_a * shape)
        return apex_curvature(Xs, Ys, n_fit), Xs, Ys

    lo, hi = 0.0, STEP_MMHG * MMHG_PA
    while True:  # continuation: each solve starts from the last convex state
        kappa, Xs, Ys = solve(hi, X, Y)
        if kappa <= 0.0:
            break
        lo, X, Y = hi, Xs, Ys
        hi += STEP_MMHG * MMHG_PA
    for _ in range(bisections):
        mid = 0.5 * (lo + hi)
        kappa, Xs, Ys = solve(mid, X, Y)
        if kappa > 0.0:
            lo, X, Y = mid, Xs, Ys
        else:
            hi = mid
    return 0.5 * (lo + hi) / MMHG_PA, (apex_rest - Y[0]) * 1e3


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", default="coarse", choices=("coarse", "paper", "fine"))
    ap.add_argument("--thickness", default="0.45,0.54,0.65", help="comma list [mm]")
    ap.add_argument("--shear", default="9.48", help="transverse shear modulus G_t [kPa] of the "
                    "shear-deformable shell (default: the clinical preset's)")
    args = ap.parse_args(argv)
    G_t = float(args.shear)
    print(f"static applanation at IOP 16 mmHg, E0 0.5 MPa, {args.resolution} cornea nodes; "
          f"shear-deformable shell with G_t = {G_t:g} kPa")
    print("| CCT [mm] | membrane: jet [mmHg] | Kirchhoff shell: jet [mmHg] | - membrane | "
          "Mindlin shell: jet [mmHg] | - membrane | Mindlin apex depth [mm] |\n"
          "|---|---|---|---|---|---|---|")
    rows = []
    for h in (float(v) for v in args.thickness.split(",")):
        base = RunParams(resolution=args.resolution, thickness=h)
        membrane, _ = applanating_amplitude(base.replace(cornea="membrane"))
        kirchhoff, _ = applanating_amplitude(base.replace(cornea="kirchhoff"))
        mindlin, depth = applanating_amplitude(base.replace(cornea="mindlin",
                                                            transverse_shear_modulus=G_t))
        rows.append((h, kirchhoff, mindlin))
        print(f"| {h:g} | {membrane:.2f} | {kirchhoff:.2f} | {kirchhoff - membrane:+.2f} | "
              f"{mindlin:.2f} | {mindlin - membrane:+.2f} | {depth:.3f} |")
    if len(rows) > 1:
        h, pk, pm = np.array(rows).T
        print(f"slopes (least squares): Kirchhoff {np.polyfit(h, pk, 1)[0] * 0.1:+.2f}, "
              f"Mindlin {np.polyfit(h, pm, 1)[0] * 0.1:+.2f} mmHg per 100 um")


if __name__ == "__main__":
    main()
