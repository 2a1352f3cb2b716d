"""The default sweep of ``make demo``: the paper's and the clinical model on a small grid.

    python -m sweep.demo --out demo_out

The same 2 E0 x 3 IOP grid, once with the paper's model (membrane cornea, rigid globe, elastic) at
coarse resolution and once with the clinical preset (shear-deformable shell cornea, compliant
globe, viscoelastic; docs/model.md) at paper resolution, on one local Dask cluster of 2 workers.  Writes
``OUT/paper/sweep.nc`` and ``OUT/clinical/sweep.nc`` (layout: ``sweep.combine``; the per-point files
share ``OUT/points``) and ``OUT/metrics_vs_IOP.png`` (IOPg, CH and DA against IOP, one line per E0,
one row per model) and prints where they are.  Running it again reuses the stored points.
"""

from __future__ import annotations

import argparse
import sys

from .grid import SweepSpec

# 2 x 3 points at the paper's jet (pmax 10 kPa) and corneal thickness (0.5 mm), for each model.
# The clinical preset runs at paper resolution: coarse resolution reads the shear-deformable
# shell's CH up to 7 mmHg low at low IOP (docs/validation.md); its 6 points take about a minute.
DEMO_E0 = [0.3, 0.6]  # MPa
DEMO_IOP = [10.0, 16.0, 22.0]  # mmHg
DEMO_RESOLUTION = {"paper": "coarse", "clinical": "paper"}  # model -> resolution
DEMO_MODELS = tuple(DEMO_RESOLUTION)


def demo_spec(model: str = "paper") -> SweepSpec:
    return SweepSpec(E0=DEMO_E0, IOP=DEMO_IOP, thickness=[0.5], pmax=[10.0],
                     options={"resolution": DEMO_RESOLUTION[model], "model": model}).validate()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sweep.demo", description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="demo_out", metavar="DIR", help="output folder (default demo_out)")
    parser.add_argument("--workers", type=int, default=2, metavar="N", help="local worker processes (default 2)")
    args = parser.parse_args(argv)
    from .cluster import close_client, make_client, pin_numba_threads_for_cluster_host

    pin_numba_threads_for_cluster_host()
    import xarray as xr

    from .plots import plot_metrics_vs_iop
    from .report import SweepProgress, summary_table
    from .runner import run_sweep

    from pathlib import Path

    specs = {model: demo_spec(model) for model in DEMO_MODELS}
    n_points = sum(spec.n_points for spec in specs.values())
    print(f"demo sweep: E0 {DEMO_E0} MPa x IOP {DEMO_IOP} mmHg, thickness 0.5 mm, pmax 10 kPa, "
          f"models {', '.join(f'{m} ({r} resolution)' for m, r in DEMO_RESOLUTION.items())}: "
          f"{n_points} points on "
          f"{args.workers} local workers -> {args.out}/", flush=True)
    out = Path(args.out)
    outcomes = {}
    client = None
    try:
        for model, spec in specs.items():
            progress = SweepProgress()
            try:
                if client is None and not all(_stored(spec, out)):
                    client = make_client(workers=args.workers)
                outcomes[model] = run_sweep(spec, out / model, client=client, progress=progress,
                                            points_dir=out / "points")
            finally:
                progress.close()
    except KeyboardInterrupt:
        print(f"interrupted; finished points are stored in {args.out}/points; run again to resume",
              file=sys.stderr)
        return 130
    finally:
        if client is not None:
            close_client(client)
    for model, outcome in outcomes.items():
        print(f"\n{model} model:")
        print(summary_table(outcome))
    datasets = {}
    for model, outcome in outcomes.items():
        with xr.open_dataset(outcome.path) as ds:
            datasets[model] = ds.load()
    png = plot_metrics_vs_iop(datasets, out / "metrics_vs_IOP.png")
    for model, outcome in outcomes.items():
        print(f"\nsweep dataset ({model}): {outcome.path.resolve()}")
    print(f"figure:        {png.resolve()}")
    print(f"explore it:    python examples/analyze_sweep.py {outcomes['clinical'].path}")
    return 0 if all(o.ok for o in outcomes.values()) else 1


def _stored(spec: SweepSpec, out) -> list[bool]:
    """Whether each point of ``spec`` is stored in ``out/points`` already."""
    from .storage import point_key, read_point

    return [read_point(out / "points", point_key(p)) is not None for p in spec.validated_points()]


if __name__ == "__main__":
    sys.exit(main())
