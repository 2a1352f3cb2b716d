"""The default sweep of ``make demo``: a small grid at coarse resolution on 2 local workers.

    python -m sweep.demo --out demo_out

Writes ``OUT/sweep.nc`` (layout: ``sweep.combine``; the per-point files: docs/model.md, section 7)
and ``OUT/metrics_vs_IOP.png`` (IOPg, CH and DA against IOP, one line per E0) and prints where they are.  Running it again reuses the stored points.
"""

from __future__ import annotations

import argparse
import sys

from .grid import SweepSpec

# 2 x 3 points at the paper's jet (pmax 10 kPa) and corneal thickness (0.5 mm); a coarse run of the
# full 35 ms took about 1 min here, so on 2 workers the grid takes about 3-4 minutes.
DEMO_E0 = [0.3, 0.6]  # MPa
DEMO_IOP = [10.0, 16.0, 22.0]  # mmHg
DEMO_OPTIONS = {"resolution": "coarse"}


def demo_spec() -> SweepSpec:
    return SweepSpec(E0=DEMO_E0, IOP=DEMO_IOP, thickness=[0.5], pmax=[10.0],
                     options=dict(DEMO_OPTIONS)).validate()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sweep.demo", description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="demo_out", metavar="DIR", help="output folder (default demo_out)")
    parser.add_argument("--workers", type=int, default=2, metavar="N", help="local worker processes (default 2)")
    args = parser.parse_args(argv)

    import xarray as xr

    from .plots import plot_metrics_vs_iop
    from .report import SweepProgress, summary_table
    from .runner import run_sweep

    spec = demo_spec()
    print(f"demo sweep: E0 {DEMO_E0} MPa x IOP {DEMO_IOP} mmHg, thickness 0.5 mm, pmax 10 kPa, "
          f"coarse resolution, {spec.n_points} points on {args.workers} local workers -> {args.out}/",
          flush=True)
    progress = SweepProgress()
    try:
        outcome = run_sweep(spec, args.out, workers=args.workers, progress=progress)
    except KeyboardInterrupt:
        progress.close()
        print(f"interrupted; finished points are stored in {args.out}/points; run again to resume",
              file=sys.stderr)
        return 130
    progress.close()
    print(summary_table(outcome))
    with xr.open_dataset(outcome.path) as ds:
        png = plot_metrics_vs_iop(ds.load(), outcome.out_dir / "metrics_vs_IOP.png")
    print(f"\nsweep dataset: {outcome.path.resolve()}")
    print(f"figure:        {png.resolve()}")
    print(f"explore it:    python examples/analyze_sweep.py {outcome.path}")
    return 0 if outcome.ok else 1


if __name__ == "__main__":
    sys.exit(main())
