"""studies/clinical_sound_speed.py: its diagnostics of the second applanation on histories whose
answers are known in closed form (a linear crossing, a rebound of given depth)."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from studies.clinical_sound_speed import p2_conditioning, rebound_dip


def _histories(kappa, jet, t_a1=8.0, t_a2=20.0):
    t = np.arange(0.0, 30.0 + 1e-9, 0.05)  # ms, the output grid
    return xr.Dataset({"apex_curvature": ("time", kappa(t)), "jet_pressure_apex": ("time", jet(t)),
                       "t_A1": t_a1, "t_A2": t_a2}, coords={"time": t})


def test_p2_conditioning_is_the_jets_fall_over_a_curvature_change():
    """Curvature rising at 0.04/mm per ms through A2 while the jet falls 8 mmHg/ms: an error of
    0.01/mm in the curvature is 0.25 ms, over which the jet falls 2 mmHg."""
    ds = _histories(lambda t: 0.04 * (t - 20.0), lambda t: 200.0 - 8.0 * t)
    assert p2_conditioning(ds) == pytest.approx(2.0, rel=1e-9)
    assert np.isnan(p2_conditioning(ds.assign(t_A2=np.nan)))


@pytest.mark.parametrize("depth, crossings", [(0.008, 1), (-0.013, 2)])
def test_rebound_dip_is_the_depth_of_the_apex_rebound_after_it_turns_convex(depth, crossings):
    """Concave until 20 ms, convex after, with a rebound 1 ms later down to ``depth`` [1/mm]
    (below zero: a second concave -> convex crossing, which is then A2); before A1 the curvature
    crosses too, which does not count."""
    def kappa(t):
        return np.select(
            [t < 2.0, t < 20.0, t < 21.0, t < 22.0],
            [0.1 * (t - 1.0), -0.1 * (20.0 - t) / 18.0, 0.05 * (t - 20.0),
             depth + (0.05 - depth) * np.abs(t - 21.5) / 0.5], 0.05)

    ds = _histories(kappa, lambda t: 0.0 * t)
    dip, n = rebound_dip(ds)
    assert dip == pytest.approx(depth, abs=1e-9)
    assert n == crossings
