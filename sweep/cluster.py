"""The Dask side of a sweep: starting or joining a cluster, and checking and warming its workers.

Worker processes run one task thread each and are started with ``NUMBA_NUM_THREADS=1`` (no
oversubscription of the cores by Numba's own thread pool) and the ``NUMBA_CACHE_DIR`` that the
client warmed (``sweep.numba_cache``), so that they load the compiled kernels instead of
compiling them.

Used by ``sweep.runner`` and the HTTP service's runner: ``make_client(workers=2,
scheduler=None)``, ``close_client(client)``, ``check_workers(client)``; and
``warm_workers(client, params=None)``, which makes the workers pay their own start-up (imports,
Numba's set-up, loading the kernels) before they get points.
"""

from __future__ import annotations

import os
import sys
import time
import uuid

from .numba_cache import shared_numba_cache_dir, warmup_params

# Environment for worker processes.  distributed's Nanny already pins the BLAS/OpenMP pools to one
# thread, but not Numba's (dask/distributed#9075), hence NUMBA_NUM_THREADS.  The Nanny applies
# this ``env`` inside the new process after distributed has imported numpy, so it reaches Numba
# (imported later, with the solver) but would come too late for the BLAS pool; that one is pinned
# by the Nanny's ``pre-spawn-environ`` (a LocalCluster worker then runs 3 OS threads, Numba's
# pool 1).  ``check_workers`` reports a worker whose variables or whose Numba say otherwise.
WORKER_THREAD_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
}

# Dask settings of a LocalCluster.  Every Dask server (the scheduler and the nannies, in this
# process, and each worker) wakes up at ``tick.interval`` only to measure how long its event loop
# was blocked, for a warning after seconds.  The default 20 ms costs this process twice the CPU
# of 500 ms (docs/performance.md, "What made the difference"); with as many workers as cores that
# CPU is taken from the workers.
LOCAL_CLUSTER_CONFIG = {"distributed.admin.tick.interval": "500ms"}


def pin_numba_threads_for_cluster_host() -> None:
    """Keep this process's Numba thread pool to one thread: call it first thing in a process
    that starts LocalClusters (``airpuff sweep``, ``serve``, ``identify``, ``sweep.demo``).
    Such a process solves only tiny warm-up runs, but those start Numba's pool (the MFPM build
    runs in a parallel loop), and a nanny that starts a worker sets NUMBA_NUM_THREADS=1 in this
    process's environment, after which Numba refuses to compile if its pool has another size
    (airpuff_core/threads.py).  Does nothing once Numba's pool is running."""
    numba = sys.modules.get("numba")
    if numba is not None:
        from numba.np.ufunc import parallel

        if parallel._is_initialized:
            return
    os.environ["NUMBA_NUM_THREADS"] = "1"
    if numba is not None:
        numba.config.reload_config()


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
    thread each, ``NUMBA_NUM_THREADS=1`` and a warm ``NUMBA_CACHE_DIR`` (results come back
    through Dask, ``sweep.engine``) -- :func:`check_workers` reports what it can see.
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
    parent_env = {name: os.environ.get(name) for name in WORKER_THREAD_ENV}
    with dask.config.set(config):  # read by each server and nanny as it is made
        cluster = LocalCluster(**kwargs)
    # a nanny applies its pre-spawn environment to this process too, for good: put it back, or
    # Numba here refuses to compile once it has started a thread pool of another size
    # (airpuff_core/threads.py; a nanny that restarts a worker sets it again)
    for name, value in parent_env.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
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


def warm_workers(client, params=None) -> dict[str, dict]:
    """Make every worker of ``client`` pay its start-up now: one tiny point on each.

    A fresh worker process imports the solver and the netCDF stack, sets Numba up and loads each
    kernel from the cache on its first point (about a second; see ``benchmarks/bench_compile.py``).
    Run this after the cluster is up and before submitting points, and the points then all run on
    warm workers: their times measure the solver, and a worker that would compile (a cache that
    does not fit its CPU, or a worker started without the shared ``NUMBA_CACHE_DIR``) shows up
    here.  The tiny point is ``params`` (a ``RunParams``: the sweep's options) shortened as in
    ``sweep.numba_cache.warm_numba_cache``; it goes through ``sweep.worker.compute_point``, the
    code path of a real point, and writes nothing outside a private temporary folder.  The
    client's own cache must be warm first (``sweep.numba_cache.warm_numba_cache``), or the
    workers compile concurrently.

    Returns worker address -> ``{"pid", "seconds" (wall time of the warm-up on the worker [s]),
    "status" ("ok" / "failed"), "message", "jit_compiled", "jit_loaded"}``; a worker whose
    warm-up task could not run at all gets ``{"status": "failed", "message": ...}``.
    """
    tiny = warmup_params(params)[0]
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


def _warm_this_worker(params) -> dict:
    """(On a worker) one tiny point through ``compute_point``; its timing and Numba activity."""
    t0 = time.perf_counter()
    from .worker import compute_point  # on the worker: the solver is imported here, not above

    record, _ = compute_point(params)
    return {"pid": os.getpid(), "seconds": time.perf_counter() - t0, "status": record.status,
            "message": record.message, "jit_compiled": record.jit_compiled,
            "jit_loaded": record.jit_loaded}


