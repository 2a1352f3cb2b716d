"""The rigid globe of the paper: chamber walls that do not move."""

from __future__ import annotations

from .compliant import WallPressure


class RigidGlobe:
    """Walls that never give way: every method of ``CompliantGlobe`` does nothing, and the
    globe's pressure is the IOP p0 [Pa]."""

    def __init__(self, si, geometry, chamber):
        self.p0 = si.p0_Pa
        self.walls = WallPressure(si, geometry, chamber)

    def start(self, fluid_volume, chamber_volume):
        """Nothing to set up."""

    def impose(self, X, Y, VX, VY, c, dt, y, vx, vy):
        """The wall nodes keep their positions and rest."""

    def work(self, rho_n, rho_new, c):
        """No work is done on walls that do not move [J]."""
        return 0.0

    def commit(self, fluid_volume, cornea_chamber_volume, dt, c, rho):
        """No state to accept."""

    def wall_pressure(self, rho, c):
        """The fluid's mean pressure on the walls [Pa] (``WallPressure``)."""
        return self.walls.mean(rho, c)

    def volume_change(self):
        """The walls never give way [m^3]."""
        return 0.0

    def pressure(self):
        """The IOP [Pa]."""
        return self.p0
