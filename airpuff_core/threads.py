"""How many threads one run's kernels use (docs/performance.md, "Threads").

The MFPM build and the hyperviscous passes split their nodes into contiguous chunks that run in
parallel (``kernels.mfpm.chunks``); a node's result never depends on the chunking, so a run gives
the same numbers, bit for bit, with any number of threads.  A single run uses every core Numba
sees (``NUMBA_NUM_THREADS``); a sweep's workers run one thread each (``sweep.cluster``), since
the sweep already keeps every core busy with a point.

Threads pay only with an OpenMP or TBB threading layer: Numba's fallback ``workqueue`` layer
made a paper-resolution run 3.4 times slower with two threads (measured), so without one of
those layers a run keeps to one thread.
"""

from __future__ import annotations

import contextlib
import importlib

from .params import ParameterError

_FAST_LAYERS = {"omp": "numba.np.ufunc.omppool", "tbb": "numba.np.ufunc.tbbpool"}
_layer_cache: dict[str, bool] = {}


def _fast_layer_available() -> bool:
    """True if Numba can use an OpenMP or TBB threading layer here (and is allowed to)."""
    if "ok" not in _layer_cache:
        import numba

        wanted = str(numba.config.THREADING_LAYER).lower()
        layers = [wanted] if wanted in _FAST_LAYERS else (
            list(_FAST_LAYERS) if wanted in ("default", "threadsafe", "forksafe", "safe") else [])
        ok = False
        for name in layers:
            try:
                importlib.import_module(_FAST_LAYERS[name])
                ok = True
                break
            except ImportError:
                continue
        _layer_cache["ok"] = ok
    return _layer_cache["ok"]


def max_threads() -> int:
    """The most threads a run may use: Numba's ``NUMBA_NUM_THREADS`` (the cores, unless the
    environment sets it), or 1 without a fast threading layer."""
    import numba

    return int(numba.config.NUMBA_NUM_THREADS) if _fast_layer_available() else 1


def check_threads(threads) -> int:
    """``threads`` as an int in 1 ... ``max_threads()``; ParameterError (naming ``threads`` and
    the accepted range) otherwise.  None means ``max_threads()``."""
    top = max_threads()
    if threads is None:
        return top
    try:
        value = int(threads)
        if isinstance(threads, bool) or value != float(threads):
            raise ValueError
    except (TypeError, ValueError):
        raise ParameterError("threads", threads, f"an integer in [1, {top}]") from None
    if not 1 <= value <= top:
        raise ParameterError("threads", threads, f"an integer in [1, {top}]")
    return value


@contextlib.contextmanager
def solver_threads(threads=None):
    """Run the enclosed kernels on ``threads`` threads (``check_threads``), then restore Numba's
    setting of the calling thread."""
    value = check_threads(threads)
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(value)
    try:
        yield value
    finally:
        numba.set_num_threads(before)
