"""airpuff_core: the physics of one air-puff run (Fung membrane cornea + MFPM aqueous humour).

Public API::

    from airpuff_core import RunParams, simulate
    result = simulate(RunParams(E0=0.5, IOP=16, resolution="coarse"))
    result.metrics            # P1, P2, CH, IOPg, IOPcc (mmHg), t_A1, t_A2, t_HC (ms), DA (mm), ...
    result.to_dataset()       # CF-annotated xarray.Dataset (docs/model.md section 7)

The modules, in the order of a run, are described in docs/model.md section 9.
"""

from .errors import SimulationError
from .params import ParameterError, RunParams
from .version import __version__


def simulate(params, progress=None, threads=None):
    """Run one coupled simulation; see :func:`airpuff_core.solver.simulate`."""
    from .solver import simulate as _simulate

    return _simulate(params, progress=progress, threads=threads)


__all__ = ["RunParams", "ParameterError", "SimulationError", "simulate", "__version__"]
