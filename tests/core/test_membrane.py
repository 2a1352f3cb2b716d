"""Membrane law and discretisation: N = dW/dE, small-strain and SVK limits, Laplace's law for the
prestretch, internal forces = -grad of the discrete energy, and the discrete rest state."""

import math

import numpy as np
import pytest

from airpuff_core import RunParams
from airpuff_core.coupling import CoupledModel
from airpuff_core.kernels.membrane import fung_resultants, internal_forces
from airpuff_core.cornea.apex import apex_curvature, apex_fit_nodes
from airpuff_core.cornea.reference import build_membrane, equibiaxial_tension, prestretch

EBAR, NU = 333.0, 0.5


def energy(E1, E2, Ebar, nu, k):
    """W = C/2 [exp(Q) - 1], C k = Ebar (k > 0)."""
    Q = k * (E1 ** 2 + E2 ** 2 + 2 * nu * E1 * E2)
    return Ebar / k / 2 * math.expm1(Q)


@pytest.mark.parametrize("k", [0.5, 5.0, 50.0])
@pytest.mark.parametrize("E1,E2", [(0.02, 0.01), (-0.01, 0.03), (0.1, 0.08)])
def test_resultants_are_energy_derivatives(k, E1, E2):
    eps = 1e-7
    N1, N2 = fung_resultants(E1, E2, EBAR, NU, k)
    dW1 = (energy(E1 + eps, E2, EBAR, NU, k) - energy(E1 - eps, E2, EBAR, NU, k)) / (2 * eps)
    dW2 = (energy(E1, E2 + eps, EBAR, NU, k) - energy(E1, E2 - eps, EBAR, NU, k)) / (2 * eps)
    assert N1 == pytest.approx(dW1, rel=1e-7)
    assert N2 == pytest.approx(dW2, rel=1e-7)


def test_zero_exponent_is_saint_venant_kirchhoff_exactly():
    for E1, E2 in [(0.02, 0.01), (-0.05, 0.3)]:
        N1, N2 = fung_resultants(E1, E2, EBAR, NU, 0.0)
        assert N1 == EBAR * (E1 + NU * E2)
        assert N2 == EBAR * (E2 + NU * E1)


def test_small_strain_limit_recovers_E0_and_nu():
    """Uniaxial stress (N2 = 0) at small strain: N1 / E1 = E0 h, E2 / E1 = -nu."""
    E0, h, nu, k = 0.5e6, 0.5e-3, 0.5, 10.0
    Ebar = E0 * h / (1 - nu ** 2)
    E1 = 1e-6
    E2 = -nu * E1  # N2 = Ebar e^Q (E2 + nu E1) vanishes here
    N1, N2 = fung_resultants(E1, E2, Ebar, nu, k)
    assert abs(N2) < 1e-9 * abs(N1)
    assert N1 / E1 == pytest.approx(E0 * h, rel=1e-6)


@pytest.mark.parametrize("k", [0.0, 1.0, 100.0])
def test_prestretch_satisfies_laplace(k):
    p0, R = 16 * 133.322, 7e-3
    lam = prestretch(p0, R, EBAR, NU, k)
    assert equibiaxial_tension(lam, EBAR, NU, k) == pytest.approx(p0 * R / 2, rel=1e-10)
    assert lam > 1.0


def test_internal_forces_are_minus_energy_gradient():
    phi = np.linspace(0, math.radians(60), 12)
    m = build_membrane(phi, 7e-3, 2133.0, 0.5e6, 0.5e-3, 0.5, 3.0, 1000.0)
    rng = np.random.default_rng(3)
    X = 1.01 * 7e-3 * np.sin(phi) + rng.uniform(-1e-5, 1e-5, phi.size)
    Y = 1.01 * 7e-3 * np.cos(phi) + rng.uniform(-1e-5, 1e-5, phi.size)
    X[0] = 0.0

    def Pi(X, Y):
        dx, dy = np.diff(X), np.diff(Y)
        E1 = 0.5 * ((dx ** 2 + dy ** 2) / m.L0 ** 2 - 1)
        E2 = 0.5 * (((X[:-1] + X[1:]) / m.S0) ** 2 - 1)
        return sum(a * energy(e1, e2, m.Ebar, m.nu, m.k) for a, e1, e2 in zip(m.A0, E1, E2))

    Fx, Fy = np.empty_like(X), np.empty_like(Y)
    internal_forces(X, Y, m.L0, m.S0, m.A0, m.Ebar, m.nu, m.k, Fx, Fy)
    eps = 1e-10
    for i in range(1, phi.size):
        for arr, F in ((X, Fx), (Y, Fy)):
            arr[i] += eps
            up = Pi(X, Y)
            arr[i] -= 2 * eps
            down = Pi(X, Y)
            arr[i] += eps
            assert -(up - down) / (2 * eps) == pytest.approx(F[i], rel=1e-5, abs=1e-9 * abs(F).max())


@pytest.mark.parametrize("resolution", ["coarse", "paper"])
def test_discrete_rest_state_has_the_drawn_curvature(resolution):
    """Lumped loads: the exact discrete equilibrium under IOP stays on the drawn arc to O(h^2),
    and its apical curvature (fitted over a fixed radius) is 1/R."""
    model = CoupledModel(RunParams(resolution=resolution, pmax=0.0))
    R = 7e-3
    assert model.equilibrium_residual < 1e-9
    assert apex_curvature(model.X, model.Y, apex_fit_nodes(model.X)) == pytest.approx(1 / R, rel=1e-3)
    h = model.chamber.h.min()
    assert model.rest_shape_deviation < 0.01 * h


@pytest.mark.parametrize("resolution", ["coarse", "paper", "fine"])
def test_apex_fit_has_the_same_form_at_every_resolution(resolution):
    """The applanation measure is one quantity at every resolution: an even quartic over the same
    physical radius (>= 3 nodes), exact on any even quartic profile, and within O(R_fit^4) of the
    apex curvature of a sphere."""
    from airpuff_core.geometry import build_chamber
    from airpuff_core.cornea.apex import APEX_FIT_RADIUS
    p = RunParams(resolution=resolution).si()
    ch = build_chamber("sector", "isotropic", resolution, p.R_m, p.r_post_m, p.alpha0_rad)
    X = p.R_m * np.sin(ch.phi_cornea)
    n_fit = apex_fit_nodes(X)
    assert n_fit >= 3
    assert X[n_fit - 1] <= APEX_FIT_RADIUS * (1 + 1e-9) < X[n_fit]
    # an even quartic dimple: y = y0 - kappa x^2 / 2 + c4 x^4 (kappa of either sign)
    for kappa, c4 in ((142.0, 3e6), (-55.0, -8e6), (0.0, 5e7)):
        Y = 6.9e-3 - 0.5 * kappa * X ** 2 + c4 * X ** 4
        assert apex_curvature(X, Y, n_fit) == pytest.approx(kappa, abs=1e-9 * 142.0)
    # a sphere of radius R: the x^6 term is the only error, (R_fit / R)^4 / 8 relative
    R = 7e-3
    Y = np.sqrt(R ** 2 - X ** 2)
    assert apex_curvature(X, Y, n_fit) == pytest.approx(1 / R, rel=(0.6 / 7) ** 4 / 8 * 1.5)
