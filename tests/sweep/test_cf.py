"""Every kind of netCDF file the project writes (run, sweep point, sweep.nc) is clean CF at the
version it declares: the IOOS compliance-checker finds no error, and the points it checks are
also checked here directly (time axis, UDUNITS units, history, Conventions).

A run's file (``airpuff run --out``) is the dataset of a sweep point's file without the three
global attributes the sweep adds: checked here, so that the compliance-checker (about 10 s a
file, longer on a busy machine) reads the point file only."""

import cf_units
import netCDF4
import pytest

from airpuff_core.dataset import CONVENTIONS, open_dataset
from tools.cf_check import cf_findings, checker_name, write_files


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return write_files(tmp_path_factory.mktemp("cf"))


# what a sweep point's file has beyond a run's (sweep/worker.py)
POINT_ONLY_ATTRS = {"sweep_point_key", "wall_time_s", "computed_on_host"}


def test_a_run_file_is_a_point_file_without_the_sweeps_attributes(files):
    """The same parameters give the run's and the point's file the same dimensions, variables,
    types and attributes; the point's file adds only ``POINT_ONLY_ATTRS``."""
    with netCDF4.Dataset(files["run"]) as run, netCDF4.Dataset(files["point"]) as point:
        assert set(point.ncattrs()) - set(run.ncattrs()) == POINT_ONLY_ATTRS
        assert set(run.ncattrs()) <= set(point.ncattrs())
        assert {k: len(d) for k, d in run.dimensions.items()} == \
            {k: len(d) for k, d in point.dimensions.items()}
        assert list(run.variables) == list(point.variables)
        for name, var in run.variables.items():
            other = point.variables[name]
            assert (var.dimensions, var.dtype) == (other.dimensions, other.dtype), name
            assert var.ncattrs() == other.ncattrs(), name
            for attr in var.ncattrs():
                assert str(var.getncattr(attr)) == str(other.getncattr(attr)), (name, attr)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["point", "sweep"])
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
