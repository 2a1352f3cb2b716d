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

* ``grid``    -- which runs: axes in user units, validation, C-ordered points
* ``store``   -- where results live: one atomic netCDF per point (keyed by a parameter hash),
                 failure records, and the combined ``sweep.nc`` (SPEC section 7)
* ``cluster`` -- the Dask cluster and the shared Numba cache
* ``runner``  -- the order of events: skip stored points, warm the cache, fan out, combine
* ``report``  -- progress bar and summary table; ``plots`` -- figures of a sweep
* ``cli``     -- ``airpuff sweep``; ``demo`` -- ``make demo``
"""
