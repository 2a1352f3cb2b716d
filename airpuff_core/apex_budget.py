"""The apex force budget of a coupled model's state: what carries the jet at the apex (SI)."""

from __future__ import annotations

import numpy as np

from .kernels.membrane import region_pressure_loads


def apex_budget(model):
    """The apex force budget [Pa] of the state of ``model`` (a ``CoupledModel``): over the nodes
    of the apex fit (``apex_fit_nodes``) the balance of the cornea's nodes in the load direction,

        sum m_i a_i = sum F_eq,i + sum F_ve,i + sum a_p,i (p_fluid,i - p_jet,i),

    divided by a = sum a_p,i (a_p,i: the lumped outward area of node i's pressure load,
    ``add_pressure_loads``), read as the jet pressure that the apex carries:

        p_jet = p_fluid + F_eq / a + F_ve / a - m a / a.

    Returns (p_jet, p_fluid, equilibrium, overstress, inertia): the area-weighted jet and fluid
    pressures (the IOP included), the equilibrium law's resistance (its internal forces: minus
    the IOP's membrane tension plus bending and shear), the tissue's overstress' and minus the
    nodes' inertia, their acceleration that of the last step."""
    n_fit = model.n_apex_fit
    region = slice(0, n_fit)
    X, Y = model.X, model.Y
    cornea, tissue = model.cornea, model.tissue
    jet = np.empty_like(X)
    model.jet.pressures(model.t, model.chamber.phi_cornea, jet)
    area, fluid, jet_mean = region_pressure_loads(X, Y, model.p_interface, jet, n_fit)
    fluid /= area
    jet_mean /= area
    equilibrium = float(cornea.internal_forces(X, Y)[1][region].sum()) / area
    overstress = 0.0
    if tissue.viscoelastic:  # the elastic tissue adds none (skips a force evaluation)
        total = cornea.internal_forces(X, Y, tissue.stored_history())[1]
        overstress = float(total[region].sum()) / area - equilibrium
    inertia = -float(np.dot(cornea.mass[region], model.apex_acceleration)) / area
    return jet_mean, fluid, equilibrium, overstress, inertia
