"""The shell cornea: the membrane of ``membrane.py`` with bending stiffness (SI units).

Discrete energy (``kernels/shell.py``): the membrane's segment energies plus nodal bending energies
A_i W_bending(K_s, K_theta) in Reissner's bending strains, large rotations, apex symmetry, limbus
clamped (default) or pinned.

Constitutive choice: the linear bending law W = D/2 (K_s^2 + K_theta^2 + 2 nu K_s K_theta) with the
plate rigidity D = E0 h^3 / (12 (1 - nu^2)), beside the Fung membrane.  The energy splits into
membrane and bending, so D = 0 is the membrane exactly and the two laws can be checked separately
(the clamped plate, the shallow cap).  Integrating the Fung law through the thickness would couple
them: it stiffens bending with the prestrain (by the Fung tangent factor, about 1.35 at the default
IOP, E0 and k = 240) and with the bending strain itself (h K / 2 reaches 0.04 at applanation).  The
linear law therefore underestimates the bending stiffness of the Fung material by up to this factor.

Rest state: the stress-free reference is the homothetic arc of radius R / lambda0 (the membrane's
prestretch).  A homothety keeps every angle, so the drawn arc has no bending strain and carries the
IOP by membrane tension alone; the discrete equilibrium (Newton, ``static_equilibrium``) differs
from it by the membrane's O(dphi^2) and is reported by the run.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .kernels.membrane import add_pressure_loads, max_wave_speed
from .kernels.shell import (LIMBUS_CLAMPED, LIMBUS_PINNED, advance_shell, bending_moments,
                            max_bending_frequency, shell_energy, shell_internal_forces,
                            shell_strains, shell_work, work_rows)
from .membrane import MEMBRANE_SAFETY, MembraneModel, build_membrane

# the history arguments of the shell kernels without viscoelasticity (not read)
NO_HISTORY = (np.zeros((4, 1)), np.zeros((1, 4, 1)), np.ones(1), np.zeros(1))
LIMBUS_CONDITIONS = {"clamped": LIMBUS_CLAMPED, "pinned": LIMBUS_PINNED}


def plate_rigidity(E0, h, nu):
    """D = E0 h^3 / (12 (1 - nu^2)) [N m] for E0 [Pa], h [m]."""
    return E0 * h ** 3 / (12.0 * (1.0 - nu * nu))


def bending_reference(X_ref, Y_ref):
    """Reference quantities of the bending energy on the stress-free meridian (X_ref, Y_ref) [m],
    apex first: segment angles psi_ref [rad], dual lengths l [m] (L0_0 at the apex, the mean of
    the two chords inside, half the last chord at the limbus), x_ref [m] and the nodal areas A_i
    [m^2] (the surface of revolution of the half-segments beside each node)."""
    dx, dy = np.diff(X_ref), np.diff(Y_ref)
    L0 = np.hypot(dx, dy)
    psi_ref = np.arctan2(-dy, dx)
    dual = np.concatenate(([L0[0]], 0.5 * (L0[:-1] + L0[1:]), [0.5 * L0[-1]]))
    xm = 0.5 * (X_ref[:-1] + X_ref[1:])
    half_left = 0.5 * math.pi * (X_ref[:-1] + xm) * L0  # half-segment beside its first node
    half_right = 0.5 * math.pi * (xm + X_ref[1:]) * L0
    area = np.zeros(X_ref.shape[0])
    area[:-1] += half_left
    area[1:] += half_right
    return psi_ref, dual, np.asarray(X_ref, dtype=float).copy(), area


@dataclass
class ShellModel(MembraneModel):
    """Discrete shell: the membrane's data plus the bending reference and rigidity (SI)."""

    psi_ref: np.ndarray = None  # reference segment angles [rad]
    dual_length: np.ndarray = None  # reference length of each node's bending cell [m]
    x_ref: np.ndarray = None  # reference distance of each node from the axis [m]
    node_area: np.ndarray = None  # reference area of each node's bending cell [m^2]
    D: float = 0.0  # bending rigidity [N m]
    limbus: int = LIMBUS_CLAMPED

    def __post_init__(self):
        self.work = shell_work(self.n)
        self._forces = tuple(np.empty(self.n) for _ in range(3))  # Fx, Fy [N], load q [Pa]

    @property
    def stencil(self):
        """The force on a node depends on the nodes up to two away (one without bending)."""
        return 2 if self.D != 0.0 else 1

    def bending_args(self):
        """The bending arguments of the shell kernels, in their order."""
        return (self.psi_ref, self.dual_length, self.x_ref, self.node_area, self.limbus)

    def forces(self, X, Y, q):
        """Total nodal forces [N] at positions (X, Y) under net inside pressure q [Pa]."""
        Fx = np.empty_like(X)
        Fy = np.empty_like(Y)
        shell_internal_forces(X, Y, self.L0, self.S0, self.A0, *self.bending_args(), self.Ebar,
                              self.nu, self.k, self.D, self.work, Fx, Fy, 0, *NO_HISTORY)
        add_pressure_loads(X, Y, q, Fx, Fy)
        return Fx, Fy

    def apex_moment(self, X, Y, overstress=None):
        """Meridional bending moment M_s at the apex [N m/m] at positions (X, Y) [m]: the bending
        law's, plus the viscoelastic overstress (``ViscoelasticHistory.overstress``) if given;
        0 for the membrane."""
        if self.D == 0.0:
            return 0.0
        E1, E2, psi, _, _, _, Ks, Kt, Ms, Mt = work_rows(self.work, self.n)
        shell_strains(X, Y, self.L0, self.S0, self.psi_ref, self.dual_length, self.x_ref,
                      self.limbus, self.D, E1, E2, psi, Ks, Kt)
        bending_moments(Ks, Kt, self.D, self.nu, Ms, Mt)
        extra = 0.0 if overstress is None else float(overstress[:, 2, 0].sum())
        return float(Ms[0]) + extra

    def energy(self, X, Y):
        """(membrane, bending) elastic energy [J] at positions (X, Y) [m]."""
        return shell_energy(X, Y, self.L0, self.S0, self.A0, *self.bending_args(), self.Ebar,
                            self.nu, self.k, self.D, self.work)

    def max_frequency(self, X, Y):
        """Upper estimate of the highest frequency [rad/s] of the current state: in-plane waves
        (2 c / L_min, c from the Fung tangent) and bending waves (``max_bending_frequency``),
        added in squares."""
        c = max_wave_speed(X, Y, self.L0, self.S0, self.Ebar, self.nu, self.k, self.rho_h)
        omega_membrane = 2.0 * c / self.L0.min()
        omega_bending = max_bending_frequency(self.dual_length, self.D, self.rho_h)
        return math.hypot(omega_membrane, omega_bending)

    def stable_substep(self, X, Y):
        """Verlet sub-step [s]: MEMBRANE_SAFETY * 2 / omega_max (Verlet is stable below
        2 / omega_max)."""
        return MEMBRANE_SAFETY * 2.0 / self.max_frequency(X, Y)

    def substeps(self, X, Y, dt):
        """Verlet sub-steps that resolve the fastest wave of the state (X, Y) [m] in a step of dt
        [s]: dt / n <= ``stable_substep``; with D = 0 exactly the membrane's rule."""
        if self.D == 0.0:
            return super().substeps(X, Y, dt)
        return max(1, int(math.ceil(dt / self.stable_substep(X, Y))))

    def advance(self, X, Y, VX, VY, p_start, p_end, t_start, dt, n_sub, jet, history=None):
        """Advance the state (X, Y [m], VX, VY [m/s], in place) from t_start to t_start + dt [s] in
        n_sub Verlet sub-steps, with the fluid pressure on the cornea going linearly from p_start
        to p_end [Pa] and the air jet ``jet`` (``SIParams.jet()``) outside.  ``history``: the
        viscoelastic trial history (``ViscoelasticHistory.begin_trial()``), advanced in place,
        or None for an elastic cornea."""
        Fx, Fy, q = self._forces
        advance_shell(X, Y, VX, VY, self.mass, self.phi, self.L0, self.S0, self.A0,
                      *self.bending_args(), self.Ebar, self.nu, self.k, self.D, p_start, p_end,
                      t_start, dt, n_sub, jet, self.work, Fx, Fy, q, history is not None,
                      *(NO_HISTORY if history is None else history))


def build_shell(phi, R, p0, E0, h, nu, k, rho_c, limbus="clamped", bending=True) -> ShellModel:
    """Shell on reference angles ``phi`` (apex first), prestressed by p0 [Pa] on the drawn arc of
    radius R [m]: the membrane of ``build_membrane`` with D = E0 h^3 / (12 (1 - nu^2)), or with
    D = 0 (the paper's membrane, computed by the same kernels bit for bit) when not ``bending``."""
    membrane = build_membrane(phi, R, p0, E0, h, nu, k, rho_c)
    X_ref = membrane.R_ref * np.sin(phi)
    Y_ref = membrane.R_ref * np.cos(phi)
    D = plate_rigidity(E0, h, nu) if bending else 0.0
    return _with_bending(membrane, X_ref, Y_ref, D, limbus)


def shell_on_meridian(X_ref, Y_ref, E0, h, nu, k, rho_c, limbus="clamped") -> ShellModel:
    """Shell whose stress-free reference is the meridian polyline (X_ref, Y_ref) [m], apex first
    (e.g. a flat plate), without prestress: chords L0, hoop sums S0 = x_a + x_b, conical zone
    areas A0 = pi (x_a + x_b) L0, lumped masses rho_c h A_i."""
    X_ref = np.asarray(X_ref, dtype=float)
    Y_ref = np.asarray(Y_ref, dtype=float)
    L0 = np.hypot(np.diff(X_ref), np.diff(Y_ref))
    S0 = X_ref[:-1] + X_ref[1:]
    A0 = math.pi * S0 * L0
    _, _, _, area = bending_reference(X_ref, Y_ref)
    Ebar = E0 * h / (1.0 - nu * nu)
    membrane = MembraneModel(np.full(X_ref.shape, np.nan), math.nan, 1.0, L0, S0, A0,
                             rho_c * h * area, Ebar, nu, k, rho_c * h)
    return _with_bending(membrane, X_ref, Y_ref, plate_rigidity(E0, h, nu), limbus)


def _with_bending(membrane: MembraneModel, X_ref, Y_ref, D, limbus) -> ShellModel:
    if limbus not in LIMBUS_CONDITIONS:
        raise ValueError(f"limbus must be one of {', '.join(LIMBUS_CONDITIONS)}, not {limbus!r}")
    psi_ref, dual, x_ref, area = bending_reference(X_ref, Y_ref)
    fields = {f.name: getattr(membrane, f.name) for f in dataclasses.fields(MembraneModel)
              if f.init}
    return ShellModel(**fields, psi_ref=psi_ref, dual_length=dual, x_ref=x_ref, node_area=area,
                      D=D, limbus=LIMBUS_CONDITIONS[limbus])
