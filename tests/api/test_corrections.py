"""Corrections over HTTP (api/corrections.py): a real server on a real coarse sweep's points:
fit, apply, the Sobol indices, and the job page."""

import json
import shutil

import numpy as np
import pytest
import xarray as xr

from airpuff_core.calibration import FORMAT
from airpuff_core.params import RunParams
from airpuff_core.provenance import model_version
from sweep.correction import Correction, fit_correction
from sweep.identification import SweepTable

from tests.api.support import ServerProcess, wait_job

# the coefficients of a calibration made for the test (docs/calibration.md's formulas)
COEFFICIENTS = {"pressure_offset": -7.25, "pressure_slope": 0.8875, "crf_constant": 1.5,
                "iopcc_ora_scale": 1.2, "iopcc_ora_constant": 3.0, "iopnc_offset": -6.0,
                "iopnc_slope": 0.9}


def write_calibration(directory) -> None:
    """A calibration of the paper's jet at coarse resolution for this model version, for the
    runs of the coarse sweep (the default options)."""
    options = {k: v for k, v in RunParams(resolution="coarse").to_dict().items() if k != "IOP"}
    directory.mkdir()
    (directory / "paper_test.json").write_text(json.dumps({
        "format": FORMAT, "instrument": "paper", "model_version": model_version(),
        "resolution": "coarse", "model": "paper", "run_options": options,
        "coefficients": COEFFICIENTS}))


def check_calibrated(points, dataset) -> None:
    """Each point's calibrated readings are the formulas of docs/calibration.md applied to its
    raw ones, and those of the job's netCDF."""
    c = COEFFICIENTS
    n = 0
    for p in points:
        assert p["calibration"].startswith("paper_test.json") and p["calibration_missing"] is None
        if p["P1"] is None or p["P2"] is None:
            assert p["IOPg_cal"] is None
            continue
        n += 1
        p1, p2 = (c["pressure_offset"] + c["pressure_slope"] * p[k] for k in ("P1", "P2"))
        expected = {"P1_cal": p1, "P2_cal": p2, "CH_cal": p1 - p2, "IOPg_cal": (p1 + p2) / 2,
                    "IOPcc_cal": p1 - 0.43 * p2, "CRF_cal": p1 - 0.70 * p2 + c["crf_constant"],
                    "IOPcc_ora_cal": c["iopcc_ora_scale"] * (p2 - 0.43 * p1)
                    + c["iopcc_ora_constant"],
                    "IOPnc_cal": c["iopnc_offset"] + c["iopnc_slope"] * p["P1"]}
        at = dataset.sel(E0=p["E0"], IOP=p["IOP"], thickness=p["thickness"], pmax=p["pmax"])
        for name, value in expected.items():
            assert p[name] == pytest.approx(value, abs=1e-9), name
            assert float(at[name]) == pytest.approx(value, abs=1e-9), name
    assert n >= 1


@pytest.mark.slow
@pytest.mark.cluster
@pytest.mark.service
def test_http_corrections_on_a_finished_job(coarse_sweep, tmp_path):
    """The real server (1 worker) on the coarse sweep's points (reused), with a calibration of
    its own: the calibrated readings beside the raw ones in the metrics, the dataset and the
    page; fit, apply (rows and CSV text), the Sobol indices, and the job page with the formula
    and the residual figure."""
    data = tmp_path / "data"
    shutil.copytree(coarse_sweep.parent / "points", data / "points")
    write_calibration(tmp_path / "calibrations")
    srv = ServerProcess(data, "--workers", "1",
                        env={"AIRPUFF_CALIBRATION_DIR": str(tmp_path / "calibrations")}).start()
    try:
        with srv.client() as c:
            r = c.post("/sweeps", json={"E0": [0.4, 0.7], "IOP": [12, 22], "thickness": [0.45, 0.6],
                                        "resolution": "coarse"})
            assert r.status_code == 202, r.text
            job = r.json()["id"]
            assert wait_job(c, job, timeout=300)["status"] == "done"
            points = c.get(f"/sweeps/{job}/metrics").json()["points"]
            (tmp_path / "job.nc").write_bytes(c.get(f"/sweeps/{job}/dataset").content)
            with xr.open_dataset(tmp_path / "job.nc") as ds:
                check_calibrated(points, ds)
            page = c.get(f"/jobs/{job}").text  # a page view computes nothing
            assert "None yet" in page and "Not computed yet" in page
            n_ok = sum(p["status"] == "ok" for p in points)
            assert "IOPg_cal [mmHg]" in page
            assert f"{n_ok} points calibrated with <code>paper_test.json" in page
            # the calibrated figures beside the raw ones, and a calibrated identification
            for name in ("ora-IOPg_cal", "ora-CH_cal"):
                assert f"/figures/{name}.png" in page
                r = c.get(f"/jobs/{job}/figures/{name}.png")
                assert r.status_code == 200 and r.content.startswith(b"\x89PNG"), name
            ok = next(p for p in points if p["IOPg_cal"] is not None and p["thickness"] == 0.45)
            r = c.post("/identify", json={"job_id": job, "thickness": 0.45, "measurement": {
                "IOPg_cal": {"value": ok["IOPg_cal"]}, "CH_cal": {"value": ok["CH_cal"]}}})
            assert r.status_code == 200, r.text
            assert r.json()["scale"].startswith("calibrated")
            assert abs(r.json()["IOP"] - ok["IOP"]) <= 1.0, r.json()
            assert c.post(f"/sweeps/{'0' * 32}/corrections",
                          json={"instrument": "ora"}).status_code == 404
            r = c.post(f"/sweeps/{job}/corrections", json={"instrument": "goldmann"})
            assert r.status_code == 422 and r.json()["detail"][0]["field"] == "instrument", r.text
            r = c.post(f"/sweeps/{job}/corrections", json={"instrument": "ora"})
            assert r.status_code == 201, r.text
            summary = r.json()
            cid = summary["id"]
            assert r.headers["location"] == f"/sweeps/{job}/corrections/{cid}"
            # the same formula as the CLI's fit on the job's own sweep.nc
            table = SweepTable.from_netcdf(coarse_sweep)
            local = fit_correction(table, "ora")
            stored = c.get(f"/sweeps/{job}/corrections/{cid}").json()
            for t in ("IOP", "E0"):
                np.testing.assert_allclose(
                    [x["coefficient"] for x in stored["targets"][t]["terms"]],
                    [x["coefficient"] for x in local["targets"][t]["terms"]], rtol=1e-9, atol=1e-12)
            assert [x["id"] for x in c.get(f"/sweeps/{job}/corrections").json()["corrections"]] == [cid]
            p1 = float(table.metrics["P1"][0, 1, 0, 0])
            p2 = float(table.metrics["P2"][0, 1, 0, 0])
            rows = [{"id": "a", "P1": p1, "P2": p2, "CCT": 450, "P1_sigma": 0.5},
                    {"id": "b", "P1": "x", "P2": p2, "CCT": 450},
                    {"id": "c", "P1": 80, "P2": p2, "CCT": 450}]
            r = c.post(f"/sweeps/{job}/corrections/{cid}/apply", json={"rows": rows})
            assert r.status_code == 200, r.text
            out = r.json()
            assert [x["status"] for x in out["rows"]] == ["ok", "error", "outside"], out
            expected = Correction.from_dict(local).apply_row(rows[0], {"P1": 0.5})
            assert out["rows"][0]["IOP"] == pytest.approx(expected["IOP"], rel=1e-9)
            assert out["rows"][0]["IOP_sigma"] == pytest.approx(expected["IOP_sigma"], rel=1e-9)
            text = f"id,P1,P2,CCT\na,{p1},{p2},450\n"
            r = c.post(f"/sweeps/{job}/corrections/{cid}/apply", json={"csv": text})
            assert r.status_code == 200 and r.json()["rows"][0]["IOP"] == pytest.approx(
                expected["IOP"], rel=1e-9), r.text
            r = c.post(f"/sweeps/{job}/corrections/{cid}/apply", json={"csv": "P1,P2\n1,2\n"})
            assert r.status_code == 422 and "no column for CCT" in r.json()["detail"][0]["msg"]
            assert c.post(f"/sweeps/{job}/corrections/ffffffffffff/apply",
                          json={"rows": rows}).status_code == 404
            r = c.get(f"/sweeps/{job}/sensitivity")
            assert r.status_code == 200, r.text
            assert r.json()["metrics"]["P1"]["S1"]["IOP"] > 0.5
            page = c.get(f"/jobs/{job}")
            assert page.status_code == 200
            assert "ora correction" in page.text and "S1 IOP" in page.text
            assert stored["targets"]["IOP"]["formula"].split(" = ")[1][:12] in page.text
            png = c.get(f"/jobs/{job}/corrections/{cid}/residuals.png")
            assert png.status_code == 200 and png.content.startswith(b"\x89PNG")
    finally:
        srv.stop()
