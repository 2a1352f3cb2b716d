"""``airpuff identify`` and ``POST /identify`` take the instrument of the measurement, which must
be the one whose pulse the sweep was computed with (a table made here; the numerics of the
identification are tests/sweep/test_identify.py's, on a real sweep)."""

from __future__ import annotations

import numpy as np
import pytest

from sweep.identification import IdentifyError, SweepTable, identify

E0 = np.array([0.3, 0.5, 0.7])
IOP = np.array([10.0, 15.0, 20.0, 25.0])


def _table(options):
    """A sweep table whose P1 and P2 are planes in (E0, IOP): the estimate is exact."""
    e, p = np.meshgrid(E0, IOP, indexing="ij")
    metrics = {"P1": (p + 10.0 * e)[..., None, None], "P2": (p - 4.0 * e)[..., None, None]}
    return SweepTable(E0, IOP, np.array([0.5]), np.array([10.0]), metrics, 0, options)


@pytest.mark.parametrize("options,instrument", [({}, "paper"), ({"instrument": "ora"}, "ora"),
                                                ({"instrument": "corvis"}, "corvis")])
def test_the_estimate_names_the_sweeps_instrument(options, instrument):
    table = _table(options)
    measured = {"P1": 15.0 + 5.0, "P2": 15.0 - 2.0}  # IOP 15, E0 0.5
    for given in (None, instrument):
        est = identify(table, measured, instrument=given)
        assert est.instrument == instrument and est.to_dict()["instrument"] == instrument
        assert est.IOP == pytest.approx(15.0, abs=0.05) and est.E0 == pytest.approx(0.5, abs=0.01)


@pytest.mark.parametrize("given,needle", [("corvis", "accepted ora"),
                                          ("nct", "accepted one of paper, ora, corvis")])
def test_another_instrument_than_the_sweeps_is_refused(given, needle):
    with pytest.raises(IdentifyError) as err:
        identify(_table({"instrument": "ora"}), {"P1": 20.0}, instrument=given)
    assert err.value.field == "instrument" and needle in str(err.value), str(err.value)
