"""CF check of every kind of netCDF file the project writes: a run file (``airpuff run``), a sweep
point file and a combined ``sweep.nc``, with the IOOS compliance-checker at the CF version each
file declares in its ``Conventions`` attribute.

    python -m tools.cf_check [--out DIR]     # about 10 s; prints the checker's findings

The checker works offline: without a ``standard_name_vocabulary`` attribute it uses the standard
name table it ships with.  ``tests/sweep/test_cf.py`` runs the same check on the same three kinds.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import netCDF4

from airpuff_core import RunParams, simulate
from airpuff_core.dataset import write_netcdf
from sweep.combine import write_sweep
from sweep.grid import SweepSpec
from sweep.storage import point_key, point_path, save_point
from sweep.worker import compute_point

SHORT = {"resolution": "coarse", "t_end": 0.5}  # a short run: the file's structure is all that counts


def write_files(out_dir: Path) -> dict[str, Path]:
    """One file of each kind in ``out_dir``: {"run": ..., "point": ..., "sweep": ...}."""
    out_dir.mkdir(parents=True, exist_ok=True)
    params = RunParams(**SHORT)
    run = write_netcdf(simulate(params).to_dataset(), out_dir / "run.nc")
    spec = SweepSpec(E0=[0.5], IOP=[16.0], options=dict(SHORT)).validate()
    points = out_dir / "points"
    for p in spec.points():
        save_point(points, point_key(p), *compute_point(p))
    point = point_path(points, point_key(next(iter(spec.points()))))
    sweep = write_sweep(spec, points, out_dir / "sweep.nc")
    return {"run": run, "point": point, "sweep": sweep}


def checker_name(path: Path) -> str:
    """'cf:1.10' for a file whose Conventions attribute is 'CF-1.10'."""
    with netCDF4.Dataset(path) as nc:
        conventions = nc.getncattr("Conventions")
    cf = [c for c in conventions.replace(",", " ").split() if c.startswith("CF-")]
    if len(cf) != 1:
        raise ValueError(f"{path}: Conventions {conventions!r} names no single CF version")
    return "cf:" + cf[0][3:]


def cf_findings(path: Path) -> dict[str, list[str]]:
    """The compliance-checker's failed checks for ``path`` at its declared CF version:
    {"errors": [...], "warnings": [...], "info": [...]} (high, medium, low priority messages),
    plus "version" (the checker suite used)."""
    from compliance_checker.runner import CheckSuite

    suite = CheckSuite()
    suite.load_all_available_checkers()
    name = checker_name(path)
    ds = suite.load_dataset(str(path))
    groups, exceptions = suite.run_all(ds, [name], skip_checks=[])[name]
    if exceptions:
        raise RuntimeError(f"the checker failed on {path}: {exceptions}")
    agg = suite.build_structure(name, groups, str(path), 1)
    found = {"version": [name]}
    for key, label in (("high_priorities", "errors"), ("medium_priorities", "warnings"),
                       ("low_priorities", "info")):
        found[label] = [f"{r.name}: {m}" for r in agg[key] if r.value[0] < r.value[1]
                        for m in r.msgs]
    return found


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="folder for the three files (default: a temporary folder)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        files = write_files(Path(args.out or tmp))
        for kind, path in files.items():
            found = cf_findings(path)
            print(f"{kind} file ({path.name}), checker {found['version'][0]}: "
                  f"{len(found['errors'])} errors, {len(found['warnings'])} warnings, "
                  f"{len(found['info'])} info")
            for label in ("errors", "warnings", "info"):
                for msg in found[label]:
                    print(f"  {label[:-1]}: {msg}")


if __name__ == "__main__":
    main()
