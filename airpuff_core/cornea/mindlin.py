"""The shear-deformable (Reissner-Mindlin) shell cornea (SI units; ``kernels/mindlin.py``).

With a transverse shear modulus G_t > 0 the shell is shear-deformable: every node carries a
director with its own rotation and rotary inertia, and bending and transverse shear are separate
strains (the Kirchhoff-Love shell of ``kirchhoff.py`` is the limit rigid in shear).  The
directors are the model's own state (``rest``, ``advance`` into a trial state, ``commit``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..kernels.energy import kinetic_energy
from ..kernels.membrane import add_pressure_loads, max_wave_speed
from ..kernels.mindlin import (SHEAR_CORRECTION, advance_mindlin, balance_directors,
                               max_director_frequency, mindlin_energy, mindlin_internal_forces,
                               mindlin_rows, mindlin_resultants, mindlin_strains, mindlin_work)
from ..kernels.shell import LIMBUS_CLAMPED, segment_angles
from ..kernels.viscoelastic import row_overstress_energy, row_overstress_work
from .kirchhoff import KirchhoffShell, plate_rigidity, shell_fields
from .reference import build_membrane
from .tissue import NO_HISTORY


def director_reference(psi_ref):
    """Director angles [rad] of the stress-free reference at the nodes: 0 at the apex (symmetry),
    the mean of the two segment angles inside, and at the limbus the angle whose mean with the
    last inner node's is the last segment's (exact on a uniformly divided arc, where the
    directors are the normals), so that the reference has no transverse shear strain there."""
    beta = np.empty(psi_ref.shape[0] + 1)
    beta[0] = 0.0
    beta[1:-1] = 0.5 * (psi_ref[:-1] + psi_ref[1:])
    beta[-1] = 2.0 * psi_ref[-1] - beta[-2]
    return beta


# Newton iterations of the directors' static balance stop once a correction is below this [rad],
# or after DIRECTOR_ITERATIONS (quadratic convergence takes 3-5)
DIRECTOR_TOL = 1e-13
DIRECTOR_ITERATIONS = 50


@dataclass
class MindlinShell(KirchhoffShell):
    """Shear-deformable (Reissner-Mindlin) shell (``kernels/mindlin.py``): the Kirchhoff shell's
    data plus the director reference, the rotary inertia and the transverse shear stiffness S =
    kappa G_t h.  It holds the directors' state (angles ``beta`` [rad], rates ``omega``
    [rad/s]) at the start of the step and the trial state that ``advance`` computes from it;
    ``commit`` makes the trial the state.  Bending strains, moments and the shear force live on
    the segments (one-point integration)."""

    beta_ref: np.ndarray = None  # director angles of the reference [rad]
    x_mid: np.ndarray = None  # reference distance of each segment's mid-point from the axis [m]
    inertia: np.ndarray = None  # rotary inertia rho h^3 / 12 A_i of each node [kg m^2]
    G_t: float = 0.0  # transverse shear modulus [Pa]
    S: float = 0.0  # transverse shear stiffness kappa G_t h [N/m]

    name = "mindlin"
    resultant_rows = 5  # N1, N2, M_s, M_theta, Q, all per segment

    @classmethod
    def for_run(cls, si, limbus, phi) -> "MindlinShell":
        """The shear-deformable shell of a run (``SIParams`` ``si`` with its
        ``transverse_shear_modulus_Pa`` > 0, ``limbus``) on the reference angles ``phi``: the
        Kirchhoff shell of ``KirchhoffShell.for_run`` with directors and shear stiffness."""
        membrane = build_membrane(phi, si.R_m, si.p0_Pa, si.E0_Pa, si.thickness_m, si.nu,
                                  si.fung_k, si.rho_cornea)
        return cls.on_reference(membrane, membrane.R_ref * np.sin(phi),
                                membrane.R_ref * np.cos(phi),
                                plate_rigidity(si.E0_Pa, si.thickness_m, si.nu), limbus,
                                si.transverse_shear_modulus_Pa, si.thickness_m)

    @classmethod
    def on_reference(cls, membrane, X_ref, Y_ref, D, limbus, G_t, h) -> "MindlinShell":
        """The shell on ``membrane`` with the stress-free meridian (X_ref, Y_ref) [m], bending
        rigidity D [N m], transverse shear modulus G_t [Pa] and thickness h [m]."""
        fields = shell_fields(membrane, X_ref, Y_ref, D, limbus)
        psi_ref, x_ref, area = fields["psi_ref"], fields["x_ref"], fields["node_area"]
        return cls(**fields, beta_ref=director_reference(psi_ref),
                   x_mid=0.5 * (x_ref[:-1] + x_ref[1:]),
                   inertia=membrane.rho_h * h * h / 12.0 * area, G_t=G_t,
                   S=SHEAR_CORRECTION * G_t * h)

    def __post_init__(self):
        n = self.n
        self.work = mindlin_work(n)
        self._forces = tuple(np.empty(n) for _ in range(4))  # Fx, Fy [N], load q [Pa], T [N m]
        self.beta = self.beta_ref.copy()
        self.omega = np.zeros(n)
        self._trial = (self.beta.copy(), self.omega.copy())

    @property
    def stencil(self):
        """The directors that balance a state (``forces``) depend on every node."""
        return self.n

    @property
    def bending_area(self):
        return self.A0

    def mindlin_args(self):
        return (self.L0, self.S0, self.A0, self.psi_ref, self.beta_ref, self.x_mid, self.Ebar,
                self.nu, self.k, self.D, self.S)

    def internal_forces(self, X, Y, history=(0, *NO_HISTORY)):
        """As ``KirchhoffShell.internal_forces``, with the directors of the state."""
        Fx, Fy, T = np.empty_like(X), np.empty_like(Y), np.empty_like(X)
        mindlin_internal_forces(X, Y, self.beta, *self.mindlin_args(), self.work, Fx, Fy, T,
                                *history)
        return Fx, Fy

    def _director_loads(self, X, Y, beta, Fx, Fy, T):
        mindlin_internal_forces(X, Y, beta, *self.mindlin_args(), self.work, Fx, Fy, T, 0,
                                *NO_HISTORY)

    def balanced_directors(self, X, Y):
        """The director angles [rad] at which the moments vanish for positions (X, Y) [m]
        (``balance_directors``, from the directors that follow the segments' tilt): the static
        shell's directors, and with them ``forces`` is -dPi/dX of the energy minimised over the
        directors."""
        n = self.n
        psi = np.empty(n - 1)
        segment_angles(X, Y, psi)
        tilt = psi - self.psi_ref
        beta = self.beta_ref.copy()
        beta[1:-1] += 0.5 * (tilt[:-1] + tilt[1:])
        if self.limbus != LIMBUS_CLAMPED:
            beta[-1] += tilt[-1]
        Fx, Fy, T = np.empty(n), np.empty(n), np.empty(n)
        balance_directors(X, Y, beta, *self.mindlin_args(), self.limbus, self.work, Fx, Fy, T,
                          *NO_HISTORY, DIRECTOR_TOL, DIRECTOR_ITERATIONS)
        return beta

    def forces(self, X, Y, q):
        """Total nodal forces [N] at positions (X, Y) under net inside pressure q [Pa], with the
        directors balanced (``balanced_directors``)."""
        beta = self.balanced_directors(X, Y)
        Fx, Fy, T = np.empty_like(X), np.empty_like(Y), np.empty_like(X)
        self._director_loads(X, Y, beta, Fx, Fy, T)
        add_pressure_loads(X, Y, q, Fx, Fy)
        return Fx, Fy

    def rest(self, X, Y):
        """Start at rest at the static equilibrium (X, Y) [m]: balanced directors, no rates."""
        self.beta[:] = self.balanced_directors(X, Y)
        self.omega[:] = 0.0

    def commit(self):
        """The directors of the last ``advance`` become the state (buffers swapped)."""
        state = (self.beta, self.omega)
        self.beta, self.omega = self._trial
        self._trial = state

    @property
    def trial_directors(self):
        return self._trial[0]

    def kinetic_energy(self, VX, VY):
        """Kinetic energy [J]: the nodes' and the directors' (1/2 I omega^2) of the state."""
        return kinetic_energy(self.mass, VX, VY) + 0.5 * float(np.sum(self.inertia
                                                                     * self.omega ** 2))

    def history_strains(self, X, Y, work, trial=False):
        """(strains, equilibrium-law resultants) per segment in the rows of the viscoelastic
        history: E1, E2, K_s, K_theta, gamma and N1, N2, M_s, M_theta, Q, with the directors of
        the state (``trial``: of the last ``advance``)."""
        beta = self._trial[0] if trial else self.beta
        E1, E2, psi, N1, N2, _, Ks, Kt, gamma, Ms, Mt, Q = mindlin_rows(work, self.n)
        mindlin_strains(X, Y, beta, self.L0, self.S0, self.psi_ref, self.beta_ref, self.x_mid,
                        E1, E2, psi, Ks, Kt, gamma)
        mindlin_resultants(E1, E2, Ks, Kt, gamma, self.Ebar, self.nu, self.k, self.D, self.S,
                           N1, N2, Ms, Mt, Q)
        return (E1, E2, Ks, Kt, gamma), (N1, N2, Ms, Mt, Q)

    def history_work(self):
        return mindlin_work(self.n)

    def overstress_bending_energy(self, overstress):
        """As ``KirchhoffShell``'s, plus the transverse shear row: q_Q^2 / S on A0."""
        bending = super().overstress_bending_energy(overstress)
        qQ = overstress[4, :self.n - 1]
        bending += row_overstress_energy(self.A0, qQ) / self.S
        return bending

    def add_overstress_bending_work(self, work, q, bend_a, bend_b):
        """As ``KirchhoffShell``'s, plus the transverse shear row's work over the change of the
        shear strain."""
        work = super().add_overstress_bending_work(work, q, bend_a, bend_b)
        work += row_overstress_work(self.A0, q[4, :self.n - 1], bend_b[2], bend_a[2])
        return work

    def apex_moment(self, X, Y, overstress=None):
        """Meridional bending moment M_s [N m/m] of the segment at the apex (its mid-point), with
        the viscoelastic overstress if given, for the directors of the state."""
        _, (_, _, Ms, _, _) = self.history_strains(X, Y, self.work)
        extra = 0.0 if overstress is None else float(overstress[:, 2, 0].sum())
        return float(Ms[0]) + extra

    def energy(self, X, Y):
        """(membrane, bending plus transverse shear) elastic energy [J] at positions (X, Y) [m]
        and the directors of the state."""
        membrane, bending, shear = self.energy_parts(X, Y, self.beta)
        return membrane, bending + shear

    def energy_parts(self, X, Y, beta):
        """(membrane, bending, transverse shear) energy [J] at positions (X, Y), directors beta."""
        return mindlin_energy(X, Y, beta, *self.mindlin_args(), self.work)

    def max_frequency(self, X, Y):
        """Upper estimate of the highest frequency [rad/s]: in-plane waves (2 c / L_min) and the
        directors' bending and shear (``max_director_frequency``), added in squares."""
        c = max_wave_speed(X, Y, self.L0, self.S0, self.Ebar, self.nu, self.k, self.rho_h)
        omega_membrane = 2.0 * c / self.L0.min()
        omega_directors = max_director_frequency(self.L0, self.A0, self.x_mid, self.mass,
                                                 self.inertia, self.limbus, self.D, self.nu,
                                                 self.S)
        return math.hypot(omega_membrane, omega_directors)

    def advance(self, X, Y, VX, VY, p_start, p_end, t_start, dt, n_sub, jet, history=NO_HISTORY,
                viscoelastic=False):
        """As ``KirchhoffShell.advance``; the directors start from the state and end in the trial
        state (``commit``)."""
        Fx, Fy, q, T = self._forces
        beta, omega = self._trial
        beta[:] = self.beta
        omega[:] = self.omega
        advance_mindlin(X, Y, VX, VY, beta, omega, self.mass, self.inertia, jet.space, self.L0,
                        self.S0, self.A0, self.psi_ref, self.beta_ref, self.x_mid, self.limbus,
                        self.Ebar, self.nu, self.k, self.D, self.S, p_start, p_end, t_start, dt,
                        n_sub, jet.kernel_args, self.work, Fx, Fy, T, q, viscoelastic, *history)
