"""Stored results that can be trusted, on the `airpuff sweep` side: damaged point files,
the model version in the point key, provenance, failures of the model and of the infrastructure,
stale temporary files.  A real LocalCluster of two worker processes, the real solver (coarse,
t_end 1 ms), real files damaged the way a crash or a full disk leaves them.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from airpuff_core import RunParams, SimulationError, simulate
from airpuff_core.atomic import atomic_write
from airpuff_core.dataset import open_dataset
from airpuff_core.provenance import LIBRARIES, model_version, model_version_of
from sweep.grid import SweepSpec
from sweep.runner import run_sweep
from sweep.storage import DAMAGED_SUBDIR, failed_path, point_key, point_path

SHORT = {"resolution": "coarse", "t_end": 1.0}  # ms
CORE = Path(__file__).resolve().parents[2] / "airpuff_core"


def damaged_records(points_dir: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted((points_dir / DAMAGED_SUBDIR).glob("*.json"))]


@pytest.mark.slow
@pytest.mark.cluster
def test_unreadable_point_files_are_moved_aside_and_recomputed(dask_client, tmp_path):
    """Items 1 and 2: a truncated point file and a garbage failure record count as missing, also
    when the damage happens after the stored points were read (found when combining)."""
    spec = SweepSpec(E0=[0.4, 0.6], options=dict(SHORT)).validate()
    first = run_sweep(spec, tmp_path, client=dask_client)
    assert (first.computed, first.failed) == (2, 0)
    points = tmp_path / "points"
    k_truncated, k_garbage = (point_key(p) for p in spec.points())
    truncated = point_path(points, k_truncated)
    size = truncated.stat().st_size
    with open(truncated, "r+b") as fh:  # a disk that filled up mid-write, or a crash
        fh.truncate(size // 2)
    point_path(points, k_garbage).unlink()
    failed_path(points, k_garbage).write_bytes(os.urandom(300))  # garbage record

    again = run_sweep(spec, tmp_path, client=dask_client, retry_failed=True)  # --retry-failed
    assert (again.computed, again.reused, again.failed) == (2, 0, 0)
    truncated.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 64)  # garbage behind a valid magic
    resumed = run_sweep(spec, tmp_path, client=dask_client)  # a plain resume
    assert (resumed.computed, resumed.reused, resumed.failed) == (1, 1, 0)

    def damage_after_reading(record, counts):  # after the stored points were read, before combining
        if record is None:
            with open(point_path(points, k_garbage), "r+b") as fh:
                fh.truncate(1000)

    late = run_sweep(spec, tmp_path, client=dask_client, progress=damage_after_reading)
    assert (late.computed, late.reused, late.failed) == (1, 1, 0)
    records = damaged_records(points)
    assert sorted(r["key"] for r in records) == sorted([k_truncated, k_garbage, k_truncated,
                                                        k_garbage])
    assert all(r["reason"].startswith("unreadable") for r in records), records
    assert (points / DAMAGED_SUBDIR / records[0]["moved_to"]).exists()
    with open_dataset(tmp_path / "sweep.nc") as ds:
        assert list(ds["status"].values.ravel()) == ["ok", "ok"]
        assert np.isfinite(ds["DA"].values).all()


def test_model_version_hashes_code_not_comments(tmp_path):
    """Item 3: the model version changes with any code of the numerical modules (a new module
    included), not with a comment or docstring, nor with a file-writing module."""
    copy = tmp_path / "airpuff_core"
    shutil.copytree(CORE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    assert model_version_of(copy) == model_version()
    kernel = copy / "kernels" / "membrane.py"
    text = kernel.read_text()
    kernel.write_text("# a comment\n" + text.replace('"""', '"""Edited docstring. ', 1))
    assert model_version_of(copy) == model_version()
    (copy / "dataset.py").write_text((copy / "dataset.py").read_text() + "\nX_UNUSED = 1\n")
    assert model_version_of(copy) == model_version()
    kernel.write_text(text + "\nHYPOTHETICAL_FACTOR = 1.0000001\n")
    changed = model_version_of(copy)
    assert changed != model_version()
    kernel.write_text(text)
    (copy / "shell.py").write_text("SHELL_LAYERS = 3\n")  # a module added later counts too
    assert model_version_of(copy) not in (model_version(), changed)


@pytest.mark.cluster
def test_a_stored_point_of_another_model_version_is_not_reused(dask_client, tmp_path):
    """Item 3: a point file whose model version is not this one (here: edited, with a DA of
    9.99) is moved aside and recomputed; files carry their provenance, and sweep.nc each
    point's; the outcome says how many points were reused."""
    spec = SweepSpec(E0=[0.5], IOP=[14.0, 18.0], options=dict(SHORT)).validate()
    run_sweep(spec, tmp_path, client=dask_client)
    points = tmp_path / "points"
    key = point_key(spec.points()[0])
    path = point_path(points, key)
    with open_dataset(path) as ds:
        ds = ds.load()
    true_da = float(ds["DA"])
    for name in ("software_version", "model_version", "git_commit"):
        assert ds.attrs[name], name
    for lib in LIBRARIES:
        assert ds.attrs[f"{lib}_version"] not in ("", "not installed"), lib
    ds["DA"] = ds["DA"].copy(data=9.99)
    ds.attrs["model_version"] = "0ld0ld0ld0ld"
    path.unlink()
    ds.to_netcdf(path, engine="netcdf4")

    again = run_sweep(spec, tmp_path, client=dask_client)
    assert (again.computed, again.reused) == (1, 1)
    (record,) = damaged_records(points)
    assert record["key"] == key and "0ld0ld0ld0ld" in record["reason"]
    with open_dataset(tmp_path / "sweep.nc") as combined:
        da = combined["DA"].sel(IOP=14.0).squeeze()
        assert float(da) == pytest.approx(true_da, rel=1e-9, abs=0) and float(da) != 9.99
        assert set(combined["model_version"].values.ravel()) == {model_version()}
        prov = json.loads(str(combined["provenance"].values.ravel()[0]))
        assert prov["model_version"] == model_version() and "netCDF4_version" in prov
        assert combined.attrs["model_version"] == model_version()
        assert not os.path.isabs(combined.attrs["point_files"])
        assert combined.attrs["point_files"] == "points/<point_key>.nc"


@pytest.mark.cluster
def test_failures_of_the_infrastructure_are_rerun_those_of_the_model_kept(dask_client, tmp_path):
    """Item 6: a write error (a directory where the point file should go: an OSError on the
    rename, as a full disk gives) is retried automatically and never reused; the solver's own
    verdict is reused unless --retry-failed."""
    bad = RunParams(thickness=0.01, **SHORT)  # 10 um: the coupling diverges at once
    with pytest.raises(SimulationError):
        simulate(bad)
    spec = SweepSpec(E0=[0.5], IOP=[16.0], thickness=[0.01, 0.5], options=dict(SHORT)).validate()
    model_key, infra_key = (point_key(p) for p in spec.points())
    points = tmp_path / "points"
    blocker = point_path(points, infra_key)
    blocker.mkdir(parents=True)

    first = run_sweep(spec, tmp_path, client=dask_client)
    assert (first.computed, first.failed) == (2, 2)
    model_rec = json.loads(failed_path(points, model_key).read_text())
    infra_rec = json.loads(failed_path(points, infra_key).read_text())
    assert model_rec["kind"] == "model" and model_rec["error_type"] == "SimulationError"
    assert infra_rec["kind"] == "infrastructure", infra_rec
    assert "IsADirectoryError" in infra_rec["message"]
    assert str(tmp_path) not in infra_rec["message"]  # no path of this machine in a message

    blocker.rmdir()  # the disk has room again
    second = run_sweep(spec, tmp_path, client=dask_client)
    assert (second.computed, second.reused, second.failed) == (1, 1, 1)  # the model's kept
    third = run_sweep(spec, tmp_path, client=dask_client, retry_failed=True)
    assert (third.computed, third.reused, third.failed) == (1, 1, 1)  # asked: run again


@pytest.mark.cluster
def test_combining_clears_stale_temporary_files(dask_client, tmp_path):
    """Item 7: a kill during combining leaves `.sweep.nc.*.tmp`; the next combine removes it
    (if older than any combine takes), and a failed write leaves none."""
    stale = tmp_path / ".sweep.nc.abc123.tmp"
    fresh = tmp_path / ".sweep.nc.def456.tmp"  # another combine may be writing it right now
    for p in (stale, fresh):
        p.write_bytes(b"\x89HDF half a file")
    old = time.time() - 2 * 3600
    os.utime(stale, (old, old))
    spec = SweepSpec(E0=[0.5], options=dict(SHORT)).validate()
    run_sweep(spec, tmp_path, client=dask_client)
    assert not stale.exists() and fresh.exists()

    target = tmp_path / "x.bin"
    target.write_bytes(b"before")

    def fails(tmp):
        tmp.write_bytes(b"half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError):
        atomic_write(target, fails)
    assert target.read_bytes() == b"before"
    assert not list(tmp_path.glob(".x.bin.*"))
