"""The fluid's compression energy (airpuff_core/kernels/energy.py): e(rho) against the integral
of p / rho^2 it stands for, and its change at a new sound speed (``compression_energy_change``,
the energy budget's W_c) against the two energies it replaces, bit for bit."""

import numpy as np
import pytest
from scipy.integrate import quad

from airpuff_core.kernels.energy import compression_energy, compression_energy_change

RHO0, P0, GAMMA = 1000.0, 2133.0, 7.0  # kg/m^3, Pa (16 mmHg), Tait exponent


def tait_pressure(rho, c):
    """Eq. (5): p = p0 + B ((rho / rho0)^gamma - 1), B = rho0 c^2 / gamma [Pa]."""
    return P0 + RHO0 * c * c / GAMMA * ((rho / RHO0) ** GAMMA - 1.0)


def fluid_state(n=1104, seed=3):
    rng = np.random.default_rng(seed)
    mass = rng.uniform(1e-9, 3e-9, n)  # kg
    rho = RHO0 * (1.0 + 1e-3 * rng.standard_normal(n))
    return mass, rho


def test_the_compression_energy_is_the_integral_of_p_over_rho_squared():
    mass, rho = fluid_state(n=5)
    c = 12.0
    expected = sum(m * quad(lambda r: tait_pressure(r, c) / r ** 2, RHO0, r_i,
                            epsabs=0.0, epsrel=1e-12)[0] for m, r_i in zip(mass, rho))
    assert compression_energy(mass, rho, RHO0, P0, c, GAMMA) == pytest.approx(expected,
                                                                              rel=1e-8)


@pytest.mark.parametrize("c_old, c_new", [(10.0, 10.5), (10.0, 40.0), (25.0, 12.0)])
def test_the_change_at_a_new_sound_speed_is_the_two_energies_difference_bit_for_bit(c_old,
                                                                                     c_new):
    mass, rho = fluid_state()
    two_passes = (compression_energy(mass, rho, RHO0, P0, c_new, GAMMA)
                  - compression_energy(mass, rho, RHO0, P0, c_old, GAMMA))
    assert compression_energy_change(mass, rho, RHO0, P0, c_old, c_new, GAMMA) == two_passes
    assert two_passes != 0.0
