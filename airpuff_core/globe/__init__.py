"""The globe behind the chamber: rigid walls (``rigid.py``, the paper's) or compliant walls that
recede with Friedenwald's pressure-volume law (``compliant.py``).  Both offer the same methods
to the coupled step."""

from __future__ import annotations

from .compliant import CompliantGlobe
from .rigid import RigidGlobe


def globe_for_run(params, si, chamber, X, Y, mass):
    """The globe of a run (``RunParams`` params, ``SIParams`` si) around ``chamber``, the cornea at
    rest at (X, Y) [m], the fluid nodes' masses ``mass`` [kg]."""
    if params.globe == "compliant":
        return CompliantGlobe(si, params.geometry, chamber, X, Y, mass)
    return RigidGlobe(si, params.geometry, chamber)
