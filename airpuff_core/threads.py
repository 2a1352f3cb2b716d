"""How many threads one run's kernels use (docs/performance.md, "Threads").

The MFPM build (``kernels/mfpm.mfpm_derivatives``) and the hyperviscous passes (``pair_flow``,
``adjoint_flow``) split their nodes into contiguous chunks that run in
Numba's parallel loops (``chunks``).  A node's result never depends on the chunking, the
adjoint's sums are added in a fixed order, and the kernels' sums are never reassociated (fused
multiply-adds are their only liberty: ``kernels.mfpm.FUSED_MULTIPLY_ADD``), so a run
gives the same numbers, bit for bit, with any number of threads, in any process.  A single run
(``simulate``, ``airpuff run``) uses every core Numba sees (``NUMBA_NUM_THREADS``) unless told
otherwise; a sweep's points run on one thread each (``sweep.worker``), since the sweep already
keeps every core busy with a point.

Threads pay only with an OpenMP or TBB threading layer: Numba's fallback ``workqueue`` layer
slows a run down with two threads and even on one (docs/performance.md, "Threads"), so without
one of those layers a run keeps to one thread.  The OpenMP layer needs libgomp (``libgomp1``),
which the Docker image installs.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import threading

from .params import ParameterError

CHUNKS_PER_THREAD = 4
SERIAL_BELOW = 256  # nodes

_FAST_LAYERS = {"omp": "numba.np.ufunc.omppool", "tbb": "numba.np.ufunc.tbbpool"}
_state = threading.local()


@functools.cache
def _fast_layer_available() -> bool:
    """True if Numba can use an OpenMP or TBB threading layer here (and is allowed to)."""
    import numba

    wanted = str(numba.config.THREADING_LAYER).lower()
    layers = [wanted] if wanted in _FAST_LAYERS else (
        list(_FAST_LAYERS) if wanted in ("default", "threadsafe", "forksafe", "safe") else [])
    for name in layers:
        try:
            importlib.import_module(_FAST_LAYERS[name])
            return True
        except ImportError:
            continue
    return False


def max_threads() -> int:
    """The most threads a run may use: Numba's ``NUMBA_NUM_THREADS`` (the cores, unless the
    environment sets it), or 1 without a fast threading layer.  Reads Numba's configuration
    only: it does not start Numba's thread pool."""
    import numba

    return int(numba.config.NUMBA_NUM_THREADS) if _fast_layer_available() else 1


def current_threads() -> int:
    """The threads the kernels use now, in this (Python) thread: set by ``solver_threads``; 1
    outside it."""
    return getattr(_state, "threads", 1)


def chunks(n_items: int) -> int:
    """How many contiguous chunks a parallel kernel splits ``n_items`` nodes into: one with one
    thread (the kernel's plain serial loop) or with fewer than SERIAL_BELOW nodes (waking the
    other threads would cost more than they save: the cornea's nodes in the coupling),
    otherwise CHUNKS_PER_THREAD per thread (node supports differ in size near walls).
    Computed here, in Python: a compiled function that asks Numba for its thread count could
    not be cached."""
    threads = current_threads()
    if threads == 1 or n_items < SERIAL_BELOW:
        return 1
    return min(n_items, CHUNKS_PER_THREAD * threads)


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
    """Run the enclosed kernels on ``threads`` threads (``check_threads``; None: all), then
    restore the setting of the calling thread (airpuff's and Numba's).

    With one thread the kernels take their serial branches, but Numba starts its thread pool
    (NUMBA_NUM_THREADS threads) as soon as it loads a kernel with a parallel loop, whatever the
    thread count.  That matters in a process that also starts a Dask LocalCluster (a sweep's
    client, which solves tiny warm-up runs): the cluster's nannies set
    NUMBA_NUM_THREADS=1 in this process's environment to start their workers, and Numba refuses
    to compile anything once the environment disagrees with the size of a pool it has started.
    ``airpuff sweep``, ``serve`` and ``identify`` and ``sweep.demo`` therefore set
    NUMBA_NUM_THREADS=1 first (``sweep.cluster.pin_numba_threads_for_cluster_host``), and
    ``sweep.cluster.make_client`` puts the variable back after its workers have started, which
    covers a script that ran a multi-threaded run first (until a nanny restarts a worker)."""
    value = check_threads(threads)
    before = current_threads()
    _state.threads = value
    pool_before = None
    if value > 1:
        import numba

        pool_before = numba.get_num_threads()
        numba.set_num_threads(value)
    try:
        yield value
    finally:
        _state.threads = before
        if pool_before is not None:
            import numba

            numba.set_num_threads(pool_before)
