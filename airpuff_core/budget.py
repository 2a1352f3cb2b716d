"""The work of one run, estimated before it starts, and the budget a run must fit in.

A run advances ``t_end`` in time steps no longer than the acoustic limit
dt <= cfl h_min / (c + v_max) with c = c0 + c_slope v_max, and the viscous limit
dt <= VISCOUS_SAFETY rho h_min^2 / mu (``step_control.StepControl``; docs/model.md
section 4).  Before the run, v_max is not known; the estimate takes the aqueous flow's mean
speed in the default run, ``TYPICAL_FLOW_SPEED``, so that

    steps ~= t_end / min(cfl h_min / (c0 + (1 + c_slope) v), VISCOUS_SAFETY rho_fluid h_min^2 / mu)

with h_min the smallest node spacing of the chamber at the run's resolution
(``geometry.smallest_spacing``).  On the default coarse run the estimate is 2,713 steps; the
run takes 2,682.  A run estimated above ``MAX_ESTIMATED_STEPS`` is refused before it starts
(``check_step_budget``), so that a tiny ``cfl`` cannot make a run that never ends; the runners
also stop a task that overruns its wall-clock limit (``sweep.engine``).
"""

from __future__ import annotations

import functools
import math

from .geometry import smallest_spacing
from .params import PARAMETERS, ParameterError
from .step_control import VISCOUS_SAFETY

# Steps of one run at most (estimated).  The largest run of the defaults, fine resolution on the
# cap, is estimated at 13,700 steps; a million steps is 70 times that, about an hour and
# a half of a fine run on one core.
MAX_ESTIMATED_STEPS = 1_000_000
# m/s: mean aqueous flow speed of the default coarse run (its mean dt, 13.0 us, against 17.5 us
# at rest with c0 = 10 m/s and c_slope = 20), the v of the estimate.
TYPICAL_FLOW_SPEED = 0.17


@functools.lru_cache(maxsize=64)
def _smallest_spacing_m(geometry, layout, resolution, R_m, r_post_m, alpha0_rad) -> float:
    return smallest_spacing(geometry, layout, resolution, R_m, r_post_m, alpha0_rad)


def estimated_steps(params) -> tuple[float, str]:
    """(estimated number of time steps, the limit that sets them: ``"acoustic"`` or
    ``"viscous"``) of a run of ``params`` (a ``RunParams``)."""
    si = params.si()
    h_min = _smallest_spacing_m(params.geometry, params.layout, params.resolution, si.R_m,
                                si.r_post_m, si.alpha0_rad)
    v = TYPICAL_FLOW_SPEED
    dt_acoustic = si.cfl * h_min / (si.c0 + (1.0 + si.c_slope) * v)
    dt_viscous = VISCOUS_SAFETY * si.rho_fluid * h_min ** 2 / si.mu if si.mu > 0 else math.inf
    limit = "acoustic" if dt_acoustic <= dt_viscous else "viscous"
    dt = min(dt_acoustic, dt_viscous)
    # a cfl of 5e-324 gives dt = 0 (underflow): no number of steps would do
    return (si.t_end_s / dt if dt > 0.0 else math.inf), limit


def check_step_budget(params) -> None:
    """Raise ``ParameterError`` if a run of ``params`` is estimated above
    ``MAX_ESTIMATED_STEPS`` steps; the message gives the estimate and what sets it."""
    steps, limit = estimated_steps(params)
    if steps <= MAX_ESTIMATED_STEPS:
        return
    if limit == "viscous":
        name, what = "mu", "lower mu or t_end, or a coarser resolution"
    elif params.cfl < PARAMETERS["cfl"].default:
        name, what = "cfl", "raise cfl, or lower t_end or the resolution"
    else:
        name, what = "t_end", "lower t_end, c0 or c_slope, or the resolution"
    raise ParameterError(
        name, getattr(params, name),
        f"{PARAMETERS[name].accepted()} with a run of at most {MAX_ESTIMATED_STEPS:,} time "
        f"steps: t_end={params.t_end:g} ms, cfl={params.cfl:g}, c0={params.c0:g} m/s, "
        f"c_slope={params.c_slope:g}, mu={params.mu:g} Pa s at resolution {params.resolution} "
        f"give an estimated {steps:.3g} steps ({limit} limit); {what}")
