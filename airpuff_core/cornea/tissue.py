"""The tissue law of the cornea, applied to any cornea model's resultants: elastic, or
viscoelastic with Prony terms (SI).

``ElasticTissue`` adds nothing.  ``ViscoelasticTissue`` holds the overstresses of each of the
model's resultants, which the cornea kernels update by Simo's recursion
(``kernels/viscoelastic.py``), through a run, and measures their energy for the budget
(``energy.py``).  E0 is the equilibrium modulus (docs/model.md, "Viscoelasticity"): the cornea
starts fully relaxed, with no overstress, and its rest state is the elastic model's.

The model declares its resultants (``resultant_rows``; ``history_strains`` gives them and their
strains) and the energy and work of the overstresses of the rows beyond the membrane's N1, N2
(``overstress_bending_energy``, ``add_overstress_bending_work``).  State at t^n (rows: N1, N2
per segment in the first n - 1 entries, then the model's others, e.g. M_s, M_theta per node of
the Kirchhoff shell, or per segment and the transverse shear force Q for the shear-deformable
one):

- ``previous`` (rows, n): the equilibrium-law resultants of the last evaluation;
- ``overstress`` (terms, rows, n): q_i, zero at rest;

and a trial copy that the coupling iterations advance from it (``begin_trial``) and that
becomes the state at t^{n+1} when the step is accepted (``commit``).

The stored energy of the overstresses, for a law linear about the rest state with tangent C, is
Psi = sum_i G_inf / (2 g_i) q_i . C^-1 q_i (the free energy of the Maxwell branches of the
generalised Maxwell model that the Prony series describes; Simo and Hughes, Computational
Inelasticity, 1998, section 10.3).  C is the tangent of the Fung membrane law at each segment's
rest strains, the bending law's D [[1, nu], [nu, 1]] and the shear stiffness S = kappa G_t h.
"""

from __future__ import annotations

import numpy as np

from ..kernels.viscoelastic import (membrane_overstress_energy, paired_overstress_work,
                                   prony_step_factors)

# the history arguments of the cornea kernels of an elastic cornea (not read; rows enough for the
# largest model's five resultants)
NO_HISTORY = (np.zeros((5, 1)), np.zeros((1, 5, 1)), np.ones(1), np.zeros(1))


def tissue_for_run(si, model, X_rest, Y_rest):
    """The tissue law of a run (``SIParams`` si): viscoelastic with the one Prony term (ve_g,
    ve_tau) when ve_g > 0, else elastic; ``model`` at rest at (X_rest, Y_rest) [m]."""
    if si.ve_g > 0.0:
        return ViscoelasticTissue(model, [si.ve_g], [si.ve_tau_s], X_rest, Y_rest)
    return ElasticTissue()


class ElasticTissue:
    """The elastic cornea: no history, no overstress, no stored or dissipated energy."""

    viscoelastic = False
    overstress = None  # the overstresses of the state (none)
    trial_overstress = None

    def set_substep(self, h):
        """Nothing to prepare for sub-steps of h [s]."""

    def begin_trial(self):
        """The history arguments of the cornea kernels (not read)."""
        return NO_HISTORY

    def stored_history(self):
        """(mode, history arguments) of the cornea's force kernels for the state: mode 0, the
        equilibrium law alone."""
        return (0, *NO_HISTORY)

    def commit(self):
        """No state to accept."""

    def stored_energy(self, overstress):
        return 0.0

    def overstress_work(self, X0, Y0, X1, Y1, overstress0, overstress1):
        return 0.0


class ViscoelasticTissue:
    """Prony terms g [1], tau [s] and the history of one cornea model's resultants."""

    viscoelastic = True

    def __init__(self, model, g, tau, X_rest, Y_rest):
        self.g = np.asarray(g, dtype=float)
        self.tau = np.asarray(tau, dtype=float)
        self.g_inf = 1.0 - float(self.g.sum())
        self.model = model
        n = model.n
        self.decay = np.ones(self.g.shape[0])
        self.weight = np.zeros(self.g.shape[0])
        self._work = model.history_work()
        self._work1 = model.history_work()
        # the strains of the trial state that ``overstress_work`` computed (in _work1, positions
        # (X1, Y1)); ``commit`` makes them the strains of the state at t^n (in _work), which the
        # next step's ``overstress_work`` then reads instead of computing them again
        self._trial_strains = None  # (X1, Y1, strains) of the last overstress_work, or None
        self._state_strains = None  # (X, Y, strains) of the committed state, or None
        # the relaxed rest state: previous = its equilibrium resultants, no overstress
        rows = model.resultant_rows
        self.previous = np.zeros((rows, n))
        self.overstress = np.zeros((self.g.shape[0], rows, n))
        (E1, E2, *_), resultants = model.history_strains(X_rest, Y_rest, self._work)
        for row, values in enumerate(resultants):
            self.previous[row, :values.shape[0]] = values
        self._membrane_compliance = self._rest_compliance(E1, E2)
        self._trial = (np.empty_like(self.previous), np.empty_like(self.overstress))

    def _rest_compliance(self, E1, E2):
        """(c11, c12, c22) per segment: the inverse of the Fung law's tangent d(N1, N2)/d(E1, E2)
        at the rest strains [m/N]."""
        m = self.model
        a = E1 + m.nu * E2
        b = E2 + m.nu * E1
        eQ = m.Ebar * np.exp(m.k * (E1 * E1 + E2 * E2 + 2.0 * m.nu * E1 * E2))
        t11 = eQ * (1.0 + 2.0 * m.k * a * a)
        t12 = eQ * (m.nu + 2.0 * m.k * a * b)
        t22 = eQ * (1.0 + 2.0 * m.k * b * b)
        det = t11 * t22 - t12 * t12
        return t22 / det, -t12 / det, t11 / det

    def set_substep(self, h):
        """The factors of Simo's update for Verlet sub-steps of h [s]."""
        prony_step_factors(h, self.g, self.tau, self.decay, self.weight)

    def begin_trial(self):
        """A fresh trial history from the state at t^n: the arguments (previous, overstress,
        decay, weight) of the shell kernels, which advance it in place."""
        previous, overstress = self._trial
        previous[:] = self.previous
        overstress[:] = self.overstress
        return previous, overstress, self.decay, self.weight

    @property
    def trial_overstress(self):
        return self._trial[1]

    def stored_history(self):
        """(mode, history arguments) of the cornea's force kernels for the state: mode 1, the
        stored overstresses added to the equilibrium law (no update)."""
        return (1, self.previous, self.overstress, self.decay, self.weight)

    def commit(self):
        """The trial history becomes the state (buffers swapped, not copied), and the trial
        state's strains (if ``overstress_work`` computed them) the state's."""
        committed = (self.previous, self.overstress)
        self.previous, self.overstress = self._trial
        self._trial = committed
        self._state_strains = self._trial_strains
        self._trial_strains = None
        if self._state_strains is not None:
            self._work, self._work1 = self._work1, self._work

    def stored_energy(self, overstress):
        """Psi [J] of the overstresses (module docstring)."""
        m = self.model
        n = m.n
        c11, c12, c22 = self._membrane_compliance
        energy = 0.0
        for i in range(self.g.shape[0]):
            qN1, qN2 = overstress[i, 0, :n - 1], overstress[i, 1, :n - 1]
            membrane = membrane_overstress_energy(m.A0, c11, c12, c22, qN1, qN2)
            bending = m.overstress_bending_energy(overstress[i])
            energy += self.g_inf / (2.0 * self.g[i]) * (membrane + bending)
        return float(energy)

    def overstress_work(self, X0, Y0, X1, Y1, overstress0, overstress1):
        """int q . dE over one step [J], trapezoidal: the mean total overstress of the two ends
        times the change of the strains (membrane per segment on A0, bending on the moments'
        areas, transverse shear per segment on A0).  (X0, Y0) is the state at the start of the
        step, (X1, Y1) the trial state at its end (with the cornea's trial directors)."""
        m = self.model
        n = m.n
        state = self._state_strains
        if state is not None and state[0] is X0 and state[1] is Y0:
            # the state is the last step's trial state, whose strains the last call computed
            E1a, E2a, *bend_a = state[2]
        else:
            (E1a, E2a, *bend_a), _ = m.history_strains(X0, Y0, self._work)
        strains_b, _ = m.history_strains(X1, Y1, self._work1, trial=True)
        self._trial_strains = (X1, Y1, strains_b)
        E1b, E2b, *bend_b = strains_b
        q = 0.5 * (overstress0.sum(axis=0) + overstress1.sum(axis=0))
        work = paired_overstress_work(m.A0, q[0, :n - 1], q[1, :n - 1], E1b, E1a, E2b, E2a)
        work = m.add_overstress_bending_work(work, q, bend_a, bend_b)
        return float(work)
