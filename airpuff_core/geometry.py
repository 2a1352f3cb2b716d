"""Reference configuration of the anterior chamber: fluid nodes, their kinds, spacing and volumes.

Meridian half-plane x >= 0 (x: distance from the axis, y: along the axis), origin at the centre of
the corneal sphere, apex at (0, R).  Two chamber shapes (docs/model.md section 2):

- ``sector``: r_post <= rho <= R, 0 <= phi <= alpha0 (the paper's spherical sector);
- ``cap``: rho <= R above the plane y = R cos(alpha0) through the limbus.

Two node layouts: ``isotropic`` rings of constant rho whose node count grows with rho (about equal
spacing in both directions, the default) and the paper's ``polar`` lattice (n_rho x n_phi).  In both
the outer ring rho = R is the cornea: its nodes are the membrane nodes, apex first.

Each node gets a local spacing h (m), its area in the meridian plane (m^2) and its volume of
revolution (m^3); areas and volumes come from a fine sampling of the domain (nearest node), scaled
so that they add up to the exact area and volume of the chamber.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .kernels.membrane import cornea_polygon_volume
from .kernels.neighbours import nearest_node_sums
from .kernels.nodes import AXIS, CORNEA, INTERIOR, WALL

# target fluid node counts (docs/model.md section 2) and the polar lattices (n_rho, n_phi)
TARGET_NODES = {"coarse": 300, "paper": 1134, "fine": 4500}
POLAR_LATTICE = {"coarse": (14, 21), "paper": (27, 42), "fine": (54, 84)}


@dataclass
class Chamber:
    x: np.ndarray  # m
    y: np.ndarray  # m
    kind: np.ndarray  # int8: INTERIOR, AXIS, WALL, CORNEA
    h: np.ndarray  # m, local node spacing
    area: np.ndarray  # m^2, area in the meridian plane
    volume: np.ndarray  # m^3, volume of revolution
    cornea_nodes: np.ndarray  # indices of the cornea nodes, apex first
    phi_cornea: np.ndarray  # rad, reference angle of each cornea node

    @property
    def n(self) -> int:
        return self.x.shape[0]


def exact_area(geometry, R, r_post, alpha0):
    if geometry == "sector":
        return 0.5 * alpha0 * (R * R - r_post * r_post)
    return 0.5 * R * R * (alpha0 - math.sin(alpha0) * math.cos(alpha0))


def exact_volume(geometry, R, r_post, alpha0):
    if geometry == "sector":
        return 2.0 * math.pi / 3.0 * (R ** 3 - r_post ** 3) * (1.0 - math.cos(alpha0))
    H = R * (1.0 - math.cos(alpha0))
    return math.pi * H * H * (3.0 * R - H) / 3.0


def _ring_nodes(rho, phi_end, spacing, include_end=True):
    n = max(1, int(round(rho * phi_end / spacing)))
    phis = np.linspace(0.0, phi_end, n + 1)
    return phis if include_end else phis[:-1]


def _sector_kind(ring, j, n_rings, n_on_ring):
    """Kind of node j on ring ``ring`` of the sector: the outer ring is the cornea, the inner ring
    and the last node of every ring (the lateral wall) are rigid, the first node is on the axis."""
    if ring == n_rings - 1:
        return CORNEA
    if ring == 0 or j == n_on_ring - 1:
        return WALL
    return AXIS if j == 0 else INTERIOR


def _sector_isotropic(R, r_post, alpha0, n_rings):
    dr = (R - r_post) / (n_rings - 1)
    xs, ys, kinds = [], [], []
    for i in range(n_rings):
        rho = r_post + i * dr
        phis = _ring_nodes(rho, alpha0, dr)
        for j, ph in enumerate(phis):
            xs.append(rho * math.sin(ph))
            ys.append(rho * math.cos(ph))
            kinds.append(_sector_kind(i, j, n_rings, len(phis)))
    h = np.full(len(xs), dr)
    return np.array(xs), np.array(ys), np.array(kinds, np.int8), h


def _sector_polar(R, r_post, alpha0, n_rho, n_phi):
    dr = (R - r_post) / (n_rho - 1)
    dphi = alpha0 / (n_phi - 1)
    xs, ys, kinds, hs = [], [], [], []
    for i in range(n_rho):
        rho = r_post + i * dr
        for j in range(n_phi):
            ph = j * dphi
            xs.append(rho * math.sin(ph))
            ys.append(rho * math.cos(ph))
            kinds.append(_sector_kind(i, j, n_rho, n_phi))
            hs.append(max(dr, rho * dphi))
    return np.array(xs), np.array(ys), np.array(kinds, np.int8), np.array(hs)


def _cap_isotropic(R, alpha0, spacing):
    yb = R * math.cos(alpha0)
    xl = R * math.sin(alpha0)
    xs, ys, kinds = [], [], []
    # outer ring: the cornea, apex to limbus (the limbus lies on the plane)
    for ph in _ring_nodes(R, alpha0, spacing):
        xs.append(R * math.sin(ph))
        ys.append(R * math.cos(ph))
        kinds.append(CORNEA)
    # inner rings, clipped by the plane; keep half a spacing off the plane
    i = 1
    while True:
        rho = R - i * spacing
        if rho - yb < 0.5 * spacing:
            break
        phi_end = math.acos(yb / rho)
        for j, ph in enumerate(_ring_nodes(rho, phi_end, spacing, include_end=False)):
            y = rho * math.cos(ph)
            if y - yb < 0.5 * spacing:
                continue
            xs.append(rho * math.sin(ph))
            ys.append(y)
            kinds.append(AXIS if j == 0 else INTERIOR)
        i += 1
    # the rigid plane, axis to (but without) the limbus
    m = max(1, int(round(xl / spacing)))
    for j in range(m):
        xs.append(j * xl / m)
        ys.append(yb)
        kinds.append(WALL)
    h = np.full(len(xs), spacing)
    return np.array(xs), np.array(ys), np.array(kinds, np.int8), h


def _inside(geometry, x, y, R, r_post, alpha0):
    rho = np.hypot(x, y)
    if geometry == "sector":
        phi = np.arctan2(x, y)
        return (rho >= r_post) & (rho <= R) & (phi <= alpha0) & (x >= 0)
    return (rho <= R) & (y >= R * math.cos(alpha0)) & (x >= 0)


def _areas_and_volumes(geometry, x, y, h, R, r_post, alpha0, per_spacing=8):
    ds = h.min() / per_spacing
    gx = np.arange(ds / 2, x.max() + ds, ds)
    gy = np.arange(y.min() - ds / 2, y.max() + ds, ds)
    SX, SY = np.meshgrid(gx, gy, indexing="ij")
    inside = _inside(geometry, SX, SY, R, r_post, alpha0)
    sx, sy = SX[inside].copy(), SY[inside].copy()
    area = np.zeros_like(x)
    vol = np.zeros_like(x)
    nearest_node_sums(x, y, sx, sy, h.max(), area, vol, ds * ds)
    if np.any(area <= 0):
        raise RuntimeError("a fluid node received no area: node layout is degenerate")
    area *= exact_area(geometry, R, r_post, alpha0) / area.sum()
    vol *= exact_volume(geometry, R, r_post, alpha0) / vol.sum()
    return area, vol


def _isotropic_rings_for(target, R, r_post, alpha0):
    best = None
    for n_rings in range(4, 200):
        x, _, _, _ = _sector_isotropic(R, r_post, alpha0, n_rings)
        err = abs(len(x) - target)
        if best is None or err < best[0]:
            best = (err, n_rings)
        if len(x) > target:
            break
    return best[1]


def build_chamber(geometry, layout, resolution, R, r_post, alpha0) -> Chamber:
    """Reference chamber in SI units (R, r_post in m, alpha0 in rad)."""
    x, y, kind, h = _nodes(geometry, layout, resolution, R, r_post, alpha0)
    cornea = np.flatnonzero(kind == CORNEA)
    phi = np.arctan2(x[cornea], y[cornea])
    order = np.argsort(phi)
    cornea, phi = cornea[order], phi[order]
    area_, vol = _areas_and_volumes(geometry, x, y, h, R, r_post, alpha0)
    return Chamber(x, y, kind, h, area_, vol, cornea, phi)


def smallest_spacing(geometry, layout, resolution, R, r_post, alpha0) -> float:
    """h_min [m]: the smallest node spacing of the chamber ``build_chamber`` makes (without
    computing its areas)."""
    return float(_nodes(geometry, layout, resolution, R, r_post, alpha0)[3].min())


def _nodes(geometry, layout, resolution, R, r_post, alpha0):
    """(x, y, kind, h) of the chamber's nodes."""
    if geometry == "sector":
        if layout == "polar":
            n_rho, n_phi = POLAR_LATTICE[resolution]
            x, y, kind, h = _sector_polar(R, r_post, alpha0, n_rho, n_phi)
        else:
            n_rings = _isotropic_rings_for(TARGET_NODES[resolution], R, r_post, alpha0)
            x, y, kind, h = _sector_isotropic(R, r_post, alpha0, n_rings)
    else:
        # (RunParams.validate allows no polar layout here: the polar lattice is a sector's)
        # spacing that gives about the target count in the cap's area
        area = exact_area("cap", R, r_post, alpha0)
        spacing = math.sqrt(area / TARGET_NODES[resolution])
        x, y, kind, h = _cap_isotropic(R, alpha0, spacing)
    return x, y, kind, h


def chamber_volume(geometry, xc, yc, r_post, alpha0) -> float:
    """Volume of the chamber [m^3] bounded by the cornea polyline (xc, yc), apex first.

    The region between the axis, the cornea and the straight closing line(s) is a polygon in the
    meridian plane; its volume of revolution is the sum of cone frusta (Pappus):
    V = pi/3 sum (x_a^2 + x_a x_b + x_b^2)(y_a - y_b) around the polygon, taken clockwise.
    ``sector``: polygon origin-apex-cornea-limbus-origin minus the posterior sector;
    ``cap``: polygon (0, y_limbus)-apex-cornea-limbus.
    """
    if geometry == "sector":
        inner = 2.0 * math.pi / 3.0 * r_post ** 3 * (1.0 - math.cos(alpha0))
        return cornea_polygon_volume(xc, yc, 0.0) - inner
    return cornea_polygon_volume(xc, yc, yc[-1])
