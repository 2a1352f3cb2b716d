"""The correction formulas (sweep/correction.py), their command `airpuff correct`, and the Sobol
indices of a sweep's surrogate (sweep/sensitivity.py): known polynomials recovered exactly,
cross-validation picking the true degree, Sobol indices of an additive function against their
closed form, and a real coarse sweep through fit and apply."""

import csv
import io
import json
import math

import numpy as np
import pytest

from sweep.correction import (Correction, CorrectionError, exponents, fit_by_cross_validation,
                              fit_correction, read_measurements, apply_rows)
from sweep.identification import SweepTable
from sweep.sensitivity import sobol_indices

from tests.conftest import airpuff


def _box(n_per_axis, lows, highs):
    axes = [np.linspace(lo, hi, n_per_axis) for lo, hi in zip(lows, highs)]
    return np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)


def test_fit_recovers_known_polynomial_coefficients():
    """y given as a polynomial in the scaled inputs z = (x - center) / half_range: the fitted
    coefficients are the given ones, and the gradient is the polynomial's derivative."""
    lows, highs = np.array([10.0, 450.0, 0.3]), np.array([30.0, 650.0, 0.9])
    x = _box(5, lows, highs)
    center, half = (lows + highs) / 2, (highs - lows) / 2
    z = (x - center) / half
    truth = {(0, 0, 0): 17.0, (1, 0, 0): 4.0, (0, 1, 0): -1.5, (0, 0, 1): 0.7,
             (2, 0, 0): 0.3, (1, 1, 0): -0.2, (0, 0, 2): 0.05}
    y = sum(c * np.prod(z ** np.array(p), axis=1) for p, c in truth.items())
    fit = fit_by_cross_validation(x, y, ["a", "b", "c"], "IOP", max_degree=3)
    assert fit.surface.degree == 2
    assert fit.rms < 1e-9
    got = dict(zip(fit.surface.powers, fit.surface.coefficients))
    assert set(got) == set(exponents(3, 2))
    for p, c in got.items():
        assert c == pytest.approx(truth.get(p, 0.0), abs=1e-9), p
    x_new = np.array([[12.3, 500.0, 0.41], [27.0, 640.0, 0.88]])
    z_new = (x_new - center) / half
    dy_dz = np.stack([4.0 + 0.6 * z_new[:, 0] - 0.2 * z_new[:, 1],
                      -1.5 - 0.2 * z_new[:, 0],
                      0.7 + 0.1 * z_new[:, 2]], axis=1)
    np.testing.assert_allclose(fit.surface.gradient(x_new), dy_dz / half, rtol=1e-9)


@pytest.mark.parametrize("true_degree", [1, 2, 3])
def test_cross_validation_picks_the_true_degree(true_degree):
    rng = np.random.default_rng(7)
    x = _box(6, [0.0, -2.0], [3.0, 5.0])
    u, v = x[:, 0], x[:, 1]
    y = {1: 1 + 2 * u - v,
         2: 1 + 2 * u - v + 0.8 * u * v - 0.5 * v ** 2,
         3: 1 + 2 * u - v + 0.8 * u * v - 0.5 * v ** 2 + 0.3 * u ** 3 - 0.2 * u * v ** 2}[true_degree]
    y = y + rng.normal(0.0, 0.01, y.size)
    fit = fit_by_cross_validation(x, y, ["u", "v"], "IOP", max_degree=4)
    assert fit.surface.degree == true_degree, fit.scores
    assert 0.005 < fit.rms < 0.02  # the noise's level, held out


# A sweep whose readings are linear in the parameters, so that IOP and E0 are linear in the
# readings:  P1 = IOP + 20 (t - 0.5) + 3 E0,  P2 = IOP - 2 E0  (t in mm)  give
# IOP = 0.4 P1 + 0.6 P2 - 0.008 CCT + 4  and  E0 = (P1 - P2 - 0.02 CCT + 10) / 5  (CCT in um).
def _linear_table(fail=(), no_applanation=()):
    E0 = np.array([0.3, 0.5, 0.7, 0.9])
    IOP = np.array([10.0, 15.0, 20.0, 25.0, 30.0])
    th = np.array([0.45, 0.5, 0.55, 0.6, 0.65])
    e, p, t, _ = np.meshgrid(E0, IOP, th, [10.0], indexing="ij")
    P1 = p + 20 * (t - 0.5) + 3 * e
    P2 = p - 2 * e
    DA = 1.2 - 0.02 * p + 0.1 * e
    metrics = {"P1": P1, "P2": P2, "DA": DA, "t_A1": 0 * P1, "t_A2": 0 * P1}
    ok = np.ones(P1.shape, bool)
    for idx in fail:
        ok[idx] = False
        for a in metrics.values():
            a[idx] = np.nan
    for idx in no_applanation:
        P2[idx] = np.nan
    return SweepTable(E0, IOP, th, np.array([10.0]), metrics, int((~ok).sum()), {}, "test", ok)


def test_fit_correction_linear_sweep_exact_and_counts_left_out_points():
    table = _linear_table(fail=[(0, 0, 0, 0), (1, 2, 3, 0)], no_applanation=[(3, 4, 4, 0)])
    d = json.loads(json.dumps(fit_correction(table, "ora")))
    assert d["sweep"]["points"] == 100
    assert (d["sweep"]["used"], d["sweep"]["excluded_failed"],
            d["sweep"]["excluded_no_reading"]) == (97, 2, 1)
    assert [r["name"] for r in d["readings"]] == ["P1_raw", "P2_raw", "CCT"]
    assert {r["calibration"] for r in d["readings"][:2]} == {"raw"} and d["calibration"] == "raw"
    for t in ("IOP", "E0"):
        assert d["targets"][t]["degree"] == 1
        assert d["targets"][t]["held_out"]["rms"] < 1e-9
    c = Correction.from_dict(d)
    r = c.apply_row({"P1": 21.0, "P2": 17.0, "CCT": 540}, {"P1": 0.5, "P2": 0.3})
    assert r["status"] == "ok"
    assert r["IOP"] == pytest.approx(0.4 * 21 + 0.6 * 17 - 0.008 * 540 + 4, abs=1e-9)
    assert r["E0"] == pytest.approx((21 - 17 - 0.02 * 540 + 10) / 5, abs=1e-9)
    rms = d["targets"]["IOP"]["held_out"]["rms"]
    assert r["IOP_sigma"] == pytest.approx(math.sqrt(rms ** 2 + (0.4 * 0.5) ** 2 + (0.6 * 0.3) ** 2),
                                           rel=1e-6)
    v = d["validation"]
    # raw IOPg - IOP = 10 (t - 0.5) + 0.5 E0: 1 mmHg per 100 um, 0.05 mmHg per 0.1 MPa
    assert v["raw_reading"]["slopes_of_error_mmHg"]["per_100um_CCT"] == pytest.approx(1.0)
    assert v["raw_reading"]["slopes_of_error_mmHg"]["per_0.1MPa_E0"] == pytest.approx(0.05)
    assert abs(v["corrected_IOP"]["slopes_of_error_mmHg"]["per_100um_CCT"]) < 1e-8
    assert v["stiffness_index"]["spearman_with_true_E0"] == pytest.approx(1.0)


def test_fit_correction_refuses_a_sweep_without_cct_variation():
    t = _linear_table()
    one = SweepTable(t.E0, t.IOP, t.thickness[:1], t.pmax,
                     {k: a[:, :, :1] for k, a in t.metrics.items()}, 0, {}, "test", t.ok[:, :, :1])
    with pytest.raises(CorrectionError, match="CCT takes one value"):
        fit_correction(one, "ora")


def test_fit_correction_takes_the_readings_of_the_sweeps_pulse():
    """A sweep under the ORA's pulse gives the ORA's readings only; the paper's jet either."""
    t = _linear_table()
    under = lambda pulse: SweepTable(t.E0, t.IOP, t.thickness, t.pmax, t.metrics, 0,  # noqa: E731
                                     {"instrument": pulse}, "test", t.ok)
    assert fit_correction(under("ora"), "ora")["instrument"] == "ora"
    with pytest.raises(CorrectionError, match="computed with the corvis pulse: accepted corvis") as err:
        fit_correction(under("corvis"), "ora")
    assert err.value.field == "instrument"


CSV_TEXT = """id,P1,P2,CCT,P1_sigma
a,21,17,540,0.5
b,60,17,540,
c,21,abc,540,
d,21,,540,
e,21,17,0.54,
f,21,17,540,-1
g,23.5,19,600,0.2
"""


@pytest.fixture
def linear_correction(tmp_path):
    path = tmp_path / "correction.json"
    path.write_text(json.dumps(fit_correction(_linear_table(), "ora")))
    return path


def test_apply_flags_out_of_range_and_reports_bad_rows_without_stopping(linear_correction,
                                                                       tmp_path):
    c = Correction.load(linear_correction)
    res = apply_rows(c, read_measurements(CSV_TEXT, c))
    assert [r["status"] for r in res] == ["ok", "outside", "error", "error", "error", "error", "ok"]
    assert [r["id"] for r in res] == list("abcdefg")
    assert "P1=60 mmHg is outside the fitted range" in res[1]["flags"][0]
    assert res[1]["IOP"] == pytest.approx(0.4 * 60 + 0.6 * 17 - 0.008 * 540 + 4)  # given, flagged
    assert "P2 value 'abc' is not a number" in res[2]["error"]
    assert "P2 is missing" in res[3]["error"]
    assert "micrometres" in res[4]["error"]
    assert "negative" in res[5]["error"]

    csv_path = tmp_path / "eyes.csv"
    csv_path.write_text(CSV_TEXT)
    proc = airpuff("correct", "apply", "--correction", str(linear_correction),
                   "--measurements", str(csv_path), "--json", timeout=120)
    assert proc.returncode == 1, proc.stderr  # some rows bad; the others corrected
    out = json.loads(proc.stdout)
    assert (out["n_rows"], out["n_error"], out["n_outside"]) == (7, 4, 1)
    assert out["rows"][6]["IOP"] == pytest.approx(20.0) and out["rows"][6]["E0"] == pytest.approx(0.5)
    assert len(proc.stderr.strip().splitlines()) == 4  # one line per bad row

    proc = airpuff("correct", "apply", "--correction", str(linear_correction),
                   "--measurements", str(csv_path), timeout=120)
    rows = list(csv.DictReader(io.StringIO(proc.stdout)))
    assert [r["status"] for r in rows][:2] == ["ok", "outside"] and rows[0]["id"] == "a"


@pytest.mark.parametrize("args, words", [
    (["fit", "--sweep", "{sweep}", "--instrument", "goldmann", "--out", "{tmp}/c.json"],
     "--instrument 'goldmann': accepted ora or corvis"),
    (["fit", "--sweep", "{tmp}/none.nc", "--instrument", "ora", "--out", "{tmp}/c.json"],
     "not found"),
    (["fit", "--sweep", "{sweep}", "--instrument", "ora", "--out", "{tmp}/c.json",
      "--folds", "1"], "--folds '1': accepted a whole number from 2 to 20"),
    (["apply", "--correction", "{tmp}/none.json", "--measurements", "{csv}"], "not found"),
    (["apply", "--correction", "{correction}", "--measurements", "{nocct}"],
     "no column for CCT [um]"),
    (["apply", "--correction", "{sweep}", "--measurements", "{csv}"],
     "cannot read correction file"),
    (["sensitivity", "--sweep", "{sweep}", "--samples", "100"], "power of 2"),
    (["sensitivity", "--sweep", "{sweep}", "--metrics", "P1,XX"], "invalid --metrics"),
])
def test_cli_bad_input_exits_2_with_one_line(args, words, tmp_path, linear_correction):
    sweep_nc = tmp_path / "not_a_sweep.nc"
    sweep_nc.write_bytes(b"\x89HDF junk")
    csv_path = tmp_path / "eyes.csv"
    csv_path.write_text(CSV_TEXT)
    nocct = tmp_path / "nocct.csv"
    nocct.write_text("P1,P2,pachy_mm\n21,17,0.54\n")
    fill = {"sweep": sweep_nc, "tmp": tmp_path, "csv": csv_path, "correction": linear_correction,
            "nocct": nocct}
    proc = airpuff("correct", *[a.format(**fill) for a in args], timeout=120)
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("airpuff correct"), proc.stderr
    assert words in lines[0]


def test_sobol_indices_of_an_additive_function_match_the_closed_form():
    """y = a IOP + b E0^2 on a grid: the surrogate is exact (degree 2), and for uniform inputs
    S_IOP = a^2 Var(IOP) / Var(y) with Var(E0^2) = (hi^5 - lo^5)/(5 w) - ((hi^3 - lo^3)/(3 w))^2;
    first-order equals total (no interaction); thickness has no effect."""
    E0, IOP, th = np.linspace(0.3, 0.9, 5), np.linspace(10, 30, 5), np.array([0.5, 0.6])
    e, p, t, _ = np.meshgrid(E0, IOP, th, [10.0], indexing="ij")
    a, b = 0.5, 20.0
    table = SweepTable(E0, IOP, th, np.array([10.0]), {"P1": a * p + b * e ** 2}, 0, {}, "t",
                       np.ones(p.shape, bool))
    res = sobol_indices(table, ["P1"], n_base=4096)
    assert res["parameters"] == ["E0", "IOP", "thickness"]
    m = res["metrics"]["P1"]
    assert m["surrogate"]["degree"] == 2 and m["surrogate"]["held_out_rms"] < 1e-9
    var_iop = a ** 2 * 20 ** 2 / 12
    lo, hi, w = 0.3, 0.9, 0.6
    var_e = b ** 2 * ((hi ** 5 - lo ** 5) / (5 * w) - ((hi ** 3 - lo ** 3) / (3 * w)) ** 2)
    for name, share in (("IOP", var_iop / (var_iop + var_e)), ("E0", var_e / (var_iop + var_e))):
        assert m["S1"][name] == pytest.approx(share, abs=0.03)
        assert m["ST"][name] == pytest.approx(share, abs=0.03)
    assert abs(m["S1"]["thickness"]) < 0.01 and abs(m["ST"]["thickness"]) < 0.01


@pytest.mark.slow
@pytest.mark.cluster
@pytest.mark.parametrize("instrument, header, row", [
    ("ora", "id,P1,P2,CCT", "eye1,{P1},{P2},{CCT}"),
    ("corvis", "id,IOPnc,CCT,DA,DA_sigma", "eye1,{P1},{CCT},{DA},0.02"),
])
def test_real_coarse_sweep_fit_and_apply_end_to_end(coarse_sweep, tmp_path, instrument, header,
                                                    row):
    import xarray as xr

    out = tmp_path / "correction.json"
    proc = airpuff("correct", "fit", "--sweep", str(coarse_sweep), "--instrument", instrument,
                   "--out", str(out), "--json", timeout=300)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    d = json.loads(out.read_text())
    assert summary["used"] == d["sweep"]["used"] == 8
    assert d["sweep"]["grid"]["thickness"] == [0.45, 0.6] and d["model_version"]
    assert d["targets"]["IOP"]["degree"] == 1  # 8 points allow no more
    # the grid's own points: a linear formula fitted on them reproduces each to its residual
    with xr.open_dataset(coarse_sweep, decode_times=False) as ds:
        pt = ds.sel(E0=0.4, IOP=22.0, thickness=0.45, pmax=ds.pmax.values[0])
        vals = {"P1": float(pt.P1), "P2": float(pt.P2), "DA": float(pt.DA), "CCT": 450}
    csv_path = tmp_path / "eyes.csv"
    csv_path.write_text(header + "\n" + row.format(**vals) + "\n")
    proc = airpuff("correct", "apply", "--correction", str(out), "--measurements", str(csv_path),
                   "--json", timeout=120)
    assert proc.returncode == 0, proc.stderr
    r = json.loads(proc.stdout)["rows"][0]
    assert r["id"] == "eye1"
    # readings of the grid's own point are inside the fitted ranges; only an estimate of a
    # linear formula on 8 points may fall outside the sweep's range (and is then flagged)
    assert r["status"] in ("ok", "outside")
    assert all(f.startswith("the estimate ") for f in r["flags"]), r["flags"]
    c = Correction.from_dict(d)
    x = np.array([[vals["P1"], vals["P2"], 450.0] if instrument == "ora"
                  else [vals["P1"], 450.0, vals["DA"]]])
    assert r["IOP"] == pytest.approx(float(c.surfaces["IOP"](x)[0]), rel=1e-12)
    assert abs(r["IOP"] - 22.0) < 3 * d["targets"]["IOP"]["held_out"]["rms"] + 0.5
    assert r["IOP_sigma"] >= d["targets"]["IOP"]["held_out"]["rms"]


@pytest.mark.slow
@pytest.mark.cluster
def test_real_coarse_sweep_sensitivity(coarse_sweep):
    proc = airpuff("correct", "sensitivity", "--sweep", str(coarse_sweep), "--metrics",
                   "P1,P2,DA", "--samples", "256", "--json", timeout=300)
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout)
    assert res["parameters"] == ["E0", "IOP", "thickness"]
    # P1 is the jet pressure at which the eye's pressure (and the cornea) give way: IOP drives it
    p1 = res["metrics"]["P1"]
    assert p1["S1"]["IOP"] > 0.5 and p1["ST"]["IOP"] >= p1["S1"]["IOP"] - p1["ST_conf"]["IOP"]
