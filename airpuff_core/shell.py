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

Transverse shear (``MindlinShellModel``, ``kernels/mindlin.py``): with a transverse shear modulus
G_t > 0 the shell is shear-deformable (Reissner-Mindlin): every node carries a director with its
own rotation and rotary inertia, and bending and transverse shear are separate strains.  The
Kirchhoff-Love ``ShellModel`` is the shell rigid in shear (G_t = 0), computed as before.  The
directors are the model's own state (``rest``, ``advance`` into a trial state, ``commit``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .kernels.energy import kinetic_energy
from .kernels.membrane import add_pressure_loads, max_wave_speed
from .kernels.mindlin import (SHEAR_CORRECTION, advance_mindlin, balance_directors,
                              max_director_frequency, mindlin_energy, mindlin_internal_forces,
                              mindlin_rows, mindlin_resultants, mindlin_strains, mindlin_work)
from .kernels.shell import (LIMBUS_CLAMPED, LIMBUS_PINNED, advance_shell, bending_moments,
                            max_bending_frequency, segment_angles, shell_energy,
                            shell_internal_forces, shell_resultants, shell_strains, shell_work,
                            work_rows)
from .membrane import MEMBRANE_SAFETY, MembraneModel, build_membrane

# the history arguments of the shell kernels without viscoelasticity (not read; rows enough for the
# shear-deformable shell's five resultants)
NO_HISTORY = (np.zeros((5, 1)), np.zeros((1, 5, 1)), np.ones(1), np.zeros(1))
LIMBUS_CONDITIONS = {"clamped": LIMBUS_CLAMPED, "pinned": LIMBUS_PINNED}


def _history_args(history):
    """(ve_mode, previous, overstress, decay, weight) of the shell kernels: the equilibrium law
    (mode 0) without a history, its stored overstresses added (mode 1, no update) with one."""
    if history is None:
        return (0, *NO_HISTORY)
    return (1, history.previous, history.overstress, history.decay, history.weight)


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

    # rows of the viscoelastic history: N1, N2 (per segment), M_s, M_theta (per node)
    history_rows = 4

    def __post_init__(self):
        self.work = shell_work(self.n)
        self._forces = tuple(np.empty(self.n) for _ in range(3))  # Fx, Fy [N], load q [Pa]

    # -- the cornea's state besides positions and velocities: none for this shell ----------
    def rest(self, X, Y):
        """Start at rest at the static equilibrium (X, Y) [m] (no state of its own here)."""

    def commit(self):
        """The state of the last ``advance`` becomes the state at the end of the step."""

    def kinetic_energy(self, VX, VY):
        """Kinetic energy [J] of the nodes moving at (VX, VY) [m/s]."""
        return kinetic_energy(self.mass, VX, VY)

    @property
    def bending_area(self):
        """The areas [m^2] the bending moments act on (one per node here)."""
        return self.node_area

    def history_strains(self, X, Y, work, trial=False):
        """(strains, equilibrium-law resultants) of the state (X, Y) [m] in the rows of the
        viscoelastic history: E1, E2 and N1, N2 per segment, K_s, K_theta and M_s, M_theta per
        node (the latter unset when D = 0); ``work`` from ``history_work``."""
        E1, E2, psi, N1, N2, _, Ks, Kt, Ms, Mt = work_rows(work, self.n)
        shell_strains(X, Y, self.L0, self.S0, self.psi_ref, self.dual_length, self.x_ref,
                      self.limbus, self.D, E1, E2, psi, Ks, Kt)
        shell_resultants(E1, E2, Ks, Kt, self.Ebar, self.nu, self.k, self.D, N1, N2, Ms, Mt)
        return (E1, E2, Ks, Kt), (N1, N2, Ms, Mt)

    def history_work(self):
        return shell_work(self.n)

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

    def internal_forces(self, X, Y, history=None):
        """The tissue's nodal forces (Fx, Fy) [N] of the state (X, Y) [m] without any pressure:
        the equilibrium law's, or with ``history`` (a ``ViscoelasticHistory``) the total ones,
        its stored overstresses added (the apex force budget, ``CoupledModel.apex_budget``)."""
        Fx, Fy = np.empty_like(X), np.empty_like(Y)
        shell_internal_forces(X, Y, self.L0, self.S0, self.A0, *self.bending_args(), self.Ebar,
                              self.nu, self.k, self.D, self.work, Fx, Fy,
                              *_history_args(history))
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


def build_shell(phi, R, p0, E0, h, nu, k, rho_c, limbus="clamped", bending=True,
                transverse_shear_modulus=0.0) -> ShellModel:
    """Shell on reference angles ``phi`` (apex first), prestressed by p0 [Pa] on the drawn arc of
    radius R [m]: the membrane of ``build_membrane`` with D = E0 h^3 / (12 (1 - nu^2)), or with
    D = 0 (the paper's membrane, computed by the same kernels bit for bit) when not ``bending``.
    ``transverse_shear_modulus`` G_t [Pa] > 0 makes the bending shell shear-deformable
    (``MindlinShellModel``); 0 keeps it rigid in shear (Kirchhoff-Love)."""
    membrane = build_membrane(phi, R, p0, E0, h, nu, k, rho_c)
    X_ref = membrane.R_ref * np.sin(phi)
    Y_ref = membrane.R_ref * np.cos(phi)
    D = plate_rigidity(E0, h, nu) if bending else 0.0
    G_t = transverse_shear_modulus if bending else 0.0
    return _with_bending(membrane, X_ref, Y_ref, D, limbus, G_t, h)


def shell_for_run(params, phi) -> ShellModel:
    """The cornea of a run (``RunParams`` ``params``) on its cornea nodes' reference angles."""
    si = params.si()
    return build_shell(phi, si.R_m, si.p0_Pa, si.E0_Pa, si.thickness_m, si.nu, si.fung_k,
                       si.rho_cornea, params.limbus, bending=params.cornea == "shell",
                       transverse_shear_modulus=si.transverse_shear_modulus_Pa)


def shell_on_meridian(X_ref, Y_ref, E0, h, nu, k, rho_c, limbus="clamped",
                      transverse_shear_modulus=0.0) -> ShellModel:
    """Shell whose stress-free reference is the meridian polyline (X_ref, Y_ref) [m], apex first
    (e.g. a flat plate), without prestress: chords L0, hoop sums S0 = x_a + x_b, conical zone
    areas A0 = pi (x_a + x_b) L0, lumped masses rho_c h A_i; shear-deformable when
    ``transverse_shear_modulus`` G_t [Pa] > 0."""
    X_ref = np.asarray(X_ref, dtype=float)
    Y_ref = np.asarray(Y_ref, dtype=float)
    L0 = np.hypot(np.diff(X_ref), np.diff(Y_ref))
    S0 = X_ref[:-1] + X_ref[1:]
    A0 = math.pi * S0 * L0
    _, _, _, area = bending_reference(X_ref, Y_ref)
    Ebar = E0 * h / (1.0 - nu * nu)
    membrane = MembraneModel(np.full(X_ref.shape, np.nan), math.nan, 1.0, L0, S0, A0,
                             rho_c * h * area, Ebar, nu, k, rho_c * h)
    return _with_bending(membrane, X_ref, Y_ref, plate_rigidity(E0, h, nu), limbus,
                         transverse_shear_modulus, h)


def _with_bending(membrane: MembraneModel, X_ref, Y_ref, D, limbus, G_t=0.0, h=0.0) -> ShellModel:
    if limbus not in LIMBUS_CONDITIONS:
        raise ValueError(f"limbus must be one of {', '.join(LIMBUS_CONDITIONS)}, not {limbus!r}")
    psi_ref, dual, x_ref, area = bending_reference(X_ref, Y_ref)
    fields = {f.name: getattr(membrane, f.name) for f in dataclasses.fields(MembraneModel)
              if f.init}
    shell = dict(fields, psi_ref=psi_ref, dual_length=dual, x_ref=x_ref, node_area=area, D=D,
                 limbus=LIMBUS_CONDITIONS[limbus])
    if G_t <= 0.0:
        return ShellModel(**shell)
    return MindlinShellModel(**shell, beta_ref=director_reference(psi_ref),
                             x_mid=0.5 * (x_ref[:-1] + x_ref[1:]),
                             inertia=membrane.rho_h * h * h / 12.0 * area, G_t=G_t,
                             S=SHEAR_CORRECTION * G_t * h)


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
class MindlinShellModel(ShellModel):
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

    history_rows = 5  # N1, N2, M_s, M_theta, Q, all per segment

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

    def internal_forces(self, X, Y, history=None):
        """As ``ShellModel.internal_forces``, with the directors of the state."""
        Fx, Fy, T = np.empty_like(X), np.empty_like(Y), np.empty_like(X)
        mindlin_internal_forces(X, Y, self.beta, *self.mindlin_args(), self.work, Fx, Fy, T,
                                *_history_args(history))
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

    def advance(self, X, Y, VX, VY, p_start, p_end, t_start, dt, n_sub, jet, history=None):
        """As ``ShellModel.advance``; the directors start from the state and end in the trial
        state (``commit``)."""
        Fx, Fy, q, T = self._forces
        beta, omega = self._trial
        beta[:] = self.beta
        omega[:] = self.omega
        advance_mindlin(X, Y, VX, VY, beta, omega, self.mass, self.inertia, self.phi, self.L0,
                        self.S0, self.A0, self.psi_ref, self.beta_ref, self.x_mid, self.limbus,
                        self.Ebar, self.nu, self.k, self.D, self.S, p_start, p_end, t_start, dt,
                        n_sub, jet, self.work, Fx, Fy, T, q, history is not None,
                        *(NO_HISTORY if history is None else history))
