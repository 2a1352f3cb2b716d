"""The Numba cache shared by a sweep's processes: where it is, warming it, and counting compiles.

Why the care: every worker process would otherwise compile the solver's kernels itself (seconds
each), and several processes compiling into one empty cache at once can corrupt it (numba#4807,
#10434).  So the client process compiles once into ``NUMBA_CACHE_DIR`` (:func:`warm_numba_cache`),
and worker processes, started with the same ``NUMBA_CACHE_DIR`` (``sweep.cluster.worker_env``),
only load the compiled code.  :func:`jit_counts` tells, per process, how many kernels were loaded
from the cache and how many compiled: that is how the tests and the Docker build check that a
warmed worker never compiles.

Nothing here imports the solver or Numba at module level (``benchmarks/bench_compile.py`` imports
this package before it sets the Numba environment).
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile
import time
from pathlib import Path

log = logging.getLogger(__name__)


# Length of the warm-up run [ms of simulated time]: long enough to pass through every kernel of a
# time step (and the output/metrics code), short enough to cost well under a second once compiled.
WARMUP_T_END_MS = 0.5


def _kernels_loaded() -> bool:
    """True if this process already holds Numba kernels of the solver (their cache location was
    fixed when they were defined, so changing NUMBA_CACHE_DIR now would not reach them)."""
    if "numba" not in sys.modules:
        return False
    return bool(_dispatchers())


def _dispatchers() -> dict:
    """Qualified name -> Numba dispatcher, for every kernel defined in an airpuff_core module."""
    from numba.core.dispatcher import Dispatcher

    found = {}
    for modname, module in list(sys.modules.items()):
        if module is None or not (modname == "airpuff_core" or modname.startswith("airpuff_core.")):
            continue
        for attr, obj in list(vars(module).items()):
            if isinstance(obj, Dispatcher) and getattr(obj, "__module__", modname) == modname:
                found[f"{modname}.{attr}"] = obj
    return found


def default_numba_cache_dir() -> Path:
    """A writable per-user cache folder (a fixed shared path would collide between users)."""
    uid = os.getuid() if hasattr(os, "getuid") else os.getlogin()
    return Path(tempfile.gettempdir()) / f"airpuff-numba-cache-{uid}"


def shared_numba_cache_dir() -> str | None:
    """The ``NUMBA_CACHE_DIR`` that this (client) process and the workers must share.

    * If ``NUMBA_CACHE_DIR`` is set (``make`` sets it), that folder.
    * Else, if the solver is not imported yet in this process, a per-user folder in the temp
      directory, which is then exported to this process's environment (and Numba's config), so
      the warm-up compiles into the folder the workers will read.
    * Else (solver already imported without ``NUMBA_CACHE_DIR``) None: this process already uses
      Numba's default location (``__pycache__`` next to the sources), and workers that are not
      given ``NUMBA_CACHE_DIR`` resolve that same location.
    """
    current = os.environ.get("NUMBA_CACHE_DIR")
    if current:
        return current
    if _kernels_loaded():
        return None
    path = default_numba_cache_dir()
    path.mkdir(parents=True, exist_ok=True)
    os.environ["NUMBA_CACHE_DIR"] = str(path)
    if "numba" in sys.modules:  # Numba reads its environment at import; make it see the change
        from numba.core import config

        config.reload_config()
    return str(path)



def warmup_params(params=None, fallback=None):
    """The tiny runs of a warm-up: ``params`` (default: all defaults) and then ``fallback`` (either
    may be None), shortened to ``WARMUP_T_END_MS`` at coarse resolution (kernel types do not
    depend on the node count)."""
    from airpuff_core.params import RunParams

    bases = (params if params is not None else RunParams(), fallback)
    return [b.replace(resolution="coarse", t_end=min(b.t_end, WARMUP_T_END_MS))
            for b in bases if b is not None]


def warm_numba_cache(params=None, fallback=None) -> float:
    """Compile the solver's kernels into the shared Numba cache by one tiny run in this process.

    Run it before fanning out, so that workers load compiled code instead of compiling it (and
    never compile into an empty cache concurrently).  ``params`` (a ``RunParams``, default: all
    defaults) should carry the sweep's options, because options such as ``geometry`` or
    ``c_rule`` may select other kernels; it is shortened to ``WARMUP_T_END_MS`` at coarse
    resolution (kernel types do not depend on the node count).  If that run fails early (which
    leaves the kernels after the failure uncompiled), ``fallback`` is tried as well; a failure
    is logged, never raised.  Returns the wall time [s].
    """
    shared_numba_cache_dir()
    from airpuff_core import simulate

    t0 = time.perf_counter()
    for tiny in warmup_params(params, fallback):
        try:
            simulate(tiny, threads=1)  # compiles every kernel; starts no thread pool here
            break
        except Exception as err:  # noqa: BLE001 - the point of the call is the compilation
            log.warning("Numba warm-up run failed (kernels compiled so far stay cached): %s", err)
    return time.perf_counter() - t0



def jit_counts() -> dict[str, tuple[int, int]]:
    """Numba compile statistics of this process: qualified kernel name -> (cache loads, compiles).

    Counts every Numba dispatcher defined in an ``airpuff_core`` module.  A compile is a cache
    miss (Numba compiled the function in this process); a load is a cache hit.  ``compute_point``
    records the difference before/after each point, which is how the tests check that a warmed
    worker never compiles.
    """
    if "numba" not in sys.modules:
        return {}
    counts: dict[str, tuple[int, int]] = {}
    for name, disp in _dispatchers().items():
        stats = disp.stats
        counts[name] = (int(sum(stats.cache_hits.values())), int(sum(stats.cache_misses.values())))
    return counts


def jit_delta(before: dict[str, tuple[int, int]],
              after: dict[str, tuple[int, int]]) -> tuple[int, int]:
    """(compiles, cache loads) between two :func:`jit_counts` snapshots of this process."""
    def grown(which: int) -> int:
        return int(sum(v[which] - before.get(k, (0, 0))[which] for k, v in after.items()))

    return grown(1), grown(0)
