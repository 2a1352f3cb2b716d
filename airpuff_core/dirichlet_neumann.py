"""The Dirichlet-Neumann iteration of the coupled step on the interface pressure (docs/model.md
section 5).

Each iteration k = 1, 2, ... maps the current estimate p^k of the pressure on the interface to a
new one: the structure is advanced under p^k (Neumann), its position and velocity imposed on the
fluid (Dirichlet), and the fluid's new pressure read off the interface.  The iteration stops once

    ||p^{k+1} - p^k|| / max(||p^k - p0||, p_ref) < tolerance,   with k >= 2,

and fails (``SimulationError``) when the pressure is not finite or after ``max_iterations``.
The map itself is the caller's (``coupling.CoupledModel``); this module knows only pressures.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import SimulationError


class DirichletNeumann:
    """The fixed-point iteration on interface pressures, with the figures of its last use:
    ``iterations`` and ``residual``."""

    def __init__(self, tolerance: float, max_iterations: int, size: int):
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self._pressures = (np.empty(size), np.empty(size))  # estimate and new pressure [Pa]
        self.iterations = 0
        self.residual = 0.0
        self.pressure = self._pressures[0]  # the converged interface pressure of the last use [Pa]

    def iterate(self, update, p_start, t_ms):
        """Iterate ``update(p_est, p_new) -> residual`` (fills p_new from the estimate p_est and
        returns their relative change) from the estimate ``p_start`` [Pa] until converged; the
        time t_ms [ms] names the step in errors.  Returns the number of iterations."""
        p_est, p_new = self._pressures
        p_est[:] = p_start
        for it in range(1, self.max_iterations + 1):
            residual = update(p_est, p_new)
            if not math.isfinite(residual):
                raise SimulationError(f"fluid-structure system blew up at t = {t_ms:.4f} ms: the "
                                      f"interface pressure is not finite", t_ms, "blow-up")
            p_est, p_new = p_new, p_est
            if it >= 2 and residual < self.tolerance:
                break
        else:
            raise SimulationError(
                f"Dirichlet-Neumann coupling did not converge at t = {t_ms:.4f} ms: residual "
                f"{residual:.3g} > tolerance {self.tolerance:.3g} after {self.max_iterations} "
                f"iterations", t_ms, "coupling")
        self.iterations = it
        self.residual = residual
        self.pressure = p_est  # the last map's output
        return it
