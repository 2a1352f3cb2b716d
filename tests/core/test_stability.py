"""No growing eigenmode of the linearised coupled operator (fluid + cornea) about rest at coarse
resolution, with a margin of two in the hyperviscosity, for the Brookshaw operator (L^3) and the
default boundary-consistent one (K^* L K on the velocity); without it, modes grow
(docs/model.md section 4)."""

import numpy as np
import pytest

from airpuff_core import RunParams
from airpuff_core.coupling import CoupledModel
from airpuff_core.kernels.nodes import AXIS
from airpuff_core.params import PARAMETERS
from airpuff_core.stability import acoustic_self_coupling, linearised_step

DEFAULT = PARAMETERS["hyperviscosity"].default
NOISE = 1.0  # 1/s: an e-folding time of 1 s, 30 times the run; unstable modes grow at ~1e3-1e4 /s


@pytest.mark.slow
@pytest.mark.parametrize("operator", ["brookshaw", "consistent_velocity"])
@pytest.mark.parametrize("gamma", [DEFAULT, DEFAULT / 2])
def test_no_growing_mode(gamma, operator):
    report = linearised_step(RunParams(resolution="coarse", hyperviscosity=gamma,
                                       hyperviscosity_operator=operator))
    assert report.n_dof > 800
    assert report.max_growth_rate < NOISE, report.growth_rates[:5]


def test_without_stabilisation_modes_grow():
    report = linearised_step(RunParams(resolution="coarse", hyperviscosity=0.0))
    assert report.max_growth_rate > 100.0


def _axis_patch(model, radius):
    """The fluid nodes within ``radius`` node spacings of the axis node halfway up the axis."""
    kind, x, y, h = model.fluid.kind, model.x, model.y, model.chamber.h
    axis = np.flatnonzero(kind == AXIS)
    centre = axis[np.argmin(np.abs(y[axis] - np.median(y[axis])))]
    return np.flatnonzero(np.hypot(x - x[centre], y - y[centre]) < radius * h[centre])


def test_the_acoustics_are_diffusive_at_every_node_of_the_cloud_at_rest():
    """(D G)_ii < 0 at every node of the undistorted cloud (stability.acoustic_self_coupling):
    a density excess at a node drives fluid away from it.  A flow-distorted cloud can turn it
    positive (docs/model.md section 4, the late blow-ups at fine resolution)."""
    model = CoupledModel(RunParams(model="clinical", resolution="coarse"))
    self_coupling = acoustic_self_coupling(model) * model.chamber.h ** 2
    assert np.all(self_coupling < -0.01), self_coupling.max()


def test_a_patch_of_the_cloud_at_rest_is_stable_with_the_stabilisation_only():
    """The step map restricted to a patch of nodes (``linearised_step(..., patch=...)``, the
    tool of studies/cloud_saddle.py) has no growing mode with the default stabilisation, and
    grows without it, as the whole system does (test_no_growing_mode)."""
    params = RunParams(resolution="coarse")
    model = CoupledModel(params)
    positions = (model.x.copy(), model.y.copy())
    patch = _axis_patch(model, 4.0)
    stable = linearised_step(params, positions=positions, patch=patch)
    assert stable.n_dof > 50
    assert stable.max_growth_rate < NOISE, stable.growth_rates[:5]
    bare = linearised_step(params.replace(hyperviscosity=0.0), positions=positions, patch=patch)
    assert bare.max_growth_rate > 100.0, bare.growth_rates[:5]
