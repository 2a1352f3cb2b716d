"""The Dask side of a sweep: starting or joining a cluster, and the Numba cache the workers share.

Why the care with Numba: every worker process would otherwise compile the solver's kernels itself
(seconds each), and several processes compiling into one empty cache at once can corrupt it
(numba#4807, #10434).  So the client process compiles once into ``NUMBA_CACHE_DIR``
(``warm_numba_cache``), and worker processes, started with the same ``NUMBA_CACHE_DIR`` and
``NUMBA_NUM_THREADS=1`` (one thread per worker, no oversubscription of the cores by Numba's own
thread pool), only load the compiled code.

Interface used by the HTTP API (issue 5): ``make_client(workers=2, scheduler=None)``,
``close_client(client)``, ``warm_numba_cache(params=None)``, ``shared_numba_cache_dir()``.
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile
import time
from pathlib import Path

log = logging.getLogger(__name__)

# Environment for worker processes.  distributed's Nanny already pins the BLAS/OpenMP pools to one
# thread, but not Numba's (dask/distributed#9075), hence NUMBA_NUM_THREADS.
WORKER_THREAD_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
}

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


def worker_env() -> dict[str, str]:
    """Environment variables for worker processes (one thread each, shared Numba cache)."""
    env = dict(WORKER_THREAD_ENV)
    cache = shared_numba_cache_dir()
    if cache:
        env["NUMBA_CACHE_DIR"] = cache
    return env


def make_client(workers: int = 2, scheduler: str | None = None, **cluster_kwargs):
    """A ``distributed.Client`` for a sweep.

    ``scheduler`` None: start a ``LocalCluster`` of ``workers`` worker *processes* with one thread
    each (the solver and netCDF4 are not thread-safe; processes also sidestep the GIL), the
    environment of :func:`worker_env`, and its HTTP endpoint on a free port (8787 may be taken by
    another cluster).  Otherwise connect to the Dask scheduler at ``scheduler`` (e.g. ``"tcp://host:8786"``); those workers must have been started with one
    thread each, ``NUMBA_NUM_THREADS=1`` and a ``NUMBA_CACHE_DIR`` and output folder on a file
    system they share with this process -- :func:`check_workers` reports what it can see.
    Close it with :func:`close_client`, which also shuts a LocalCluster down.
    """
    from distributed import Client, LocalCluster

    if scheduler:
        return Client(scheduler)
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers!r}")
    kwargs = dict(n_workers=int(workers), threads_per_worker=1, processes=True,
                  dashboard_address=":0", env=worker_env())
    kwargs.update(cluster_kwargs)
    cluster = LocalCluster(**kwargs)
    try:
        return Client(cluster)
    except BaseException:
        cluster.close()
        raise


def close_client(client) -> None:
    """Close ``client`` and, if it runs on a LocalCluster, shut that cluster down too."""
    cluster = getattr(client, "cluster", None)
    try:
        client.close()
    finally:
        if cluster is not None:
            cluster.close()


def _worker_report() -> dict:
    import os as _os

    return {"pid": _os.getpid(),
            "NUMBA_NUM_THREADS": _os.environ.get("NUMBA_NUM_THREADS"),
            "NUMBA_CACHE_DIR": _os.environ.get("NUMBA_CACHE_DIR")}


def check_workers(client) -> list[str]:
    """Warnings about workers that would oversubscribe the cores or miss the warmed cache."""
    warnings = []
    try:
        reports = client.run(_worker_report)
        info = client.scheduler_info()["workers"]
    except Exception as err:  # a diagnostic only; never fail a sweep on it
        return [f"could not inspect the workers: {err}"]
    expected_cache = shared_numba_cache_dir()
    for addr, rep in reports.items():
        nthreads = info.get(addr, {}).get("nthreads")
        if nthreads not in (None, 1):
            warnings.append(f"worker {addr} runs {nthreads} threads; start workers with --nthreads 1")
        if rep.get("NUMBA_NUM_THREADS") != "1":
            warnings.append(f"worker {addr} has NUMBA_NUM_THREADS={rep.get('NUMBA_NUM_THREADS')}; "
                            "set NUMBA_NUM_THREADS=1 in the worker environment")
        if expected_cache and rep.get("NUMBA_CACHE_DIR") != expected_cache:
            warnings.append(f"worker {addr} uses NUMBA_CACHE_DIR={rep.get('NUMBA_CACHE_DIR')}, "
                            f"not the warmed {expected_cache}: it will compile the solver itself")
    return warnings


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
    from airpuff_core.params import RunParams
    from airpuff_core import simulate

    t0 = time.perf_counter()
    for base in (params if params is not None else RunParams(), fallback):
        if base is None:
            continue
        tiny = base.replace(resolution="coarse", t_end=min(base.t_end, WARMUP_T_END_MS))
        try:
            simulate(tiny)
            break
        except Exception as err:  # noqa: BLE001 - the point of the call is the compilation
            log.warning("Numba warm-up run failed (kernels compiled so far stay cached): %s", err)
    return time.perf_counter() - t0


def jit_counts() -> dict[str, tuple[int, int]]:
    """Numba compile statistics of this process: qualified kernel name -> (cache loads, compiles).

    Counts every Numba dispatcher defined in an ``airpuff_core`` module.  A compile is a cache
    miss (Numba compiled the function in this process); a load is a cache hit.  ``run_point``
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
