"""The instruments' calibration (airpuff_core/calibration.py, docs/calibration.md): the fit against
a known linear map, the apply step on a real coarse run (its netCDF and a combined sweep file),
the refusal of a calibration of another model version or other options, and the command's bad
input."""

import json
import math

import numpy as np
import pytest

from airpuff_core import RunParams, simulate
from airpuff_core.calibration import (CALIBRATED, FORMAT, Calibration, apply_coefficients,
                                      calibrate_metrics, calibration_from_dict,
                                      fit_coefficients, load_calibrations)
from airpuff_core.dataset import open_dataset, write_netcdf
from airpuff_core.provenance import model_version

from tests.conftest import airpuff

# a known map of raw pressures to the Goldmann scale: IOP = A + B (P1 + P2)/2
A, B = -7.25, 0.8875


def synthetic_readings():
    """Raw P1, P2 of eyes whose calibrated IOPg is exactly their IOP under (A, B), with a
    hysteresis that changes with the IOP (so CH is not constant)."""
    iop = np.linspace(10.0, 30.0, 9)
    centre = (iop - A) / B
    half_ch = 3.0 - 0.05 * iop
    return iop, centre + half_ch, centre - half_ch


def test_the_fit_recovers_a_known_linear_map_exactly():
    iop, p1, p2 = synthetic_readings()
    coef = fit_coefficients(iop, p1, p2)
    assert coef["pressure_offset"] == pytest.approx(A, abs=1e-10)
    assert coef["pressure_slope"] == pytest.approx(B, abs=1e-12)
    cal = apply_coefficients(coef, p1, p2)
    np.testing.assert_allclose(cal["IOPg_cal"], iop, atol=1e-10)
    np.testing.assert_allclose(cal["CH_cal"], B * (p1 - p2), atol=1e-10)
    # P1 is linear in the IOP here, and so is P2 - 0.43 P1: both IOP forms read it exactly
    np.testing.assert_allclose(cal["IOPnc_cal"], iop, atol=1e-9)
    np.testing.assert_allclose(cal["IOPcc_ora_cal"], iop, atol=1e-9)
    # the CRF constant puts the CRF mean on the CH mean
    assert np.mean(cal["CRF_cal"]) == pytest.approx(np.mean(cal["CH_cal"]), abs=1e-10)
    p1c, p2c = A + B * p1, A + B * p2
    np.testing.assert_allclose(cal["CRF_cal"] - (p1c - 0.70 * p2c), coef["crf_constant"],
                               atol=1e-10)
    np.testing.assert_allclose(cal["IOPcc_cal"], p1c - 0.43 * p2c, atol=1e-10)


def test_the_fit_refuses_too_few_or_missing_readings():
    with pytest.raises(ValueError, match="at least two points"):
        fit_coefficients([16.0], [24.0], [20.0])
    with pytest.raises(ValueError, match="finite"):
        fit_coefficients([10.0, 20.0], [20.0, math.nan], [15.0, 25.0])


def calibration_for(params: RunParams, version: str, **changes) -> Calibration:
    """A calibration file's object for runs like ``params``, with the coefficients of the
    synthetic readings, read back through the file format."""
    iop, p1, p2 = synthetic_readings()
    options = {k: v for k, v in params.to_dict().items() if k != "IOP"}
    options.update(changes)
    data = {"format": FORMAT, "instrument": "paper", "model_version": version,
            "resolution": params.resolution, "model": params.model, "run_options": options,
            "coefficients": fit_coefficients(iop, p1, p2)}
    return calibration_from_dict(json.loads(json.dumps(data)), "test.json")


@pytest.fixture(scope="module")
def coarse_result():
    """One real coarse run (the paper's model and jet)."""
    return simulate(RunParams(resolution="coarse"))


def test_the_calibration_applies_to_a_real_coarse_run(coarse_result, tmp_path):
    res = coarse_result
    cal = calibration_for(res.params, model_version())
    path = write_netcdf(res.to_dataset(calibrations=[cal]), tmp_path / "run.nc")
    ds = open_dataset(path)
    P1, P2 = float(ds.P1), float(ds.P2)
    assert math.isfinite(P1) and math.isfinite(P2)
    a, b = cal.pressure_offset, cal.pressure_slope
    assert float(ds.P1_cal) == pytest.approx(a + b * P1, abs=1e-9)
    assert float(ds.IOPg_cal) == pytest.approx(a + b * float(ds.IOPg), abs=1e-9)
    assert float(ds.CH_cal) == pytest.approx(b * float(ds.CH), abs=1e-9)
    assert float(ds.IOPnc_cal) == pytest.approx(cal.iopnc_offset + cal.iopnc_slope * P1,
                                                abs=1e-9)
    for name, (unit, _) in CALIBRATED.items():
        assert ds[name].attrs["units"] == unit
        assert "test.json" in ds[name].attrs["calibration"]
        assert "comment" not in ds[name].attrs
    assert ds.IOPg.attrs["calibration"] == "raw"


def test_a_combined_sweep_file_carries_the_calibration_made_after_its_points(
        coarse_result, tmp_path, monkeypatch):
    from sweep.combine import combine
    from sweep.grid import SweepSpec
    from sweep.storage import point_key, point_path

    res = coarse_result
    spec = SweepSpec(options={"resolution": "coarse"}).validate()
    (params,) = spec.points()
    assert params == res.params
    points = tmp_path / "points"
    points.mkdir()
    # the point is stored before any calibration exists: its own file has none
    monkeypatch.setenv("AIRPUFF_CALIBRATION_DIR", str(tmp_path / "calibrations"))
    write_netcdf(res.to_dataset(), point_path(points, point_key(params)))
    assert math.isnan(combine(spec, points).IOPg_cal.item())
    (tmp_path / "calibrations").mkdir()
    cal = calibration_for(params, model_version())
    data = {"format": FORMAT, "instrument": "paper", "model_version": cal.model_version,
            "resolution": "coarse", "model": "paper", "run_options": cal.run_options,
            "coefficients": cal.coefficients()}
    (tmp_path / "calibrations" / "paper.json").write_text(json.dumps(data))
    assert len(load_calibrations()) == 1
    ds = combine(spec, points)
    assert ds.IOPg_cal.item() == pytest.approx(
        cal.pressure_offset + cal.pressure_slope * ds.IOPg.item(), abs=1e-9)
    assert ds.IOPg.attrs["calibration"] == "raw"
    assert "comment" not in ds.IOPg_cal.attrs
    assert "paper.json" in ds.IOPg_cal.attrs["calibration"]


def test_a_calibration_of_another_model_version_is_not_applied(coarse_result):
    res = coarse_result
    stale = calibration_for(res.params, "0123456789ab")
    values, used, reason = calibrate_metrics(res.params.to_dict(), res.metrics, model_version(),
                                             [stale])
    assert used is None
    assert all(math.isnan(v) for v in values.values())
    assert "0123456789ab" in reason and model_version() in reason
    assert "airpuff calibrate --instrument paper --resolution coarse --model paper" in reason
    ds = res.to_dataset(calibrations=[stale])
    assert math.isnan(float(ds.IOPg_cal))
    assert ds.IOPg_cal.attrs["calibration"] == "none"
    assert "not applied" in ds.IOPg_cal.attrs["comment"]
    assert math.isfinite(float(ds.IOPg))  # the raw reading stays


def test_a_calibration_fitted_with_another_pulse_is_not_applied(coarse_result):
    res = coarse_result
    other = calibration_for(res.params, model_version(), pmax=7.0)
    values, used, reason = calibrate_metrics(res.params.to_dict(), res.metrics, model_version(),
                                             [other])
    assert used is None and math.isnan(values["IOPg_cal"])
    assert "pmax 7.0 (this run 10.0)" in reason
    # another model (preset) or resolution: the command named carries it
    values, used, reason = calibrate_metrics({**res.params.to_dict(), "resolution": "paper"},
                                             res.metrics, model_version(), [other])
    assert used is None and "--resolution paper" in reason


@pytest.mark.parametrize("args, needle", [
    (("--IOP", "16"), "IOP"),
    (("--IOP", "10:30:x"), "IOP"),
    (("--instrument", "tonopen"), "instrument"),
    (("--thickness", "0"), "thickness"),
    (("--workers", "0"), "workers"),
    (("--resolution", "ultra"), "resolution"),
])
def test_calibrate_bad_input_is_one_line_and_exit_2(args, needle, tmp_path):
    proc = airpuff("calibrate", "--out", str(tmp_path), "--calibration-dir", str(tmp_path), *args,
                   timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], proc.stderr
    assert not list(tmp_path.glob("*.json"))


def test_airpuff_run_prints_the_calibrated_readings_beside_the_raw_ones(coarse_run):
    from airpuff_core.dataset import params_from_dataset

    m, path = coarse_run
    ds = open_dataset(path)
    assert set(CALIBRATED) <= set(m)
    raw = {k: (math.nan if m[k] is None else m[k]) for k in ("P1", "P2")}
    values, cal, reason = calibrate_metrics(params_from_dataset(ds).to_dict(), raw,
                                            ds.attrs["model_version"])
    if cal is None:
        assert m["calibration"] == f"none: {reason}" and "airpuff calibrate" in reason
        assert m["IOPg_cal"] is None and math.isnan(float(ds.IOPg_cal))
        assert ds.IOPg_cal.attrs["comment"] == reason
    else:
        assert m["calibration"] == cal.label
        assert m["IOPg_cal"] == pytest.approx(values["IOPg_cal"], abs=1e-9)
        assert float(ds.IOPg_cal) == pytest.approx(values["IOPg_cal"], abs=1e-9)


def test_the_calibration_file_records_the_one_line_that_makes_it_again():
    from sweep.calibration import command_line, reference_spec

    spec = reference_spec("paper", [10.0, 20.0], {"model": "clinical", "resolution": "coarse"})
    assert command_line(spec, True) == ("airpuff calibrate --instrument paper --resolution coarse "
                                        "--model clinical --IOP 10,20 --check")
    spec = reference_spec("paper", [10.0, 20.0], {"model": "clinical", "resolution": "coarse",
                                                  "c0": 20}, {"thickness": 0.54}, pmax=7.0)
    assert command_line(spec, False) == ("airpuff calibrate --instrument paper --resolution "
                                         "coarse --model clinical --pmax 7 --c0 20 --IOP 10,20 "
                                         "--thickness 0.54")
