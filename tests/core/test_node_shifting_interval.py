"""The option ``node_shifting_interval`` (fluid_stepper.py; docs/model.md section 4, "Node
shifting"): with N > 1 the nodes are shifted after every N-th step only, by the shift of the N
steps' time together (at most N times the per-step limit).

Checked: a displaced node moves back by up to N times the per-step limit and linear fields are
carried exactly (a linear field's gradient is exact); the shifts fall on every N-th step and
take the summed dt; a coarse run keeps its mass and volume, and a coarse clinical run its
metrics at the default interval (8) within the stated accuracy of a clinical point (issue 31)
of the run shifted at every step."""

import numpy as np
import pytest

from airpuff_core import RunParams, simulate
from airpuff_core.coupling import CoupledModel
from airpuff_core.fluid_stepper import SHIFT_LIMIT, FluidStepper

from tests.conftest import assert_within_stated_accuracy
from tests.core.test_node_shifting import (assert_conserves_mass_and_volume,
                                          assert_linear_fields_carried,
                                          displaced_node_with_linear_fields)


def test_a_shift_of_n_steps_moves_up_to_n_limits_and_carries_linear_fields():
    model = CoupledModel(RunParams(resolution="coarse", node_shifting=1.0,
                                   node_shifting_interval=3))
    fluid = model.fluid
    i, h = displaced_node_with_linear_fields(fluid)
    x0, y0 = fluid.x.copy(), fluid.y.copy()
    fluid.shift(2.0 * h / fluid.max_speed(), steps=3)  # a request far above the limit
    moved = np.hypot(fluid.x - x0, fluid.y - y0)
    assert 2.0 * SHIFT_LIMIT * h < moved[i] <= 3.0 * SHIFT_LIMIT * h * (1 + 1e-12)
    assert_linear_fields_carried(fluid)


@pytest.mark.parametrize("interval", [1, 3])
def test_the_shifts_fall_on_every_nth_step_with_the_summed_time(interval, monkeypatch):
    calls = []
    shift = FluidStepper.shift

    def observed(self, dt, steps=1):
        calls.append((dt, steps))
        return shift(self, dt, steps)

    monkeypatch.setattr(FluidStepper, "shift", observed)
    model = CoupledModel(RunParams(resolution="coarse", model="clinical", t_end=0.2,
                                   node_shifting_interval=interval))
    dts = []
    for _ in range(7):
        dts.append(model.step())
    assert [steps for _, steps in calls] == [interval] * (7 // interval)
    for k, (dt, _) in enumerate(calls):
        assert dt == pytest.approx(sum(dts[k * interval:(k + 1) * interval]), rel=1e-15)


def test_the_default_interval_of_eight_keeps_the_clinical_metrics():
    base = RunParams(resolution="coarse", model="clinical")
    assert base.node_shifting_interval == 8
    every = simulate(base.replace(node_shifting_interval=1), threads=1)
    eighth = simulate(base, threads=1)
    assert_within_stated_accuracy(eighth.metrics, every.metrics)


def test_an_interval_of_four_conserves_mass_and_volume():
    """As ``test_node_shifting.test_a_run_with_shifting_conserves_mass_and_volume`` (the rigid
    chamber of the paper preset, whose volume is exact), with the shifts every fourth step."""
    fourth = simulate(RunParams(resolution="coarse", node_shifting=1.0,
                                node_shifting_interval=4), threads=1)
    assert_conserves_mass_and_volume(fourth)
