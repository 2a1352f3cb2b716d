"""The Dask side of a sweep: starting or joining a cluster, and the Numba cache the workers share.

Why the care with Numba: every worker process would otherwise compile the solver's kernels itself
(seconds each), and several processes compiling into one empty cache at once can corrupt it
(numba#4807, #10434).  So the client process compiles once into ``NUMBA_CACHE_DIR``
(``warm_numba_cache``), and worker processes, started with the same ``NUMBA_CACHE_DIR`` and
``NUMBA_NUM_THREADS=1`` (one thread per worker, no oversubscription of the cores by Numba's own
thread pool), only load the compiled code.

Interface used by the HTTP API (issue 5): ``make_client(workers=2, scheduler=None)``,
``close_client(client)``, ``warm_numba_cache(params=None)``, ``shared_numba_cache_dir()``; and
``warm_workers(client, params=None)``, which makes the workers pay their own start-up (imports,
Numba's set-up, loading the kernels) before they get points.
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile
import time
import uuid
from pathlib import Path

log = logging.getLogger(__name__)

# Environment for worker processes.  distributed's Nanny already pins the BLAS/OpenMP pools to one
# thread, but not Numba's (dask/distributed#9075), hence NUMBA_NUM_THREADS.  The Nanny applies
# this ``env`` inside the new process after distributed has imported numpy, so it reaches Numba
# (imported later, with the solver) but would come too late for the BLAS pool; that one is pinned
# by the Nanny's ``pre-spawn-environ`` (measured: a LocalCluster worker runs 3 OS threads, Numba
# with 1 thread).  ``check_workers`` reports a worker whose variables or whose Numba say otherwise.
WORKER_THREAD_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
}

# Dask settings of a LocalCluster.  Every Dask server (the scheduler and the nannies, in this
# process, and each worker) wakes up at ``tick.interval`` only to measure how long its event loop
# was blocked, for a warning after seconds.  At the default 20 ms this process alone used 7 % of a
# core during a sweep, 3.6 % at 500 ms (measured, 1 worker); with as many workers as cores that
# CPU is taken from the workers.
LOCAL_CLUSTER_CONFIG = {"distributed.admin.tick.interval": "500ms"}

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
    Close it with :func:`close_client`, which also shuts a LocalCluster down.  A LocalCluster's
    scheduler, nannies and workers run with ``LOCAL_CLUSTER_CONFIG``.
    """
    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        return Client(scheduler)
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers!r}")
    kwargs = dict(n_workers=int(workers), threads_per_worker=1, processes=True,
                  dashboard_address=":0", env=worker_env())
    kwargs.update(cluster_kwargs)
    # the Nanny sets ``pre-spawn-environ`` before the worker process starts, so Numba, imported
    # early in a worker (through distributed), reads NUMBA_NUM_THREADS=1 too
    spawn_env = {**dask.config.get("distributed.nanny.pre-spawn-environ", {}), **WORKER_THREAD_ENV}
    config = {**LOCAL_CLUSTER_CONFIG, "distributed.nanny.pre-spawn-environ": spawn_env}
    with dask.config.set(config):  # read by each server and nanny as it is made
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
    import sys as _sys

    report = {"pid": _os.getpid(), "NUMBA_CACHE_DIR": _os.environ.get("NUMBA_CACHE_DIR")}
    report.update({name: _os.environ.get(name) for name in WORKER_THREAD_ENV})
    numba = _sys.modules.get("numba")  # what Numba read at its import, if it is imported
    report["numba_threads"] = None if numba is None else numba.config.NUMBA_NUM_THREADS
    return report


def check_workers(client) -> list[str]:
    """Warnings about workers that would oversubscribe the cores or miss the warmed cache.

    Each worker must run one task thread, and Numba's, OpenMP's and the BLAS thread pools must be
    limited to one thread (``WORKER_THREAD_ENV``): a worker's own pools would otherwise compete
    with the other workers for the cores, which is what stops a sweep from scaling.
    """
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
        for name, value in WORKER_THREAD_ENV.items():
            if rep.get(name) != value:
                warnings.append(f"worker {addr} has {name}={rep.get(name)}; "
                                f"set {name}={value} in the worker environment")
        if rep.get("numba_threads") not in (None, 1):
            warnings.append(f"worker {addr}: Numba was imported with {rep['numba_threads']} "
                            "threads, before NUMBA_NUM_THREADS=1 took effect")
        if expected_cache and rep.get("NUMBA_CACHE_DIR") != expected_cache:
            warnings.append(f"worker {addr} uses NUMBA_CACHE_DIR={rep.get('NUMBA_CACHE_DIR')}, "
                            f"not the warmed {expected_cache}: it will compile the solver itself")
    return warnings


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
            simulate(tiny)
            break
        except Exception as err:  # noqa: BLE001 - the point of the call is the compilation
            log.warning("Numba warm-up run failed (kernels compiled so far stay cached): %s", err)
    return time.perf_counter() - t0


def warm_workers(client, params=None) -> dict[str, dict]:
    """Make every worker of ``client`` pay its start-up now: one tiny point on each.

    A fresh worker process imports the solver and the netCDF stack, sets Numba up and loads each
    kernel from the cache on its first point (about a second; see ``benchmarks/bench_compile.py``).
    Run this after the cluster is up and before submitting points, and the points then all run on
    warm workers: their times measure the solver, and a worker that would compile (a cache that
    does not fit its CPU, or a worker started without the shared ``NUMBA_CACHE_DIR``) shows up
    here.  The tiny point is ``params`` (a ``RunParams``: the sweep's options) shortened as in
    :func:`warm_numba_cache`; it goes through ``sweep.store.compute_point``, the code path of a
    real point, and writes nothing outside a private temporary folder.  The client's own cache
    must be warm first (:func:`warm_numba_cache`), or the workers compile concurrently.

    Returns worker address -> ``{"pid", "seconds" (wall time of the warm-up on the worker [s]),
    "status" ("ok" / "failed"), "message", "jit_compiled", "jit_loaded"}``; a worker whose
    warm-up task could not run at all gets ``{"status": "failed", "message": ...}``.
    """
    tiny = warmup_params(params)[0].to_dict()
    batch = uuid.uuid4().hex[:8]
    futures = {
        addr: client.submit(_warm_this_worker, tiny, key=f"airpuff-warm-{batch}-{i}", pure=False,
                            workers=[addr], allow_other_workers=False)
        for i, addr in enumerate(sorted(client.scheduler_info()["workers"]))}
    reports = {}
    for addr, fut in futures.items():
        try:
            reports[addr] = fut.result()
        except Exception as err:  # noqa: BLE001 - a diagnostic; the sweep itself may still run
            reports[addr] = {"status": "failed", "message": f"{type(err).__name__}: {err}"}
        finally:
            fut.release()
    return reports


def _warm_this_worker(params_dict: dict) -> dict:
    """(On a worker) one tiny point through ``compute_point``; its timing and Numba activity."""
    t0 = time.perf_counter()
    from sweep.store import compute_point

    record, _ = compute_point(params_dict)
    return {"pid": os.getpid(), "seconds": time.perf_counter() - t0, "status": record["status"],
            "message": record["message"], "jit_compiled": record["jit_compiled"],
            "jit_loaded": record["jit_loaded"]}


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
