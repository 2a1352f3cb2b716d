"""The blow-up checks of a run: an observer that stops it once the fluid's state is no longer
physical (``SimulationError``, naming the time and the quantity)."""

from __future__ import annotations

import math

from .errors import SimulationError
from .kernels.fluid import max_density_deviation

BLOWUP_SPEED = 50.0  # m/s: a fluid speed above this is a blow-up (physical speeds ~0.2-1 m/s)
BLOWUP_DENSITY = 0.2  # relative density change beyond which the run is declared blown up


class BlowUpCheck:
    """After every step (``committed``): the largest fluid speed at most BLOWUP_SPEED, the
    largest relative density deviation at most BLOWUP_DENSITY, both finite."""

    def coupled(self, model, dt):
        """Nothing to check before the commit (the coupling checks its own pressures)."""

    def committed(self, model, dt):
        t_ms = model.t * 1e3
        vmax = model.control.v_prev
        if not math.isfinite(vmax) or vmax > BLOWUP_SPEED:
            raise SimulationError(f"fluid blew up at t = {t_ms:.4f} ms: max speed "
                                  f"{vmax:.3g} m/s", t_ms, "blow-up")
        dev = max_density_deviation(model.fluid.rho, model.si.rho_fluid)
        if not math.isfinite(dev) or dev > BLOWUP_DENSITY:
            raise SimulationError(f"fluid blew up at t = {t_ms:.4f} ms: density deviates "
                                  f"by {dev:.3g} from the reference", t_ms, "blow-up")
