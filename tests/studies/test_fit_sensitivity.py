"""studies/fit_sensitivity.py: the moves from the baseline on known values, the variations'
spreads, and a real run of two tiny development fits at coarse resolution (the baseline and
tau doubled) whose table comes from the fits' own records and the stored runs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from airpuff_core.params import ORA_RISE_RATE
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
    # the rise rate scales as 1/t_A1 at a fixed applanation pressure
    assert rise["rise-"] * 8.40 == pytest.approx(ORA_RISE_RATE * 8.29)
    assert rise["rise+"] * 8.18 == pytest.approx(ORA_RISE_RATE * 8.29)
    assert all(vs[n].instrument == "ora" for n in vs if n[:4] in ("rise", "dela", "fall"))
    assert all(v.source for v in vs.values())


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
