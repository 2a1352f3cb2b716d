"""One run: the coupled model stepped from t = 0 to t_end, watched by its observers.

``simulate`` is the whole algorithm of a run at the top level: build the ``CoupledModel``
(chamber, cornea at rest under IOP, globe, operators; ``coupling.py``), advance it step by step
to t_end (each step: step control, fluid predictor, Dirichlet-Neumann coupling, commit), and let
the observers see every step: the ``EnergyBudget`` (``energy.py``) adds each step's work, the
``BlowUpCheck`` (``blowup.py``) stops a run gone unphysical, and the ``Recorder``
(``recorder.py``) keeps the histories, snapshots and diagnostics from which the result and its
metrics are made.
"""

from __future__ import annotations

import time as _time

from .blowup import BlowUpCheck
from .budget import check_step_budget
from .coupling import CoupledModel
from .energy import EnergyBudget
from .params import RunParams
from .recorder import Recorder
from .result import RunResult
from .threads import solver_threads

PROGRESS_INTERVAL = 0.2  # s of wall time between calls of ``progress``


def simulate(params: RunParams, progress=None, reuse: bool = True, threads=None,
             strain_limit=None, observers=()) -> RunResult:
    """Run one coupled simulation and return its histories, snapshots and metrics.

    ``progress(t_ms, t_end_ms)`` is called now and then.  ``reuse`` and ``strain_limit``: see
    ``CoupledModel``.
    ``observers``: more observers of the steps (studies), each built as ``observer(model)`` and
    then called like the recorder (``committed(model, dt)``, and ``coupled(model, dt)``).
    ``threads``: how many threads the kernels use (``threads.py``; default Numba's setting, every
    core it sees unless changed); the result does not depend on it.  Raises SimulationError on blow-up, non-convergent
    coupling or an ill-conditioned operator (the message names the time), ParameterError on a
    bad ``threads`` or a run estimated above the step budget (``budget.check_step_budget``).
    """
    with solver_threads(threads):
        return _simulate(params, progress, reuse, strain_limit, observers)


def _simulate(params, progress, reuse, strain_limit, extra_observers):
    check_step_budget(params)  # a run estimated above the budget never starts
    wall0 = _time.monotonic()
    model = CoupledModel(params, reuse, strain_limit)
    budget = EnergyBudget(model)
    recorder = Recorder(model, budget)
    observers = (budget, BlowUpCheck(), recorder) + tuple(make(model) for make in extra_observers)
    t_end = model.si.t_end_s
    last_progress = _time.monotonic()
    if progress:
        progress(0.0, t_end * 1e3)
    while model.t < t_end - 1e-15:
        model.step(t_stop=t_end, observers=observers)
        if progress and _time.monotonic() - last_progress > PROGRESS_INTERVAL:
            progress(model.t * 1e3, t_end * 1e3)
            last_progress = _time.monotonic()
    if progress:
        progress(t_end * 1e3, t_end * 1e3)
    return recorder.result(model, _time.monotonic() - wall0)
