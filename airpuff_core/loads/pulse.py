"""What every instrument's air pulse offers the run (SI units): its kernel arguments, its
pressure on the cornea's nodes and at the apex, its peak time, and its online state.

The cornea kernels evaluate the pulse inside their sub-steps from ``kernel_args`` and ``space``
(``kernels/air_jet.py``); the start at rest, the energy budget, the apex force budget and the
recorder use the methods here.  A pulse that is switched off by what happens to the eye
(``watches_applanation``) is told the instrument's applanation signal (``readout.py``) after
every committed step (``CoupledModel.commit``) and sets its switch-off time in ``kernel_args``
itself.
"""

from __future__ import annotations

import numpy as np

from ..kernels.air_jet import jet_pressures, pulse_pressure, pulse_space


class AirPulse:
    """The interface of an instrument's pulse; each kind sets ``kernel_args`` and calls
    ``set_nodes``.  ``space``: the pulse's space factor on the cornea's nodes (the kernels'
    ``jet_space``)."""

    name = ""
    kernel_args = None
    space = None
    # True: ``observe(t, signal)`` after every committed step
    watches_applanation = False

    def set_nodes(self, phi):
        """The space factor on the cornea's nodes of reference angles phi [rad]."""
        self.space = np.empty(phi.shape[0])
        pulse_space(phi, self.kernel_args, self.space)

    def pressures(self, t, phi, out):
        """out[k] = p_a(t, phi[k]) [Pa] at time t [s] on the nodes of reference angles phi."""
        jet_pressures(t, phi, self.kernel_args, out)

    def at_apex(self, t):
        """p_a(t, 0) [Pa] at time t [s]."""
        return pulse_pressure(t, 0.0, self.kernel_args)

    @property
    def peak_time(self):
        """The time [s] of the pulse's peak at the apex (inf while it is not known yet)."""
        raise NotImplementedError

    def observe(self, t, signal):
        """The instrument's applanation signal (``readout.py``) of the state committed at time
        t [s]."""

    def diagnostics(self) -> dict:
        """What the run reports of its pulse (user units)."""
        return {}

