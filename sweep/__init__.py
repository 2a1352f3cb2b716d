"""sweep: many air-puff runs -- a grid over E0, IOP, thickness and pmax on Dask, stored as netCDF.

Command line::

    airpuff sweep --E0 0.3,0.5,0.7 --IOP 10:25:4 --resolution coarse --workers 2 --out results/
    airpuff sweep ... --scheduler tcp://host:8786      # an existing Dask cluster instead

Python::

    from sweep.grid import SweepSpec
    from sweep.runner import run_sweep

    spec = SweepSpec(E0=[0.3, 0.5], IOP=[12, 16, 20], options={"resolution": "coarse"})
    outcome = run_sweep(spec, "results")          # -> results/sweep.nc
    xarray.open_dataset(outcome.path, decode_times=False)["CH"].sel(E0=0.5)

One module, one job:

* ``grid``           -- which runs: axes in user units, validation, C-ordered points
* ``storage``        -- where results live: point keys (a parameter hash), file names, atomic
                        writes, point records (one netCDF or one failure record per point)
* ``worker``         -- the task of one point on a Dask worker: simulate, JIT accounting, failures
* ``combine``        -- the point files of a sweep combined into ``sweep.nc``
* ``numba_cache``    -- the Numba cache the processes share: location, warm-up, compile counts
* ``cluster``        -- the Dask cluster: start or join, check and warm its workers
* ``runner``         -- the order of events: skip stored points, warm the cache, fan out, combine
* ``report``         -- progress bar and summary table; ``plots`` -- figures of a sweep
* ``identification`` -- the inverse problem: IOP and E0 from a measurement, on a stored sweep
* ``demo``           -- ``make demo``

The command line (``airpuff sweep``, ``airpuff identify``) lives in ``api.cli``.
"""
