"""studies/predict_clinical.py: its slopes, values and verdicts on synthetic data with known
answers, its refusal of bad input, and a real run at coarse resolution on a small grid whose
every number is recomputed from the stored runs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from airpuff_core.calibration import calibrate_metrics
from studies import predict_clinical as pc
from sweep.engine import stored_record


def _row(against, criterion="sd", **clinic):
    return pc.Row("r", "ora", "CH_cal", against, "u", pc.Clinic("t", criterion, "s", **clinic))


# -- the computations ---------------------------------------------------------------------------
def test_least_squares_slope_of_a_line_with_noise_and_a_missing_point():
    rng = np.random.default_rng(3)
    x = np.linspace(10.0, 30.0, 9)
    noise = rng.normal(0.0, 0.1, x.size)
    noise -= np.polyval(np.polyfit(x, noise, 1), x)  # noise orthogonal to the line: exact
    y = 4.0 - 0.0425 * x + noise
    y[3] = math.nan
    assert pc.least_squares_slope(x, y) == pytest.approx(
        np.polyfit(np.delete(x, 3), np.delete(y, 3), 1)[0], rel=1e-12)
    assert pc.least_squares_slope(x[~np.isnan(y)], (4.0 - 0.0425 * x)[~np.isnan(y)]) == \
        pytest.approx(-0.0425, rel=1e-12)
    assert math.isnan(pc.least_squares_slope([1.0, 1.0], [2.0, 3.0]))  # one distinct x
    assert math.isnan(pc.least_squares_slope([1.0, 2.0], [2.0, math.nan]))


@pytest.mark.parametrize("against, xs, line, expected", [
    ("CCT", (0.45, 0.54, 0.65), lambda h: 3.0 + 15.0 * h, 1.5),     # 15 per mm: 1.5 per 100 um
    ("E0", (0.3, 0.5, 0.7), lambda e: 20.0 + 4.0 * e, 0.4),         # 4 per MPa: 0.4 per 0.1 MPa
    ("IOP", (12.0, 16.0, 20.0, 24.0), lambda p: 1.2 - 0.05 * p, -0.05),
])
def test_row_value_is_the_slope_in_the_rows_unit(against, xs, line, expected):
    points = [(x, line(x)) for x in xs]
    assert pc.row_value(_row(against), points) == pytest.approx(expected, rel=1e-12)


def test_row_value_at_the_normal_eye_takes_its_point():
    assert pc.row_value(_row(None), [(16.0, 7.66)], 16.0) == 7.66
    assert pc.row_value(_row(None), [(12.0, 1.0), (16.0, 2.0)], 16.0) == 2.0
    assert math.isnan(pc.row_value(_row(None), [(12.0, 1.0)], 16.0))


@pytest.mark.parametrize("value, clinic, verdict", [
    (7.66, dict(criterion="sd", value=7.36, spread=0.39), "yes"),
    (7.76, dict(criterion="sd", value=7.36, spread=0.39), "no"),
    (1.0, dict(criterion="range", low=0.4, high=2.2), "yes"),
    (-0.19, dict(criterion="range", low=0.4, high=2.2), "no"),
    (-0.04, dict(criterion="sign", value=-1.0), "yes"),
    (0.04, dict(criterion="sign", value=-1.0), "no"),
    (0.0, dict(criterion="sign", value=1.0), "no"),
    (math.nan, dict(criterion="sd", value=1.0, spread=0.1), "no model value"),
    (1.37, dict(criterion="none"), "no clinical number"),
])
def test_agreement_by_each_criterion(value, clinic, verdict):
    c = pc.Clinic("t", source="s", **clinic)
    assert pc.agreement(value, c) == verdict


def test_off_by_counts_standard_deviations():
    c = pc.Clinic("t", "sd", "s", value=20.13, spread=0.48)
    assert pc.off_by(24.93, c) == "+10.0 SD"
    assert pc.off_by(1.0, pc.Clinic("t", "sign", "s", value=1.0)) == ""


def test_every_row_has_a_source_and_a_criterion_it_can_judge():
    for row in pc.ROWS:
        assert row.clinic.source and row.clinic.text
        assert row.against in (None, *pc.AGAINST)
        assert pc.agreement(1.0, row.clinic) in ("yes", "no", "no clinical number")
        # the ORA rows read calibrated readings; the fit's two readings are not rows
        assert row.calibrated == (row.instrument == "ora")
        assert (row.reading, row.against) not in (("IOPg_cal", "CCT"), ("CH_cal", None))


# -- the command ----------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, word", [
    (["--set", "thickness=0.5"], "--set thickness"),
    (["--cct", "0.5"], "--cct"),
    (["--rows", "A1T,nonsense"], "--rows"),
    (["--set", "ve_g=2"], "ve_g"),
    (["--calibration-iop", "10,20"], "--calibration-iop"),
])
def test_bad_input_is_one_line_and_runs_nothing(tmp_path, capsys, argv, word):
    with pytest.raises(SystemExit) as exc:
        pc.main(["--out", str(tmp_path / "p"), *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and word in err, err
    assert not (tmp_path / "p" / "points").exists()


@pytest.mark.slow
def test_a_coarse_run_on_a_small_grid_every_number_from_the_stored_runs(tmp_path, monkeypatch):
    out = tmp_path / "pred"
    argv = ["--out", str(out), "--cct", "0.5,0.54", "--iop", "16,20", "--e0", "0.5,0.7",
            "--corvis-iop", "16,20"]
    assert pc.main(argv) == 0
    summary = json.loads((out / "predictions.json").read_text())
    assert [r["row"] for r in summary["rows"]] == [r.name for r in pc.ROWS]
    table = (out / "predictions.md").read_text()
    assert table.count("\n| ") == len(pc.ROWS) + 1  # the header and one line per row
    assert summary["runs"] == summary["runs_computed"] == 6  # the normal eye shared by the rows
    for r, row in zip(summary["rows"], pc.ROWS):
        assert r["row"] in table
        records = [stored_record(out / "points", key) for key in r["keys"]]
        assert all(rec is not None and rec.ok for rec in records)
        assert [x for x, _ in r["points"]] == [rec.params[pc.AGAINST[row.against or "IOP"][0]]
                                               for rec in records]
        if row.calibrated:
            values = []
            for rec in records:
                cal, _, reason = calibrate_metrics(rec.params, rec.metrics, rec.model_version)
                values.append(cal[row.reading])
            if not all(math.isfinite(v) for v in values):  # no calibration of this version
                assert r["model"] is None and "no calibration" in r["note"], r
                assert r["agrees"] == "no model value"
                continue
        else:
            values = [rec.metrics[row.reading] for rec in records]
        expected = (values[0] if row.against is None else
                    np.polyfit([x for x, _ in r["points"]], values, 1)[0]
                    * pc.AGAINST[row.against][2])
        assert r["model"] == pytest.approx(expected, rel=1e-9), r["row"]
        assert r["agrees"] == pc.agreement(r["model"], row.clinic)

    # without a calibration file the calibrated rows are NaN with the reason and the command
    # that makes one; the raw rows are unchanged (the runs are read back, not computed again)
    empty = tmp_path / "no_calibrations"
    empty.mkdir()
    monkeypatch.setenv("AIRPUFF_CALIBRATION_DIR", str(empty))
    assert pc.main(argv) == 0
    again = json.loads((out / "predictions.json").read_text())
    assert again["runs_computed"] == 0
    for before, after, row in zip(summary["rows"], again["rows"], pc.ROWS):
        if row.calibrated:
            assert after["model"] is None and after["agrees"] == "no model value"
            assert "no calibration" in after["note"] and "airpuff calibrate" in after["note"]
        else:
            assert after["model"] == before["model"]
    assert again["calibration"]["ora"].startswith("none: no calibration")
