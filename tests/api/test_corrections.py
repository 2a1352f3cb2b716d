"""Corrections over HTTP (api/corrections.py): a real server on a real coarse sweep's points:
fit, apply, the Sobol indices, and the job page."""

import shutil

import numpy as np
import pytest

from sweep.correction import Correction, fit_correction
from sweep.identification import SweepTable

from tests.api.support import ServerProcess, wait_job


@pytest.mark.slow
@pytest.mark.cluster
@pytest.mark.service
def test_http_corrections_on_a_finished_job(coarse_sweep, tmp_path):
    """The real server (1 worker) on the coarse sweep's points (reused): fit, apply (rows and CSV
    text), the Sobol indices, and the job page with the formula and the residual figure."""
    data = tmp_path / "data"
    shutil.copytree(coarse_sweep.parent / "points", data / "points")
    srv = ServerProcess(data, "--workers", "1").start()
    try:
        with srv.client() as c:
            r = c.post("/sweeps", json={"E0": [0.4, 0.7], "IOP": [12, 22], "thickness": [0.45, 0.6],
                                        "resolution": "coarse"})
            assert r.status_code == 202, r.text
            job = r.json()["id"]
            assert wait_job(c, job, timeout=300)["status"] == "done"
            page = c.get(f"/jobs/{job}").text  # a page view computes nothing
            assert "None yet" in page and "Not computed yet" in page
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
