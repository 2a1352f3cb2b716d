"""Where the default Fung exponent comes from: python -m studies.fung_exponent

The simplified isotropic Fung law of the membrane, W = C/2 (exp(Q) - 1),
Q = k (E1^2 + E2^2 + 2 nu E1 E2), C k = E0 h / (1 - nu^2), has the small-strain Young's modulus E0
for every k; k only sets how fast the cornea stiffens as it is stretched.  Under the IOP the
cornea is in an equibiaxial state (Laplace), and its tangent Young's modulus there is

    E_t(IOP) = E0 * (dN/dE at the prestretch) / (dN/dE at zero strain),

N the equibiaxial membrane force.  Orssengo and Pye (1999, Bull. Math. Biol. 61:551-572) give the
in-vivo tangent modulus of the human cornea as proportional to the IOP, E = 0.0229 MPa/mmHg x IOP.
The paper fixes the level of the modulus (E0 = 0.5 MPa); the data fix its rate of increase with
IOP.  This script finds the k at which dE_t/dIOP = 0.0229 MPa/mmHg at the default IOP (16 mmHg),
with the paper's geometry (R = 7 mm, h = 0.5 mm, nu = 0.5).  It runs no simulation.
"""

from __future__ import annotations

import math

from airpuff_core import RunParams
from airpuff_core.cornea.reference import prestretch
from airpuff_core.params import MMHG_PA

SLOPE_ORSSENGO_PYE = 0.0229  # MPa per mmHg


def tangent_modulus(k: float, iop_mmhg: float, p: RunParams) -> tuple[float, float]:
    """(E_t [Pa], prestretch) of the equibiaxial membrane at IOP ``iop_mmhg``."""
    si = p.si()
    E0, h, nu, R = si.E0_Pa, si.thickness_m, si.nu, si.R_m
    Ebar = E0 * h / (1.0 - nu * nu)
    lam = prestretch(iop_mmhg * MMHG_PA, R, Ebar, nu, k)
    E = 0.5 * (lam * lam - 1.0)

    def N(e):  # equibiaxial second Piola-Kirchhoff membrane force
        return Ebar * math.exp(2.0 * k * (1.0 + nu) * e * e) * (1.0 + nu) * e

    d = 1e-7
    dNdE = (N(E + d) - N(E - d)) / (2 * d)
    return E0 * dNdE / (Ebar * (1.0 + nu)), lam


def slope(k: float, p: RunParams, iop: float) -> float:
    """dE_t/dIOP [MPa/mmHg] at ``iop`` (central difference over +-0.5 mmHg)."""
    return (tangent_modulus(k, iop + 0.5, p)[0] - tangent_modulus(k, iop - 0.5, p)[0]) / 1e6


def main():
    p = RunParams()
    iop = p.IOP
    print(f"E0 = {p.E0} MPa, IOP = {iop} mmHg, R = {p.R} mm, h = {p.thickness} mm, nu = {p.nu}")
    print("| k | prestretch | E_t at IOP [MPa] | dE_t/dIOP [MPa/mmHg] |")
    print("|---|---|---|---|")
    for k in (0, 1, 10, 100, 240, 1000):
        Et, lam = tangent_modulus(k, iop, p)
        print(f"| {k} | {lam:.5f} | {Et / 1e6:.3f} | {slope(k, p, iop):.4f} |")
    lo, hi = 1.0, 1000.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if slope(mid, p, iop) < SLOPE_ORSSENGO_PYE else (lo, mid)
    print(f"\nk matching dE_t/dIOP = {SLOPE_ORSSENGO_PYE} MPa/mmHg (Orssengo & Pye 1999): "
          f"{lo:.1f}; default fung_k = {p.fung_k:g}")


if __name__ == "__main__":
    main()
