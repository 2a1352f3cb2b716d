"""The energy budget of a run: where the jet's work goes (SI inside, microjoules in the histories).

Cumulative from t = 0, with gauge pressures (kernels/energy.py):

    W_jet = dK + dE + D_tissue + D_fluid + W_globe - W_c + residual

- W_jet: work of the air jet on the cornea (its lumped loads, trapezoidal rule over each step);
- dK: change of kinetic energy, cornea (with its directors' rotation) plus fluid;
- dE: change of stored energy: the cornea's strain energy (membrane, bending and transverse
  shear, of the equilibrium law), the energy stored in its viscoelastic overstresses, and the
  fluid's compression energy;
- D_tissue: viscoelastic dissipation, the work of the overstresses q minus the energy they store,
  int q . dE - Psi, with Psi = sum_i G_inf / (2 g_i) q_i . C^-1 q_i and C the tangent of the
  equilibrium law at rest (exact for a law linear about the rest state, Simo and Hughes 1998,
  section 10.3; here the Fung membrane law is linearised at its prestrain);
- D_fluid: energy removed by the physical viscosity and by the stabilising hyperviscosity;
- W_globe: work of the fluid on the compliant walls (stored in the globe);
- W_c: energy the running-maximum sound speed adds when it raises c at fixed density;
- residual: what the discretisation does not conserve (the time integrators and the coupling).

The residual, relative to the largest work the jet has done, measures how well the budget
closes (docs/model.md, "Energy budget").
"""

from __future__ import annotations

import numpy as np

from .kernels.energy import (compression_energy, fluid_dissipation_power, kinetic_energy,
                             pressure_load_work)

UJ = 1e-6  # J per microjoule


class EnergyBudget:
    """Cumulative budget of one run; ``account_step`` after the coupling of every step (with the
    state at t^n still in the model and the trial state at t^{n+1} passed in), ``terms`` for the
    histories."""

    def __init__(self, cornea, viscoelastic, mass, rho0, p0, gamma):
        self.cornea = cornea  # cornea mechanics: kinetic_energy(VX, VY), energy(X, Y)
        self.viscoelastic = viscoelastic  # its ViscoelasticHistory, or None
        self.mass = mass
        self.rho0, self.p0, self.gamma = rho0, p0, gamma
        self._loads = None
        self.jet_work = 0.0
        self.overstress_work = 0.0
        self.fluid_viscous = 0.0
        self.fluid_hyperviscous = 0.0
        self.globe_work = 0.0
        self.sound_speed_work = 0.0
        self._reference = None

    def _stored(self, X, Y, VX, VY, vx, vy, rho, c, history):
        cornea = self.cornea
        membrane, bending = cornea.energy(X, Y)  # bending includes the transverse shear
        kinetic = cornea.kinetic_energy(VX, VY) + kinetic_energy(self.mass, vx, vy)
        elastic = membrane + bending + compression_energy(self.mass, rho, self.rho0, self.p0, c,
                                                          self.gamma)
        ve = self.viscoelastic
        ve_stored = ve.stored_energy(history) if ve is not None else 0.0
        return kinetic, elastic, ve_stored

    def start(self, X, Y, VX, VY, vx, vy, rho, c, history):
        """The reference state at t = 0."""
        self._reference = self._stored(X, Y, VX, VY, vx, vy, rho, c, history)
        n = X.shape[0]
        self._loads = tuple(np.empty(n) for _ in range(4))

    def account_step(self, dt, jet_n, jet_new, X0, Y0, X1, Y1, history0, history1, kind, x,
                     vx0, vy0, vx1, vy1, dv0, rho_n, mu, hv_vx, hv_vy, hv_rho, p_n, c_old, c_new,
                     globe_work):
        """Add the work terms of one step of dt [s]: the jet's net pressures jet_n, jet_new on
        the cornea nodes at t^n and t^{n+1} [Pa], the cornea's positions X0 .. Y1 [m] and
        viscoelastic overstresses at both ends (ignored without viscoelasticity), the fluid's velocities at both ends, the velocity
        derivatives dv0 and density rho_n at t^n, the hyperviscous rates, the pressure p_n at t^n
        [Pa], the sound speeds of the last and this step [m/s], and the work on the walls [J].
        """
        # the jet presses from outside: its loads are those of the net inside pressure -p_jet
        self.jet_work -= pressure_load_work(X0, Y0, X1, Y1, jet_n, jet_new, *self._loads)
        if self.viscoelastic is not None:
            self.overstress_work += self.viscoelastic.overstress_work(X0, Y0, X1, Y1, history0,
                                                                     history1)
        visc, hyper = fluid_dissipation_power(kind, x, vx0, vy0, vx1, vy1, dv0[0], dv0[1], rho_n,
                                              mu, hv_vx, hv_vy, self.mass, p_n, hv_rho)
        self.fluid_viscous += visc * dt
        self.fluid_hyperviscous += hyper * dt
        self.globe_work += globe_work
        if c_new != c_old:
            self.sound_speed_work += (
                compression_energy(self.mass, rho_n, self.rho0, self.p0, c_new, self.gamma)
                - compression_energy(self.mass, rho_n, self.rho0, self.p0, c_old, self.gamma))

    def terms(self, X, Y, VX, VY, vx, vy, rho, c, history):
        """The budget's terms at the current state [uJ] (histories of the same names,
        ``result.HISTORIES``)."""
        kinetic, elastic, ve_stored = self._stored(X, Y, VX, VY, vx, vy, rho, c, history)
        k0, e0, v0 = self._reference
        d_kinetic = kinetic - k0
        d_elastic = elastic - e0 + ve_stored - v0
        tissue = self.overstress_work - (ve_stored - v0)
        fluid = self.fluid_viscous + self.fluid_hyperviscous
        residual = (self.jet_work - d_kinetic - d_elastic - tissue - fluid - self.globe_work
                    + self.sound_speed_work)
        return {
            "jet_work": self.jet_work / UJ,
            "kinetic_energy": d_kinetic / UJ,
            "elastic_energy": d_elastic / UJ,
            "tissue_dissipation": tissue / UJ,
            "fluid_dissipation": fluid / UJ,
            "globe_work": self.globe_work / UJ,
            "energy_residual": residual / UJ,
        }
