"""studies/fit_clinical.py: its 1-D solver on functions with known roots, its refusal of a
clinical fit without the instrument and calibration, the runs through the sweep engine on a real
Dask cluster, and a real round trip: targets computed by the solver at known tissue values,
fitted back from the published ones (coarse resolution)."""

from __future__ import annotations

import json
import math
from dataclasses import asdict

import pytest
import xarray as xr

from studies import fit_clinical as fc
from sweep.engine import stored_record
from sweep.storage import point_key


# -- the 1-D solver ---------------------------------------------------------------------------
@pytest.mark.parametrize("f, low, high, x0, root", [
    (lambda x: 2.0 * x - 3.0, 0.0, 5.0, 0.5, 1.5),                # linear, from below
    (lambda x: math.exp(x) - 5.0, 0.0, 3.0, 2.9, math.log(5.0)),  # convex, from above
    (lambda x: 1.0 - x ** 3, 0.0, 2.0, 0.1, 1.0),                 # decreasing
    (lambda x: math.atan(10 * (x - 0.7)), 0.0, 1.0, 0.0, 0.7),    # flat far from the root
])
def test_solve_monotone_finds_known_roots_inside_the_range(f, low, high, x0, root):
    seen = []

    def residual(x):
        seen.append(x)
        return f(x)

    s = fc.solve_monotone(residual, low, high, x0, step=0.25 * (high - low), tolerance=1e-6,
                          max_evaluations=40)
    assert s.status == "converged"
    assert abs(s.residual) <= 1e-6
    assert s.x == pytest.approx(root, abs=1e-4)
    assert all(low <= x <= high for x in seen)
    assert [x for x, _ in s.history] == seen


@pytest.mark.parametrize("f, edge, x_edge", [
    (lambda x: x + 10.0, "lower edge", 0.0),    # root at -10: below the range
    (lambda x: x - 10.0, "upper edge", 5.0),    # root at +10: above it
    (lambda x: 10.0 - x, "upper edge", 5.0),    # decreasing, root above
])
def test_solve_monotone_stops_at_the_edge_when_the_target_is_out_of_range(f, edge, x_edge):
    s = fc.solve_monotone(f, 0.0, 5.0, 2.0, step=1.0, tolerance=1e-6, max_evaluations=20)
    assert s.status == edge
    assert s.x == x_edge
    assert s.residual == pytest.approx(f(x_edge))
    assert len(s.history) <= 4  # the start, a secant step, the edge


def test_solve_monotone_newton_start_and_known_first_residual():
    calls = []

    def f(x):
        calls.append(x)
        return 3.0 * (x - 2.0)

    s = fc.solve_monotone(f, 0.0, 4.0, 1.0, step=1.0, tolerance=1e-9, derivative=3.0, f0=-3.0)
    assert s.status == "converged" and s.x == pytest.approx(2.0)
    assert calls == [pytest.approx(2.0)]  # x0's residual was known; one Newton step


def test_a_step_across_the_target_is_bracketed_and_reported_as_a_jump():
    """A response that is smooth but for a step of 4 across the target at x = 2.3 (the ORA's
    second applanation read on another peak): no value meets the target, the solve says where
    it jumps; a smooth response's bracket is not called a jump."""
    def step(x):
        return 0.1 * (x - 2.3) + (2.0 if x >= 2.3 else -2.0)

    s = fc.solve_monotone(step, 0.0, 5.0, 1.0, step=1.0, tolerance=0.01, max_evaluations=12)
    assert s.status in ("evaluations", "bracket") and abs(s.residual) >= 2.0
    (xa, fa), (xb, fb) = s.bracket()
    assert xa < 2.3 <= xb and fa < 0 < fb and xb - xa < 0.5
    assert s.jump_ratio() > fc.JUMP_RATIO
    line = "\n".join(fc.solve_lines([{"parameter": fc.RATIO.name, "outer": 1, **asdict(s),
                                       "bracket": s.bracket(), "jump_ratio": s.jump_ratio()}]))
    assert "JUMPS" in line

    smooth = fc.solve_monotone(lambda x: x * x - 5.0, 0.0, 5.0, 1.0, step=1.0, tolerance=1e-12,
                               max_evaluations=4)
    assert smooth.status == "evaluations" and smooth.bracket() is not None
    assert smooth.jump_ratio() < fc.JUMP_RATIO


def test_calibration_lines_name_the_misses_and_the_calibration_at_the_fit():
    def made(shear, ratio, slope, error):
        return {"response": "calibration_slope", fc.SHEAR.name: shear, fc.RATIO.name: ratio,
                "value": slope, "max_error_mmHg": error,
                "coefficients": {"pressure_offset": -5.0, "pressure_slope": slope}}

    evaluations = [made(9.48, 0.3, 0.77, 0.2), made(12.0, 0.5, 0.9, 1.3),
                   {"response": "CH", fc.SHEAR.name: 12.0, fc.RATIO.name: 0.5, "value": 10.6}]
    at_good = {"fitted": {fc.SHEAR.name: {"value": 9.48}, fc.RATIO.name: {"value": 0.3}}}
    at_bad = {"fitted": {fc.SHEAR.name: {"value": 12.0}, fc.RATIO.name: {"value": 0.5}}}
    good = fc.calibration_lines(evaluations, at_good)[0]
    assert "Calibrations made: 2" in good and "1 missed 0.3 mmHg" in good
    assert "0.77000 P" in good and "MISSES" not in good
    assert "MISSES 0.3 mmHg" in fc.calibration_lines(evaluations, at_bad)[0]


def test_sensitivities_of_a_plane_are_its_coefficients():
    def slope(x, y):
        return 1.0 + 0.25 * x + 3.0 * y

    def ch(x, y):
        return -2.0 + 0.3 * x + 40.0 * y

    pts = [(10.0, 0.3), (12.0, 0.3), (12.0, 0.4), (11.0, 0.35)]
    sens = fc.sensitivities([(x, y, slope(x, y)) for x, y in pts],
                            [(x, y, ch(x, y)) for x, y in pts], (11.5, 0.36))
    assert sens["dslope_dG_t"] == pytest.approx(0.25)
    assert sens["dslope_dg"] == pytest.approx(3.0)
    assert sens["dCH_dG_t"] == pytest.approx(0.3)
    assert sens["dCH_dg"] == pytest.approx(40.0)
    assert sens["gauss_seidel_factor"] == pytest.approx(3.0 * 0.3 / (0.25 * 40.0))


# -- the command ----------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, word", [
    (["--instrument", "paper", "--raw"], "--development"),        # development not asked for
    (["--instrument", "ora", "--resolution", "coarse"], "--resolution coarse"),
    (["--instrument", "paper", "--raw", "--development", "--set", "ve_g=0.5"], "--set ve_g"),
    (["--instrument", "paper", "--raw", "--development", "--cct", "0.5"], "--cct"),
    (["--instrument", "paper", "--raw", "--development", "--set", "IOP=99"], "IOP"),
])
def test_a_clinical_fit_is_refused_without_its_parts_and_bad_input_is_one_line(
        tmp_path, capsys, argv, word):
    with pytest.raises(SystemExit) as exc:
        fc.main(["--out", str(tmp_path / "fit"), *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and word in err, err
    assert not (tmp_path / "fit" / "points").exists()


# -- the runs ---------------------------------------------------------------------------------------
@pytest.mark.cluster
def test_point_runner_on_dask_equals_in_process_and_reuses_stored_points(tmp_path, dask_client):
    base = {"model": "clinical", "resolution": "coarse", **fc.REFERENCE}
    points = [fc.RunParams.from_dict({**base, "thickness": c, "t_end": 12.0}) for c in (0.5, 0.6)]
    logged = []
    on_dask = fc.PointRunner(tmp_path / "dask", dask_client, lambda r, p: logged.append(r))
    here = fc.PointRunner(tmp_path / "here")
    a, b = on_dask.run(points), here.run(points)
    assert [r.key for r in a] == [point_key(p) for p in points] == [r.key for r in b]
    assert all(r.ok and r.computed for r in a + b)
    for ra, rb in zip(a, b):
        assert ra.metrics["P1"] == rb.metrics["P1"] and math.isfinite(ra.metrics["P1"])
    assert stored_record(tmp_path / "dask", a[0].key) is not None
    again = on_dask.run(points)
    assert [r.computed for r in again] == [False, False]
    assert len(logged) == 4


@pytest.mark.slow
def test_fit_recovers_known_tissue_values_from_targets_the_solver_computed(tmp_path):
    """A real round trip at coarse resolution: the CCT slope and CH computed by the solver at
    G_t 11 kPa, g 0.36; the fit, started at the published 9.48 kPa and 0.3, must find them again
    within what its tolerances allow (0.01 mmHg per 100 um and 0.02 mmHg)."""
    truth = (11.0, 0.36)
    base = {"model": "clinical", "resolution": "coarse", **fc.REFERENCE}
    responses = fc.Responses(fc.PointRunner(tmp_path / "truth"), base, log=lambda e: None)
    slope, ch = responses.slope(*truth), responses.ch(*truth)
    out = tmp_path / "fit"
    code = fc.main(["--out", str(out), "--instrument", "paper", "--raw", "--development",
                    "--resolution", "coarse", "--slope-target", repr(slope), "--ch-target",
                    repr(ch), "--slope-tolerance", "0.01", "--ch-tolerance", "0.02"])
    assert code == 0
    summary = json.loads((out / "fit.json").read_text())
    fitted = summary["fitted"]
    assert fitted["transverse_shear_modulus"]["status"] == "converged"
    assert fitted["ve_g"]["status"] == "converged"
    assert fitted["transverse_shear_modulus"]["value"] == pytest.approx(truth[0], abs=0.15)
    assert fitted["ve_g"]["value"] == pytest.approx(truth[1], abs=0.003)
    assert summary["mode"] == "development"
    with xr.open_dataset(out / "fit.nc") as ds:
        assert ds.attrs["mode"] == "development"
        assert ds.sizes["run"] == len(summary["runs"]) and ds.sizes["run"] >= 6
        assert ds.sizes["evaluation"] == len(summary["evaluations"])
        last = summary["evaluations"][-1]
        assert float(ds["evaluation_value"][-1]) == pytest.approx(last["value"])
    assert "DEVELOPMENT" in (out / "fit.md").read_text()
    lines = (out / "evaluations.jsonl").read_text().splitlines()
    assert len(lines) == len(summary["runs"]) + len(summary["evaluations"])


@pytest.mark.slow
def test_calibrated_readings_are_refit_per_trial_and_read_the_true_iop_at_the_reference_eye(
        tmp_path):
    """The calibrated mode's calibration, made on its reference sweep (IOP 17.5, 22.5, 27.5 at
    the calibration's reference eye) with the trial's tissue values, makes IOPg_cal read the
    true IOP at that eye at IOP 20, a point it was not fitted on (within airpuff calibrate's 0.3
    mmHg), for two trials whose raw readings differ by mmHg.  (At coarse resolution the second
    applanation of this eye is misread below IOP 17.5 on the paper's jet, so the sweep starts
    there.)"""
    from airpuff_core.calibration import REFERENCE_EYE

    base = {"model": "clinical", "resolution": "coarse", **fc.REFERENCE, "IOP": 20.0}
    responses = fc.Responses(fc.PointRunner(tmp_path / "points"), base,
                             calibration_iops=(17.5, 22.5, 27.5), log=lambda e: None)
    assert responses.readings == {"slope": "IOPg_cal", "CH": "CH_cal"}
    eye = REFERENCE_EYE["thickness"]
    raw = {}
    for trial in ((9.48, 0.3), (13.0, 0.4)):
        (reading,) = responses._readings(*trial, (eye,))
        assert reading["slope"] == pytest.approx(20.0, abs=0.3)
        (record,) = responses.runner.run([responses.params(*trial, eye)])
        raw[trial] = record.metrics["IOPg"]
        assert reading["CH"] == pytest.approx(
            responses.calibration(*trial)["pressure_slope"] * record.metrics["CH"])
    assert abs(raw[(13.0, 0.4)] - raw[(9.48, 0.3)]) > 1.0  # the calibrations had to differ
    calibrations = [e for e in responses.evaluations if e["response"] == "calibration_slope"]
    assert len(calibrations) == 2  # one per trial, reused within it
    for e in calibrations:  # its error on the reference sweep: a + b (P1 + P2)/2 - IOP
        a, b = e["coefficients"]["pressure_offset"], e["coefficients"]["pressure_slope"]
        error = [a + b * (p1 + p2) / 2 - iop for iop, p1, p2 in zip(e["IOP"], e["P1_raw"],
                                                                    e["P2_raw"])]
        assert e["max_error_mmHg"] == pytest.approx(max(abs(x) for x in error))
