"""What a cornea model offers the coupled step, the energy budget and the recorder (SI units).

Positions (X, Y) [m] and velocities (VX, VY) [m/s] of the cornea's nodes, apex first, belong to
the coupled model; a cornea model holds its reference, its material, and any state of its own
(the directors of the shear-deformable shell), with a trial copy that ``advance`` fills and
``commit`` accepts.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class CorneaModel(Protocol):
    """The interface of a cornea model (``membrane.py``, ``kirchhoff.py``, ``mindlin.py``)."""

    name: str  # its name in ``registry.CORNEAS``
    mass: np.ndarray  # lumped nodal masses [kg]
    # rows of its resultants (N1, N2, ...), the rows of a tissue law's history
    resultant_rows: int
    stencil: int  # the force on a node depends on the nodes up to this many away

    @classmethod
    def for_run(cls, si, limbus: str, phi: np.ndarray) -> "CorneaModel":
        """The model of a run (``SIParams`` si) on the reference angles phi [rad]."""

    @property
    def n(self) -> int:
        """Number of nodes."""

    def rest(self, X, Y) -> None:
        """Start at rest at the static equilibrium (X, Y) [m]."""

    def forces(self, X, Y, q) -> tuple[np.ndarray, np.ndarray]:
        """Total nodal forces (Fx, Fy) [N] at (X, Y) [m] under the net inside pressure q [Pa]."""

    def substeps(self, X, Y, dt: float) -> int:
        """Number of stable sub-steps of the state (X, Y) in a step of dt [s]."""

    def advance(self, X, Y, VX, VY, p_start, p_end, t_start, dt, n_sub, jet, history,
                viscoelastic) -> None:
        """Advance (X, Y, VX, VY) in place over dt [s] in n_sub sub-steps under the fluid
        pressure going from p_start to p_end [Pa] and the air pulse ``jet`` outside (a
        ``loads.pulse.AirPulse`` on the model's nodes: ``space``, ``kernel_args``); ``history``:
        the tissue law's trial history (``tissue``), advanced when ``viscoelastic``."""

    def internal_forces(self, X, Y, history) -> tuple[np.ndarray, np.ndarray]:
        """The tissue's nodal forces (Fx, Fy) [N] at (X, Y) [m] without pressure, with a tissue
        law's ``stored_history()``."""

    def commit(self) -> None:
        """The model's own trial state of the last ``advance`` becomes its state."""

    def energy(self, X, Y) -> tuple[float, float]:
        """(membrane, bending with transverse shear) elastic energy [J]."""

    def kinetic_energy(self, VX, VY) -> float:
        """Kinetic energy [J] (with the model's own rates, e.g. the directors')."""

    def apex_moment(self, X, Y, overstress=None) -> float:
        """Meridional bending moment at the apex [N m/m], with a tissue overstress if given."""

    def history_work(self):
        """Work arrays for ``history_strains``."""

    def history_strains(self, X, Y, work, trial=False):
        """(strains, equilibrium-law resultants) in the rows of ``resultant_rows``."""

    def overstress_bending_energy(self, overstress) -> float:
        """Energy [J] stored by one Prony term's overstresses of the rows beyond N1, N2."""

    def add_overstress_bending_work(self, work, q, bend_a, bend_b) -> float:
        """``work`` plus the work of the overstresses q of the rows beyond N1, N2."""

    def diagnostics(self) -> dict[str, float]:
        """What a run reports of the model (prestretch, bending rigidity, R_ref)."""
