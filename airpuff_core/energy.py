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

from .kernels.energy import (compression_energy, compression_energy_change,
                             fluid_dissipation_power, kinetic_energy, pressure_load_work)

UJ = 1e-6  # J per microjoule


class EnergyBudget:
    """Cumulative budget of one run, an observer of its steps (``CoupledModel.step``):
    ``coupled`` adds the work terms of a step once it is coupled (the state at t^n still the
    model's, the one at t^{n+1} in its trial arrays), ``terms`` gives the histories' values."""

    def __init__(self, model):
        """The budget of ``model`` (a ``CoupledModel``) from its state at rest."""
        si = model.si
        self.cornea = model.cornea  # energy(X, Y), kinetic_energy(VX, VY)
        self.tissue = model.tissue  # stored_energy, overstress_work
        self.mass = model.fluid.mass
        self.rho0, self.p0, self.gamma, self.mu = si.rho_fluid, si.p0_Pa, si.tait_gamma, si.mu
        self.jet_work = 0.0
        self.overstress_work = 0.0
        self.fluid_viscous = 0.0
        self.fluid_hyperviscous = 0.0
        self.globe_work = 0.0
        self.sound_speed_work = 0.0
        n = model.X.shape[0]
        self._loads = tuple(np.empty(n) for _ in range(4))
        # the jet on the cornea at t^n and t^{n+1} [Pa]; the jet at t^{n+1} of one step is the
        # next step's at t^n (at time _jet_time [s])
        self._jet_new, self._jet_n = np.empty(n), np.empty(n)
        self._jet_time = np.nan
        self._p_n = np.empty(model.fluid.rho.shape[0])  # fluid pressure at t^n [Pa]
        self._c_last = model.c
        self._reference = self._stored(model)

    def _stored(self, model):
        """(kinetic, elastic, viscoelastic) energy [J] of the model's state."""
        fluid, c = model.fluid, model.c
        membrane, bending = self.cornea.energy(model.X, model.Y)  # bending with transverse shear
        kinetic = (self.cornea.kinetic_energy(model.VX, model.VY)
                   + kinetic_energy(self.mass, fluid.vx, fluid.vy))
        elastic = membrane + bending + compression_energy(self.mass, fluid.rho, self.rho0, self.p0,
                                                          c, self.gamma)
        return kinetic, elastic, self.tissue.stored_energy(self.tissue.overstress)

    def coupled(self, model, dt):
        """Add the work terms of the step of dt [s] just coupled: the jet's on the cornea
        (trapezoidal in its net pressures at both ends), the tissue's overstresses', the fluid's
        viscous and hyperviscous dissipation at t^n, the work on the globe's walls, and the
        energy a change of the sound speed puts into the compression."""
        fluid, c, t = model.fluid, model.c, model.t
        w = fluid.work
        X0, Y0 = model.X, model.Y
        X1, Y1 = model.trial_cornea[0], model.trial_cornea[1]
        phi = model.chamber.phi_cornea
        if self._jet_time != t:
            model.jet.pressures(t, phi, self._jet_n)
        else:
            self._jet_n, self._jet_new = self._jet_new, self._jet_n
        model.jet.pressures(t + dt, phi, self._jet_new)
        self._jet_time = t + dt
        p_n = self._p_n
        fluid.pressure(c, p_n)
        # the jet presses from outside: its loads are those of the net inside pressure -p_jet
        self.jet_work -= pressure_load_work(X0, Y0, X1, Y1, self._jet_n, self._jet_new,
                                            *self._loads)
        tissue = self.tissue
        self.overstress_work += tissue.overstress_work(X0, Y0, X1, Y1, tissue.overstress,
                                                       tissue.trial_overstress)
        visc, hyper = fluid_dissipation_power(fluid.kind, fluid.x, fluid.vx, fluid.vy,
                                              w["vx_new"], w["vy_new"], fluid.dv[0], fluid.dv[1],
                                              fluid.rho, self.mu, w["hv_vx"], w["hv_vy"],
                                              self.mass, p_n, w["hv_rho"])
        self.fluid_viscous += visc * dt
        self.fluid_hyperviscous += hyper * dt
        self.globe_work += model.globe.work(fluid.rho, w["rho_new"], c)
        if c != self._c_last:
            self.sound_speed_work += compression_energy_change(
                self.mass, fluid.rho, self.rho0, self.p0, self._c_last, c, self.gamma)
        self._c_last = c

    def committed(self, model, dt):
        """Nothing to add once the step is accepted."""

    def terms(self, model):
        """The budget's terms at the model's current state [uJ] (histories of the same names,
        ``result.HISTORIES``)."""
        kinetic, elastic, ve_stored = self._stored(model)
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
