"""studies/fit_sensitivity.py: the moves from the baseline on known values, the variations'
spreads, and a real run of two tiny development fits at coarse resolution (the baseline and
tau doubled) whose table comes from the fits' own records and the stored runs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from airpuff_core.kernels.air_jet import RAMP, rise
from airpuff_core.params import ORA_ONSET, ORA_RISE_RATE
from studies import fit_sensitivity as fs
from sweep.engine import stored_record


def test_moves_are_differences_from_the_baseline():
    results = {
        fs.BASELINE: {"G_t": 11.24, "g": 0.606},
        "E0+": {"G_t": 10.74, "g": 0.650},
        "failed": {"G_t": math.nan, "g": 0.5},
    }
    rows = {r["variation"]: r for r in fs.moves(results)}
    assert rows[fs.BASELINE]["dG_t"] == 0.0 and rows[fs.BASELINE]["dg"] == 0.0
    assert rows["E0+"]["dG_t"] == pytest.approx(-0.5)
    assert rows["E0+"]["dg"] == pytest.approx(0.044)
    assert math.isnan(rows["failed"]["dG_t"]) and rows["failed"]["dg"] == pytest.approx(-0.106)


def test_variations_move_each_choice_by_its_stated_spread():
    vs = {v.name: v for v in fs.variations("paper", (0.45, 0.54, 0.65))}
    assert vs["IOP-"].argv == ("--set", f"IOP={16.0 - 2.9!r}")
    assert vs["CCT+"].argv[1] == "0.481,0.571,0.681" and vs["CCT+"].argv[3] == "0.571"
    assert {n for n in vs if n.startswith("resolution-")} == {"resolution-coarse",
                                                              "resolution-fine"}
    rise = {n: float(vs[n].argv[1].split("=")[1]) for n in ("rise-", "rise+")}
    assert rise["rise-"] == pytest.approx(fs.rise_rate_for(8.40, ORA_RISE_RATE, ORA_ONSET))
    assert rise["rise+"] == pytest.approx(fs.rise_rate_for(8.18, ORA_RISE_RATE, ORA_ONSET))
    assert all(vs[n].instrument == "ora" for n in vs if n[:4] in ("rise", "dela", "fall"))
    assert all(v.source for v in vs.values())


def _pulse_time_to_reach(pressure_Pa, rise_rate_kPa_per_ms, onset_ms):
    """When the ORA pulse's own time profile (the kernel's ``rise``) reaches a pressure [ms],
    by bisection."""
    jet = np.array([RAMP, 21.5, math.inf, 0.0, 0.0, rise_rate_kPa_per_ms * 1e6,
                    onset_ms * 1e-3])
    low, high = 0.0, 0.1
    for _ in range(200):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if rise(mid, jet) < pressure_Pa else (low, mid)
    return 0.5 * (low + high) * 1e3


@pytest.mark.parametrize("time_in", [8.18, 8.40, 6.0, 12.0])
@pytest.mark.parametrize("onset", [0.0, 3.5, 5.0])
def test_rise_rate_moves_the_pulse_s_crossing_of_an_applanation_pressure(time_in, onset):
    """The pulse with the scaled rate reaches the pressure the calibrated pulse had at 8.29 ms
    at time_in instead: what the same eye's applanation pressure implies."""
    jet = np.array([RAMP, 21.5, math.inf, 0.0, 0.0, ORA_RISE_RATE * 1e6, onset * 1e-3])
    applanation_pressure = rise(8.29e-3, jet)
    scaled = fs.rise_rate_for(time_in, ORA_RISE_RATE, onset)
    assert _pulse_time_to_reach(applanation_pressure, scaled, onset) == pytest.approx(
        time_in, abs=1e-9)
    if onset > 0:  # a rate scaled as 1/t_A1 would miss it
        naive = ORA_RISE_RATE * 8.29 / time_in
        assert abs(_pulse_time_to_reach(applanation_pressure, naive, onset) - time_in) > 1e-3


def test_rise_rate_refuses_an_applanation_inside_the_onset():
    with pytest.raises(ValueError, match="onset"):
        fs.rise_rate_for(3.0, ORA_RISE_RATE, 3.5)


def test_unknown_variation_is_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        fs.main(["--out", str(tmp_path / "s"), "--only", "nonsense"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--only" in err


@pytest.mark.slow
def test_two_tiny_fits_and_their_table_come_from_the_runs(tmp_path):
    """Tolerances so wide that each fit ends at its start: 2 runs per fit (CCT 0.45, 0.54)."""
    out = tmp_path / "sens"
    code = fs.main(["--out", str(out), "--resolution", "coarse", "--instrument", "paper",
                    "--raw", "--development", "--cct", "0.45,0.54", "--only", "tau+",
                    "--slope-tolerance", "100", "--ch-tolerance", "100"])
    assert code == 0
    summary = json.loads((out / "sensitivity.json").read_text())
    rows = {r["variation"]: r for r in summary["rows"]}
    assert list(rows) == [fs.BASELINE, "tau+"]
    assert "DEVELOPMENT" in summary["title"]
    table = (out / "sensitivity.md").read_text()
    assert table.count("\n| ") == 3 and "| tau+ | tissue |" in table
    for name, row in rows.items():
        fit = json.loads((out / name / "fit.json").read_text())
        assert row["G_t"] == fit["fitted"]["transverse_shear_modulus"]["value"]
        assert row["g"] == fit["fitted"]["ve_g"]["value"]
        # the slope reached: the least-squares slope of the stored runs' IOPg over CCT
        runs = [r for r in fit["runs"] if r["ve_g"] == row["g"]]
        records = {r["key"]: stored_record(out / "points", r["key"]) for r in runs}
        by_cct = {rec.params["thickness"]: rec for rec in records.values()}
        assert set(by_cct) == {0.45, 0.54}
        assert all(rec.params["ve_tau"] == (20.0 if name == "tau+" else 10.0)
                   for rec in by_cct.values())
        slope = np.polyfit([0.45, 0.54], [by_cct[c].metrics["IOPg"] for c in (0.45, 0.54)],
                           1)[0] * 0.1
        assert row["slope"] == pytest.approx(slope, rel=1e-9)
        assert row["CH"] == pytest.approx(by_cct[0.54].metrics["CH"], rel=1e-9)
    assert rows["tau+"]["slope"] != rows[fs.BASELINE]["slope"]  # tau reached the solver


# -- the first-order mode, on responses whose exact answers are known ---------------------------
def _quadratic(shift=(0.0, 0.0)):
    """F(G_t, g) = (slope, CH), a quadratic with cross terms, moved by ``shift``; its exact
    Jacobian at (x, y)."""
    def F(x, y):
        return np.array([2.8 + 0.45 * (x - 10) + 2.4 * (y - 0.58) + 0.03 * (x - 10) ** 2
                         + 0.5 * (x - 10) * (y - 0.58) + shift[0],
                         10.6 + 0.19 * (x - 10) + 7.8 * (y - 0.58) - 6.0 * (y - 0.58) ** 2
                         + shift[1]])

    def J(x, y):
        return np.array([[0.45 + 0.06 * (x - 10) + 0.5 * (y - 0.58), 2.4 + 0.5 * (x - 10)],
                         [0.19, 7.8 - 12.0 * (y - 0.58)]])
    return F, J


def test_central_differences_of_a_quadratic_are_its_exact_derivatives():
    F, J = _quadratic()
    at = (10.7, 0.61)
    jac = fs.measure_jacobian(lambda x, y: F(x, y), at, (0.5, 0.02))
    assert jac.central == pytest.approx(J(*at), rel=1e-9, abs=1e-9)
    np.testing.assert_allclose(jac.centre, F(*at))
    # the second differences are the quadratic's own: 2 x 0.03 in G_t, 2 x -6 in g
    assert jac.curvature[0, 0] == pytest.approx(0.06, rel=1e-6)
    assert jac.curvature[1, 1] == pytest.approx(-12.0, rel=1e-6)
    # the one-sided differences miss by h/2 F''
    assert jac.forward[1, 1] - jac.central[1, 1] == pytest.approx(-6.0 * 0.02, rel=1e-6)


def test_first_order_move_of_a_linear_response_is_the_exact_refit():
    """F linear: the variation F + delta is fitted exactly at theta* - J^-1 delta (solved here by
    hand for the 2x2), and a target moved by dT at theta* + J^-1 dT."""
    A = np.array([[0.45, 2.4], [0.19, 7.8]])
    at = (10.0, 0.58)
    delta = np.array([0.3, -0.4])
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    exact = (-(A[1, 1] * delta[0] - A[0, 1] * delta[1]) / det,
             -(-A[1, 0] * delta[0] + A[0, 0] * delta[1]) / det)
    move = fs.first_order_move(A, at, delta)
    assert (move["dG_t"], move["dg"]) == pytest.approx(exact, rel=1e-12)
    assert move["in_range"]
    assert (move["G_t"], move["g"]) == pytest.approx((at[0] + exact[0], at[1] + exact[1]),
                                                     abs=1e-8)
    assert move["G_t_status"] == move["g_status"] == "converged"
    # a moved target needs no run: d theta = J^-1 dT
    dT = np.array([-0.5, 0.0])
    move = fs.first_order_move(A, at, (0.0, 0.0), dT)
    assert (move["dG_t"], move["dg"]) == pytest.approx(
        ((A[1, 1] * dT[0]) / det, (-A[1, 0] * dT[0]) / det), rel=1e-12)


def test_a_move_out_of_the_range_stops_at_the_edge_and_fits_the_other_value_there():
    """A slope target out of reach inside the range (G_t 10 + 7.8 x 2.2 / 3.054 = 15.62 kPa):
    G_t stops at the upper edge, and g meets CH with G_t there: 0.19 (G_t_high - 10) +
    7.8 (g - 0.58) = 0."""
    A = np.array([[0.45, 2.4], [0.19, 7.8]])
    at = (10.0, 0.58)
    move = fs.first_order_move(A, at, (0.0, 0.0), (5.0 - 2.8, 0.0))
    assert not move["in_range"] and move["G_t_unclipped"] > fs.SHEAR.high
    assert move["G_t"] == fs.SHEAR.high and move["G_t_status"] == "upper edge"
    assert move["g"] == pytest.approx(0.58 - 0.19 * (fs.SHEAR.high - 10.0) / 7.8, abs=1e-8)


def test_first_order_moves_of_a_quadratic_come_within_second_order_of_the_exact_fit():
    """A variation shifting a quadratic F: the first-order move (Jacobian by central differences)
    and the exact root of F + delta = target differ by O(delta^2), and the Newton step of the
    check recovers most of it."""
    F, J = _quadratic()
    at = (10.0, 0.58)  # F(at) = the targets
    jac = fs.measure_jacobian(lambda x, y: F(x, y), at, (0.5, 0.02))
    errors = []
    for scale in (1.0, 0.5):
        delta = scale * np.array([0.2, 0.3])
        G, _ = _quadratic(delta)
        move = fs.first_order_move(jac.central, at, G(*at) - F(*at))
        exact = _newton_root(G, J, at, np.array([2.8, 10.6]))
        errors.append(np.hypot((move["G_t"] - exact[0]) / 13, (move["g"] - exact[1]) / 0.44))
        check = fs.second_order_check(lambda x, y: G(x, y), jac.central, move, F(*at))
        second = (move["G_t"] + check["newton_dG_t"], move["g"] + check["newton_dg"])
        assert np.hypot((second[0] - exact[0]) / 13, (second[1] - exact[1]) / 0.44) < \
            0.2 * errors[-1]
    assert errors[0] > 0 and errors[1] == pytest.approx(errors[0] / 4, rel=0.2)


def _newton_root(F, J, x0, target):
    """The root of F = target by Newton's method with the exact Jacobian J."""
    x = np.array(x0, dtype=float)
    for _ in range(50):
        x -= np.linalg.solve(J(*x), F(*x) - target)
    assert np.allclose(F(*x), target, rtol=0, atol=1e-12)
    return x


def test_linear_mode_refuses_a_fit_of_another_model_version_in_one_line(tmp_path, capsys):
    fit_json = tmp_path / "fit.json"
    fit_json.write_text(json.dumps({
        "command": "python -m studies.fit_clinical --out x --resolution coarse --development",
        "model_version": "000000000000", "fitted": {"transverse_shear_modulus": {"value": 10.0},
                                                   "ve_g": {"value": 0.5}}, "error": ""}))
    for argv, word in ((["--linear", str(fit_json)], "model version"),
                       (["--linear", str(tmp_path / "none.json")], "--linear"),
                       (["--linear", str(fit_json), "--resolution", "paper"], "--resolution"),
                       (["--check", "E0+"], "--check")):
        with pytest.raises(SystemExit) as exc:
            fs.main(["--out", str(tmp_path / "s"), *argv])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and word in err, err
    assert not (tmp_path / "s").exists()
