"""Identify IOP and E0 from a measurement, on a real sweep (no mocks).

One real coarse sweep (E0 0.3, 0.5, 0.7 MPa x IOP 10, 14, 18, 22 mmHg; thickness 0.5 mm, pmax
10 kPa; 12 points on 2 Dask workers) and five direct solver runs at parameter values off the grid
serve every test here.  Tolerances (measured margins in docs/identify.md):

* from (P1, P2) alone, and from all five metrics: IOP within 1.0 mmHg of the truth, and the truth
  inside the reported 68 % E0 interval;
* from (P1, P2): E0 not identified (its interval is the whole sweep, 0.3 to 0.7 MPa);
* from all five metrics: E0 within 0.1 MPa of the truth (noise-free synthetic data);
* from DA and the applanation times, at IOP 12 mmHg: E0 identified, interval narrower than 0.3 MPa.
"""

from __future__ import annotations

import concurrent.futures
import json
import multiprocessing
import shutil

import pytest

from sweep.grid import SweepSpec
from sweep.identification import (RAW_SIGMA, IdentifyError, SweepTable, identify, refine,
                                  solver_metrics)
from sweep.runner import run_sweep

from tests.conftest import airpuff

from tests.api.support import ServerProcess, wait_job

pytestmark = [pytest.mark.cluster, pytest.mark.slow]

GRID = {"E0": [0.3, 0.5, 0.7], "IOP": [10.0, 14.0, 18.0, 22.0], "thickness": [0.5],
        "pmax": [10.0], "options": {"resolution": "coarse"}}
# (IOP [mmHg], E0 [MPa]) off the grid in both parameters
TRUTHS = [(12.0, 0.4), (16.0, 0.4), (20.0, 0.4), (12.0, 0.6), (20.0, 0.6)]
RAW = tuple(RAW_SIGMA)  # the five raw measurable metrics
IOP_TOL = 1.0  # mmHg
E0_TOL_ALL = 0.1  # MPa, all five metrics measured


@pytest.fixture(scope="session")
def id_sweep(tmp_path_factory):
    """(sweep.nc path, data dir whose points/ holds the point files) of the 12-point sweep."""
    root = tmp_path_factory.mktemp("identify")
    data = root / "data"
    out = run_sweep(SweepSpec.from_dict(GRID), root / "sweep", workers=2,
                    points_dir=data / "points")
    assert out.failed == 0
    return out.path, data


@pytest.fixture(scope="session")
def truths(id_sweep):
    """Metrics of direct solver runs at the off-grid TRUTHS (2 processes, after the sweep)."""
    params = [{**GRID["options"], "E0": e, "IOP": p, "thickness": 0.5, "pmax": 10.0}
              for p, e in TRUTHS]
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(2, mp_context=ctx) as pool:
        metrics = list(pool.map(solver_metrics, params))
    return list(zip(TRUTHS, metrics))


@pytest.fixture(scope="session")
def table(id_sweep):
    return SweepTable.from_netcdf(id_sweep[0])


def _meas(metrics, names):
    return {n: metrics[n] for n in names}


@pytest.mark.parametrize("names", [("P1", "P2"), RAW], ids=["P1P2", "all"])
def test_round_trip_off_grid(table, truths, names):
    for (iop, e0), m in truths:
        est = identify(table, _meas(m, names), thickness=0.5, pmax=10.0)
        assert abs(est.IOP - iop) <= IOP_TOL, (names, iop, e0, est.to_dict())
        assert est.IOP_interval[0] - 1e-9 <= est.IOP <= est.IOP_interval[1] + 1e-9
        assert est.E0_interval[0] - 1e-9 <= e0 <= est.E0_interval[1] + 1e-9, (names, iop, e0,
                                                                               est.to_dict())
        if names == RAW:
            assert abs(est.E0 - e0) <= E0_TOL_ALL, (iop, e0, est.to_dict())
        else:  # P1 and P2 carry (almost) no information on E0: the interval is the whole sweep
            assert not est.E0_identified and est.E0_interval == pytest.approx((0.3, 0.7)), est.to_dict()


@pytest.mark.parametrize("names", [("DA", "t_A1", "t_A2"), RAW], ids=["DAtimes", "all"])
def test_deformation_identifies_E0_at_low_IOP(table, truths, names):
    """DA and the applanation times bound E0 at IOP 12 mmHg (at 20 mmHg they hardly do)."""
    for (iop, e0), m in truths:
        if iop == 12.0:
            est = identify(table, _meas(m, names), thickness=0.5)
            assert est.E0_identified, est.to_dict()
            assert est.E0_interval[1] - est.E0_interval[0] < 0.3, est.to_dict()


def test_out_of_range_measurement_is_refused(table, id_sweep):
    with pytest.raises(IdentifyError) as err:
        identify(table, {"P1": 60.0}, thickness=0.5)
    assert err.value.field == "P1" and "outside" in str(err.value)
    proc = airpuff("identify", "--sweep", str(id_sweep[0]), "--P1", "60", "--P2", "50")
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "P1=60 mmHg is outside what the sweep covers" in lines[0], lines[0]
    assert proc.stdout == ""


def test_thickness_outside_sweep_is_refused(table):
    with pytest.raises(IdentifyError, match=r"thickness=0.6 mm is outside the sweep"):
        identify(table, {"P1": 15.0}, thickness=0.6)


@pytest.mark.parametrize("args, word", [
    (["--P1", "abc"], "--P1"), ([], "no measured quantity"), (["--P1", "15+-0"], "sigma"),
    (["--P1", "15", "--pmax", "x"], "--pmax"), (["--P1", "15", "--refine-runs", "20"], "refine-runs"),
    (["--P1", "15", "--instrument", "ora"], "accepted paper"),  # the sweep's is the paper's jet
])
def test_cli_bad_input_is_one_line(id_sweep, args, word):
    proc = airpuff("identify", "--sweep", str(id_sweep[0]), *args)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and word in proc.stderr, proc.stderr


def test_cli_json(id_sweep, truths):
    (iop, e0), m = truths[1]
    proc = airpuff("identify", "--sweep", str(id_sweep[0]), "--json",
                   "--P1", f"{m['P1']:.3f}+-0.3", "--P2", f"{m['P2']:.3f}",
                   "--DA", f"{m['DA']:.4f}", "--t-A1", f"{m['t_A1']:.3f}")
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    assert abs(d["IOP"] - iop) <= IOP_TOL
    assert d["E0_interval"][0] <= e0 <= d["E0_interval"][1]
    assert d["measurement"]["P1"] == {"value": round(m["P1"], 3), "sigma": 0.3}
    assert d["measurement"]["P2"]["sigma"] == 0.5  # the default
    assert set(d) >= {"IOP", "E0", "IOP_interval", "E0_interval", "E0_identified", "chi2_min"}
    assert d["scale"].startswith("raw: P1 and P2 are compared with the sweep's raw readings")


def test_refine_with_solver_runs(table, truths):
    (iop, e0), m = truths[3]
    est = identify(table, _meas(m, RAW), thickness=0.5)
    ref = refine(table, est, max_runs=4)
    assert ref.refined["solver_runs"] == 4
    # the refined point is at least as good as the grid estimate, as judged by the solver itself
    assert ref.chi2_min <= ref.refined["iterations"][0]["chi2"] + 1e-12
    assert abs(ref.IOP - iop) <= IOP_TOL and abs(ref.E0 - e0) <= E0_TOL_ALL, ref.to_dict()


@pytest.mark.service
def test_http_identify_on_a_finished_job(id_sweep, truths, tmp_path):
    """The real server (1 worker): the job's points are already on disk and are reused."""
    _, data = id_sweep
    data2 = tmp_path / "data"
    shutil.copytree(data / "points", data2 / "points")
    srv = ServerProcess(data2, "--workers", "1").start()
    try:
        with srv.client() as c:
            (iop, e0), m = truths[0]
            body = {"job_id": "0" * 32, "thickness": 0.5,
                    "measurement": {"P1": {"value": m["P1"]}, "P2": {"value": m["P2"]}}}
            assert c.post("/identify", json=body).status_code == 404
            r = c.post("/sweeps", json={k: GRID[k] for k in ("E0", "IOP", "thickness", "pmax")}
                       | {"resolution": "coarse"})
            assert r.status_code == 202, r.text
            job = r.json()["id"]
            assert wait_job(c, job, timeout=120)["status"] == "done"
            r = c.post("/identify", json={**body, "job_id": job, "instrument": "ora"})
            assert r.status_code == 422, r.text
            assert any(e["field"] == "instrument" for e in r.json()["detail"]), r.text
            r = c.post("/identify", json={**body, "job_id": job})
            assert r.status_code == 200, r.text
            d = r.json()
            assert d["instrument"] == "paper"
            assert abs(d["IOP"] - iop) <= IOP_TOL and d["job_id"] == job
            assert d["E0_interval"][0] <= e0 <= d["E0_interval"][1]
            # the same answer as the CLI's interpolation on the job's sweep.nc
            local = identify(SweepTable.from_netcdf(id_sweep[0]),
                             {"P1": m["P1"], "P2": m["P2"]}, thickness=0.5).to_dict()
            assert d["IOP"] == local["IOP"] and d["E0_interval"] == local["E0_interval"]
            assert d["scale"] == local["scale"] and d["scale"].startswith("raw")
            r = c.post("/identify", json={**body, "job_id": job,
                                          "measurement": {"P1": {"value": 60.0}}})
            assert r.status_code == 422 and r.json()["detail"][0]["field"] == "P1", r.text
            assert "outside what the sweep covers" in r.json()["detail"][0]["msg"]
            # a calibrated reading without the job's calibration: 422 naming it and the command
            r = c.post("/identify", json={**body, "job_id": job, "measurement": {
                "IOPg_cal": {"value": 16.0}, "CH_cal": {"value": 5.0}}})
            assert r.status_code == 422 and r.json()["detail"][0]["field"] == "IOPg_cal", r.text
            assert "airpuff calibrate" in r.json()["detail"][0]["msg"]
            r = c.post("/identify", json={**body, "job_id": job, "refine": True})
            assert r.status_code == 422 and r.json()["detail"][0]["field"] == "refine"
            r = c.post("/identify", json={**body, "job_id": job, "measurement": {}})
            assert r.status_code == 422, r.text
            r = c.post("/identify", json={**body, "job_id": job, "thickness": 0.7})
            assert r.status_code == 422 and r.json()["detail"][0]["field"] == "thickness"
            # a job that is not done yet: 409 (then cancel it)
            r = c.post("/sweeps", json={"E0": [0.45], "IOP": [15.0], "resolution": "coarse"})
            other = r.json()["id"]
            r = c.post("/identify", json={**body, "job_id": other})
            assert r.status_code == 409, r.text
            c.delete(f"/sweeps/{other}")
    finally:
        srv.stop()


def test_calibrated_measurement_needs_the_sweeps_calibration(table):
    """The paper's model has no shipped calibration at coarse resolution: a calibrated reading
    is refused with the reason and the command that makes one, and the scales do not mix."""
    with pytest.raises(IdentifyError, match="airpuff calibrate") as err:
        identify(table, {"IOPg_cal": 16.0, "CH_cal": 5.0}, thickness=0.5)
    assert err.value.field == "IOPg_cal"
    with pytest.raises(IdentifyError, match="two scales") as err:
        identify(table, {"P1": 20.0, "P2_cal": 15.0}, thickness=0.5)
    with pytest.raises(IdentifyError, match="at most two") as err:
        identify(table, {"P1_cal": 20.0, "P2_cal": 15.0, "CH_cal": 5.0}, thickness=0.5)
    assert err.value.field == "CH_cal"


def test_calibrated_identification_is_the_raw_one_mapped(id_sweep, truths, tmp_path,
                                                        monkeypatch):
    """With a calibration P_cal = a + b P (fitted by the real fitting code on the sweep's own
    reference slice, E0 0.5 MPa), chi^2 of (P1_cal, P2_cal) with sigmas b s equals chi^2 of
    (P1, P2) with sigmas s term by term (the interpolation errors scale by b too), so the
    estimate and its region are the raw one's; and IOPg_cal, CH_cal (an ORA's printout)
    identify IOP within the raw tolerance."""
    from airpuff_core.calibration import FORMAT, apply_coefficients, fit_coefficients
    from airpuff_core.dataset import write_netcdf
    from airpuff_core.provenance import model_version
    from sweep.combine import combine

    path, data = id_sweep
    raw = SweepTable.from_netcdf(path)
    e = list(raw.E0).index(0.5)
    coef = fit_coefficients(raw.IOP, raw.metrics["P1"][e, :, 0, 0], raw.metrics["P2"][e, :, 0, 0])
    spec = SweepSpec.from_dict(GRID)
    options = {k: v for k, v in spec.point(0).to_dict().items() if k != "IOP"}
    cal_dir = tmp_path / "calibrations"
    cal_dir.mkdir()
    (cal_dir / "paper_paper_coarse_test.json").write_text(json.dumps({
        "format": FORMAT, "instrument": "paper", "model_version": model_version(),
        "resolution": "coarse", "model": "paper", "run_options": options, "coefficients": coef}))
    monkeypatch.setenv("AIRPUFF_CALIBRATION_DIR", str(cal_dir))
    cal_table = SweepTable.from_netcdf(write_netcdf(combine(spec, data / "points"),
                                                    tmp_path / "sweep.nc"))
    b = coef["pressure_slope"]
    (iop, e0), m = truths[1]
    c = apply_coefficients(coef, m["P1"], m["P2"])
    by_raw = identify(cal_table, {"P1": (m["P1"], 0.5), "P2": (m["P2"], 0.5)}, thickness=0.5)
    by_cal = identify(cal_table, {"P1_cal": (c["P1_cal"], 0.5 * b),
                                  "P2_cal": (c["P2_cal"], 0.5 * b)}, thickness=0.5)
    assert by_cal.IOP == by_raw.IOP and by_cal.E0 == by_raw.E0
    assert by_cal.IOP_interval == by_raw.IOP_interval
    assert by_cal.chi2_min == pytest.approx(by_raw.chi2_min, rel=1e-9, abs=1e-12)
    assert by_cal.to_dict()["scale"].startswith("calibrated")
    printout = identify(cal_table, {"IOPg_cal": c["IOPg_cal"], "CH_cal": c["CH_cal"]},
                        thickness=0.5)
    assert abs(printout.IOP - iop) <= IOP_TOL, printout.to_dict()
    proc = airpuff("identify", "--sweep", str(tmp_path / "sweep.nc"), "--thickness", "0.5",
                   "--IOPg-cal", f"{c['IOPg_cal']:.4f}", "--CH-cal", f"{c['CH_cal']:.4f}")
    assert proc.returncode == 0, proc.stderr
    assert "scale: calibrated" in proc.stdout
