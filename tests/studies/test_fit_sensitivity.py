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
