"""The Kirchhoff-Love shell cornea: the membrane of ``reference.py`` with bending stiffness (SI).

Discrete energy (``kernels/shell.py``): the membrane's segment energies plus nodal bending energies
A_i W_bending(K_s, K_theta) in Reissner's bending strains, large rotations, apex symmetry, limbus
clamped (default) or pinned.

Constitutive choice: the linear bending law W = D/2 (K_s^2 + K_theta^2 + 2 nu K_s K_theta) with the
plate rigidity D = E0 h^3 / (12 (1 - nu^2)), beside the Fung membrane.  The energy splits into
membrane and bending, so D = 0 is the membrane exactly (``membrane.py``) and the two laws can be
checked separately (the clamped plate, the shallow cap).  Integrating the Fung law through the
thickness would couple them: it stiffens bending with the prestrain (by the Fung tangent factor,
about 1.35 at the default IOP, E0 and k = 240) and with the bending strain itself (h K / 2 reaches
0.04 at applanation).  The linear law therefore underestimates the bending stiffness of the Fung
material by up to this factor.

Rest state: the stress-free reference is the homothetic arc of radius R / lambda0 (the membrane's
prestretch).  A homothety keeps every angle, so the drawn arc has no bending strain and carries the
IOP by membrane tension alone; the discrete equilibrium (Newton, ``static_equilibrium``) differs
from it by the membrane's O(dphi^2) and is reported by the run.

The shear-deformable shell is ``mindlin.py``; this one is rigid in transverse shear.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..kernels.energy import kinetic_energy
from ..kernels.membrane import add_pressure_loads, max_wave_speed
from ..kernels.shell import (LIMBUS_CLAMPED, LIMBUS_PINNED, advance_shell, bending_moments,
                             max_bending_frequency, shell_energy, shell_internal_forces,
                             shell_resultants, shell_strains, shell_work, work_rows)
from ..kernels.viscoelastic import bending_overstress_energy, paired_overstress_work
from .reference import MEMBRANE_SAFETY, MembraneModel, build_membrane
from .tissue import NO_HISTORY

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
class KirchhoffShell(MembraneModel):
    """Discrete Kirchhoff-Love shell: the membrane's data plus the bending reference and rigidity
    (SI).  It implements ``interface.CorneaModel``."""

    psi_ref: np.ndarray = None  # reference segment angles [rad]
    dual_length: np.ndarray = None  # reference length of each node's bending cell [m]
    x_ref: np.ndarray = None  # reference distance of each node from the axis [m]
    node_area: np.ndarray = None  # reference area of each node's bending cell [m^2]
    D: float = 0.0  # bending rigidity [N m]
    limbus: int = LIMBUS_CLAMPED

    name = "kirchhoff"
    # the rows of its resultants (and of a tissue law's history): N1, N2 per segment, M_s,
    # M_theta per node
    resultant_rows = 4

    def __post_init__(self):
        self.work = shell_work(self.n)
        self._forces = tuple(np.empty(self.n) for _ in range(3))  # Fx, Fy [N], load q [Pa]

    @classmethod
    def for_run(cls, si, limbus, phi) -> "KirchhoffShell":
        """The shell of a run (``SIParams`` ``si``, ``limbus`` clamped or pinned) on the
        reference angles ``phi`` of its nodes (apex first), prestressed by the IOP on the drawn
        arc of radius R: the membrane of ``build_membrane`` with D = E0 h^3 / (12 (1 - nu^2))."""
        membrane = build_membrane(phi, si.R_m, si.p0_Pa, si.E0_Pa, si.thickness_m, si.nu,
                                  si.fung_k, si.rho_cornea)
        return cls(**shell_fields(membrane, membrane.R_ref * np.sin(phi),
                                  membrane.R_ref * np.cos(phi),
                                  plate_rigidity(si.E0_Pa, si.thickness_m, si.nu), limbus))

    # -- the cornea's state besides positions and velocities: none for this shell ----------
    def rest(self, X, Y):
        """Start at rest at the static equilibrium (X, Y) [m] (no state of its own here)."""

    def commit(self):
        """The state of the last ``advance`` becomes the state at the end of the step."""

    def kinetic_energy(self, VX, VY):
        """Kinetic energy [J] of the nodes moving at (VX, VY) [m/s]."""
        return kinetic_energy(self.mass, VX, VY)

    def diagnostics(self):
        """What the run reports of the model: prestretch, bending rigidity, stress-free radius."""
        return {"prestretch": self.lambda0, "bending_rigidity_N_m": self.D,
                "R_ref_mm": self.R_ref * 1e3}

    @property
    def bending_area(self):
        """The areas [m^2] the bending moments act on (one per node here)."""
        return self.node_area

    def history_strains(self, X, Y, work, trial=False):
        """(strains, equilibrium-law resultants) of the state (X, Y) [m] in the rows of
        ``resultant_rows``: E1, E2 and N1, N2 per segment, K_s, K_theta and M_s, M_theta per
        node; ``work`` from ``history_work``."""
        E1, E2, psi, N1, N2, _, Ks, Kt, Ms, Mt = work_rows(work, self.n)
        shell_strains(X, Y, self.L0, self.S0, self.psi_ref, self.dual_length, self.x_ref,
                      self.limbus, self.D, E1, E2, psi, Ks, Kt)
        shell_resultants(E1, E2, Ks, Kt, self.Ebar, self.nu, self.k, self.D, N1, N2, Ms, Mt)
        return (E1, E2, Ks, Kt), (N1, N2, Ms, Mt)

    def history_work(self):
        return shell_work(self.n)

    def overstress_bending_energy(self, overstress):
        """Energy [J] stored by the overstresses of the bending rows of one Prony term
        (``tissue.ViscoelasticTissue``): q . C^-1 q on the bending areas, C = D [[1, nu],
        [nu, 1]]."""
        area = self.bending_area
        cells = area.shape[0]
        qMs, qMt = overstress[2, :cells], overstress[3, :cells]
        inv = 1.0 / (self.D * (1.0 - self.nu * self.nu))
        return bending_overstress_energy(area, inv, self.nu, qMs, qMt)

    def add_overstress_bending_work(self, work, q, bend_a, bend_b):
        """``work`` [J] plus the work of the mean overstresses ``q`` of the bending rows over the
        change of the bending strains from ``bend_a`` to ``bend_b`` (``history_strains``)."""
        area = self.bending_area
        cells = area.shape[0]
        work += paired_overstress_work(area, q[2, :cells], q[3, :cells], bend_b[0], bend_a[0],
                                       bend_b[1], bend_a[1])
        return work

    stencil = 2  # the force on a node depends on the nodes up to two away

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

    def internal_forces(self, X, Y, history=(0, *NO_HISTORY)):
        """The tissue's nodal forces (Fx, Fy) [N] of the state (X, Y) [m] without any pressure:
        the equilibrium law's, or with a tissue law's ``stored_history()`` the total ones."""
        Fx, Fy = np.empty_like(X), np.empty_like(Y)
        shell_internal_forces(X, Y, self.L0, self.S0, self.A0, *self.bending_args(), self.Ebar,
                              self.nu, self.k, self.D, self.work, Fx, Fy, *history)
        return Fx, Fy

    def apex_moment(self, X, Y, overstress=None):
        """Meridional bending moment M_s at the apex [N m/m] at positions (X, Y) [m]: the bending
        law's, plus the tissue's overstress (``overstress`` of a ``tissue`` law) if given."""
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
        [s]: dt / n <= ``stable_substep``."""
        return max(1, int(math.ceil(dt / self.stable_substep(X, Y))))

    def advance(self, X, Y, VX, VY, p_start, p_end, t_start, dt, n_sub, jet, history=NO_HISTORY,
                viscoelastic=False):
        """Advance the state (X, Y [m], VX, VY [m/s], in place) from t_start to t_start + dt [s] in
        n_sub Verlet sub-steps, with the fluid pressure on the cornea going linearly from p_start
        to p_end [Pa] and the air pulse ``jet`` (a ``loads.pulse.AirPulse`` on these nodes)
        outside.  ``history``: the
        tissue law's trial history (``begin_trial()``), advanced in place when
        ``viscoelastic``."""
        Fx, Fy, q = self._forces
        advance_shell(X, Y, VX, VY, self.mass, jet.space, self.L0, self.S0, self.A0,
                      *self.bending_args(), self.Ebar, self.nu, self.k, self.D, p_start, p_end,
                      t_start, dt, n_sub, jet.kernel_args, self.work, Fx, Fy, q, viscoelastic,
                      *history)


def shell_fields(membrane: MembraneModel, X_ref, Y_ref, D, limbus) -> dict:
    """The fields of a ``KirchhoffShell`` built on ``membrane`` whose stress-free meridian is
    (X_ref, Y_ref) [m], with bending rigidity D [N m] and ``limbus`` clamped or pinned."""
    if limbus not in LIMBUS_CONDITIONS:
        raise ValueError(f"limbus must be one of {', '.join(LIMBUS_CONDITIONS)}, not {limbus!r}")
    psi_ref, dual, x_ref, area = bending_reference(X_ref, Y_ref)
    fields = {f.name: getattr(membrane, f.name) for f in dataclasses.fields(MembraneModel)
              if f.init}
    return dict(fields, psi_ref=psi_ref, dual_length=dual, x_ref=x_ref, node_area=area, D=D,
                limbus=LIMBUS_CONDITIONS[limbus])
