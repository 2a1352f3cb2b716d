"""With pmax = 0 the prestressed cornea and the fluid stay at rest for the whole run, at coarse and
paper resolution, for the membrane and the shell cornea (clamped and pinned limbus), with no
balancing force (docs/model.md sections 3 and 3a)."""

import numpy as np
import pytest

from airpuff_core import RunParams, simulate


@pytest.mark.parametrize("resolution,cornea,limbus", [
    ("coarse", "membrane", "clamped"),
    pytest.param("paper", "membrane", "clamped", marks=pytest.mark.slow),
    ("coarse", "shell", "clamped"), ("coarse", "shell", "pinned"),
    pytest.param("paper", "shell", "clamped", marks=pytest.mark.slow)])
def test_rest_state_stays_at_rest(resolution, cornea, limbus):
    r = simulate(RunParams(resolution=resolution, pmax=0.0, cornea=cornea, limbus=limbus))
    h = r.histories
    assert r.time[-1] == pytest.approx(35.0)
    max_disp = np.max(np.abs(h["apex_displacement"]))  # mm
    max_speed = max(np.nanmax(np.abs(r.snapshots[k])) for k in ("fluid_vx", "fluid_vy"))  # m/s
    max_dp = np.max(np.abs(h["fluid_pressure_apex"] - 16.0))  # mmHg
    print(f"{resolution} {cornea} {limbus}: apex {max_disp:.3e} mm, fluid speed {max_speed:.3e} m/s, "
          f"apex pressure deviation {max_dp:.3e} mmHg")
    assert max_disp < 1e-9
    assert max_speed < 1e-9
    assert max_dp < 1e-6
    assert np.isnan(r.metrics["P1"]) and "never applanated" in r.metric_notes["P1"]
