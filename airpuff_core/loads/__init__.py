"""The loads on the cornea from outside: the air pulse of the run's ``instrument``, each in its
module (the paper's jet of eq. (11) ``air_jet.py``, the ORA's ``ora.py``, the Corvis ST's
``corvis.py``; what they share ``pulse.py``).  ``pulse_for_run`` builds the pulse of a run."""

from .air_jet import AirJet
from .corvis import CorvisPulse
from .ora import OraPulse

PULSES = {"paper": AirJet, "ora": OraPulse, "corvis": CorvisPulse}


def pulse_for_run(params, si, phi):
    """The air pulse of a run (``RunParams`` params, its ``SIParams`` si) on the cornea's nodes
    of reference angles phi [rad]."""
    return PULSES[params.instrument](si, phi)
