"""The paper's membrane cornea: the Fung membrane, no bending rigidity (SI units).

Its mechanics are the Kirchhoff shell's (``kirchhoff.py``) with D = 0: the energy splits into
membrane and bending, so the shell kernels with D = 0 compute the membrane exactly, and the
membrane runs through the same time integrator.  What differs is what a membrane lacks: no
bending moment, no limbus condition, no bending rows in its resultants, and the sub-step and
stencil of in-plane waves alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .kirchhoff import KirchhoffShell, shell_fields
from .reference import MembraneModel, build_membrane


@dataclass
class Membrane(KirchhoffShell):
    """The Fung membrane of the paper: ``KirchhoffShell`` with D = 0."""

    name = "membrane"
    stencil = 1  # the force on a node depends on its neighbours only

    @classmethod
    def for_run(cls, si, limbus, phi) -> "Membrane":
        """The membrane of a run (``SIParams`` ``si``) on the reference angles ``phi``,
        prestressed by the IOP on the drawn arc of radius R (``limbus`` is a shell's option: a
        membrane carries no moment, ``params`` refuses it other than clamped)."""
        membrane = build_membrane(phi, si.R_m, si.p0_Pa, si.E0_Pa, si.thickness_m, si.nu,
                                  si.fung_k, si.rho_cornea)
        return cls(**shell_fields(membrane, membrane.R_ref * np.sin(phi),
                                  membrane.R_ref * np.cos(phi), 0.0, limbus))

    def substeps(self, X, Y, dt):
        """Verlet sub-steps that resolve the fastest membrane wave (``MembraneModel``)."""
        return MembraneModel.substeps(self, X, Y, dt)

    def apex_moment(self, X, Y, overstress=None):
        """A membrane carries no bending moment: 0 [N m/m]."""
        return 0.0

    def overstress_bending_energy(self, overstress):
        """No bending rows: 0 [J]."""
        return 0.0

    def add_overstress_bending_work(self, work, q, bend_a, bend_b):
        """No bending rows: ``work`` unchanged."""
        return work
