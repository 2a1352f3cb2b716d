"""Run parameters: the SI values the solver gets, and the combinations that RunParams rejects
(docs/model.md section 1), checked against values computed here by hand."""

import math

import numpy as np
import pytest

from airpuff_core import ParameterError, RunParams
from airpuff_core.cornea.reference import prestretch
from airpuff_core.kernels.air_jet import PAPER
from airpuff_core.loads.air_jet import AirJet


def test_si_values_are_the_user_values_in_si_units():
    si = RunParams(E0=0.5, IOP=16, thickness=0.5, pmax=10, R=7, r_post=2.04, alpha0=60, T=30,
                   t0=15, t_end=35, output_interval=0.05).si()
    assert si.E0_Pa == pytest.approx(5e5, rel=1e-15)
    assert si.p0_Pa == pytest.approx(16 * 133.322, rel=1e-15)
    assert si.thickness_m == pytest.approx(5e-4, rel=1e-15)
    assert si.pmax_Pa == pytest.approx(1e4, rel=1e-15)
    assert (si.R_m, si.r_post_m) == pytest.approx((7e-3, 2.04e-3), rel=1e-15)
    assert si.alpha0_rad == pytest.approx(math.pi / 3, rel=1e-15)
    assert (si.T_s, si.t0_s, si.t_end_s, si.output_interval_s) == pytest.approx(
        (0.03, 0.015, 0.035, 5e-5), rel=1e-15)
    jet = AirJet(si, np.array([0.0]))
    assert list(jet.kernel_args) == pytest.approx([PAPER, 1e4, 21.5, 25.0, 0.03, 0.015], rel=1e-15)


def test_a_cornea_too_soft_to_carry_the_iop_is_a_parameter_error():
    """With fung_k = 0 the equibiaxial tension is linear, N = E0 h / (1 - nu) E, and Laplace's law
    N = p0 R / 2 at the largest prestretch 10 (E = 49.5) gives the softest accepted E0."""
    p0, R, h, nu = 16 * 133.322, 7e-3, 5e-4, 0.5
    E_max = 0.5 * (10.0 ** 2 - 1.0)
    E0_min_MPa = 0.5 * p0 * R / (h / (1 - nu) * E_max) * 1e-6
    with pytest.raises(ParameterError) as err:
        RunParams(E0=0.99 * E0_min_MPa, fung_k=0.0)
    assert err.value.name == "E0" and "\n" not in str(err.value)
    assert f"{E0_min_MPa:.3g} MPa" in str(err.value)
    si = RunParams(E0=1.01 * E0_min_MPa, fung_k=0.0).si()
    Ebar = si.E0_Pa * si.thickness_m / (1 - si.nu ** 2)
    lam = prestretch(si.p0_Pa, si.R_m, Ebar, si.nu, 0.0)
    assert lam == pytest.approx(math.sqrt(1 + 2 * E_max / 1.01), rel=1e-9)


@pytest.mark.parametrize("values, name", [
    ({"thickness": 5e-324, "fung_k": 0.0}, "E0"),  # no E0 in range will do
    ({"thickness": 1e-300, "E0": 1e-300}, "thickness"),  # E0 h underflows to 0 in SI
])
def test_extreme_values_in_range_are_parameter_errors(values, name):
    """Values at the edge of double precision give a ParameterError, never an arithmetic one."""
    with pytest.raises(ParameterError) as err:
        RunParams(**values)
    assert err.value.name == name


def test_the_polar_lattice_needs_the_sector():
    with pytest.raises(ParameterError) as err:
        RunParams(geometry="cap", layout="polar")
    assert err.value.name == "layout"
    RunParams(geometry="sector", layout="polar")
