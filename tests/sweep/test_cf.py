"""Every kind of netCDF file the project writes (run, sweep point, sweep.nc) is clean CF at the
version it declares: the IOOS compliance-checker finds no error, and the points it checks are
also checked here directly (time axis, UDUNITS units, history, Conventions)."""

import cf_units
import netCDF4
import pytest

from airpuff_core.dataset import CONVENTIONS, open_dataset
from tools.cf_check import cf_findings, checker_name, write_files


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return write_files(tmp_path_factory.mktemp("cf"))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["run", "point", "sweep"])
def test_compliance_checker_finds_no_error(files, kind):
    found = cf_findings(files[kind])
    assert found["version"] == ["cf:1.10"]
    assert found["errors"] == [], found["errors"]


@pytest.mark.parametrize("kind", ["run", "point", "sweep"])
def test_cf_points_checked_directly(files, kind):
    path = files[kind]
    assert checker_name(path) == "cf:" + CONVENTIONS[3:]
    with netCDF4.Dataset(path) as nc:
        assert nc.getncattr("Conventions") == CONVENTIONS
        history = nc.getncattr("history")
        assert isinstance(history, str) and "airpuff" in history
        time = nc.variables["time"]
        attrs = time.ncattrs()
        # CF 2.5.1: no missing values in a coordinate variable; CF 4.4: a time axis
        assert "_FillValue" not in attrs and "missing_value" not in attrs
        assert time.getncattr("standard_name") == "time" and time.getncattr("axis") == "T"
        unit = cf_units.Unit(time.getncattr("units"), calendar=time.getncattr("calendar"))
        assert unit.is_time_reference()
        # every units attribute is a valid UDUNITS unit (e.g. "degree", not "deg")
        for name, var in nc.variables.items():
            if "units" in var.ncattrs():
                cf_units.Unit(var.getncattr("units"))  # raises ValueError if not UDUNITS
    with pytest.raises(ValueError):
        cf_units.Unit("deg")  # the check can fail: a common spelling that is not UDUNITS


def test_time_reads_back_in_milliseconds(files):
    with open_dataset(files["run"]) as ds:
        t = ds["time"].values
    assert t.dtype.kind == "f" and t[0] == 0.0 and t[-1] == pytest.approx(0.5)
