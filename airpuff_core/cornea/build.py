"""The cornea models behind the registry's names, and the cornea of a run.

``cornea_for_run`` is how the rest of the package gets a cornea: by the name ``params.cornea``
(``registry.CORNEAS``), never by a class.  ``build_shell`` and ``shell_on_meridian`` make a
model from material constants directly, for the checks of the mechanics against analytic values.
"""

from __future__ import annotations

import math

import numpy as np

from .interface import CorneaModel
from .kirchhoff import KirchhoffShell, bending_reference, plate_rigidity, shell_fields
from .membrane import Membrane
from .mindlin import MindlinShell
from .reference import MembraneModel, build_membrane

MODELS: dict[str, type] = {cls.name: cls for cls in (Membrane, KirchhoffShell, MindlinShell)}


def cornea_for_run(params, phi) -> CorneaModel:
    """The cornea of a run (``RunParams`` ``params``, its ``cornea`` a registry name) on the
    reference angles ``phi`` [rad] of its nodes, apex first."""
    return MODELS[params.cornea].for_run(params.si(), params.limbus, phi)


def build_shell(phi, R, p0, E0, h, nu, k, rho_c, limbus="clamped", bending=True,
                transverse_shear_modulus=0.0) -> CorneaModel:
    """Cornea on reference angles ``phi`` (apex first), prestressed by p0 [Pa] on the drawn arc of
    radius R [m] (SI material constants): the membrane when not ``bending``, else the
    Kirchhoff shell, or the shear-deformable one for ``transverse_shear_modulus`` G_t [Pa] > 0."""
    membrane = build_membrane(phi, R, p0, E0, h, nu, k, rho_c)
    X_ref = membrane.R_ref * np.sin(phi)
    Y_ref = membrane.R_ref * np.cos(phi)
    if not bending:
        return Membrane(**shell_fields(membrane, X_ref, Y_ref, 0.0, limbus))
    return _with_bending(membrane, X_ref, Y_ref, plate_rigidity(E0, h, nu), limbus,
                         transverse_shear_modulus, h)


def shell_on_meridian(X_ref, Y_ref, E0, h, nu, k, rho_c, limbus="clamped",
                      transverse_shear_modulus=0.0) -> CorneaModel:
    """Shell whose stress-free reference is the meridian polyline (X_ref, Y_ref) [m], apex first
    (e.g. a flat plate), without prestress: chords L0, hoop sums S0 = x_a + x_b, conical zone
    areas A0 = pi (x_a + x_b) L0, lumped masses rho_c h A_i; shear-deformable when
    ``transverse_shear_modulus`` G_t [Pa] > 0."""
    X_ref = np.asarray(X_ref, dtype=float)
    Y_ref = np.asarray(Y_ref, dtype=float)
    L0 = np.hypot(np.diff(X_ref), np.diff(Y_ref))
    S0 = X_ref[:-1] + X_ref[1:]
    A0 = math.pi * S0 * L0
    _, _, _, area = bending_reference(X_ref, Y_ref)
    Ebar = E0 * h / (1.0 - nu * nu)
    membrane = MembraneModel(np.full(X_ref.shape, np.nan), math.nan, 1.0, L0, S0, A0,
                             rho_c * h * area, Ebar, nu, k, rho_c * h)
    return _with_bending(membrane, X_ref, Y_ref, plate_rigidity(E0, h, nu), limbus,
                         transverse_shear_modulus, h)


def _with_bending(membrane, X_ref, Y_ref, D, limbus, G_t, h) -> CorneaModel:
    if G_t <= 0.0:
        return KirchhoffShell(**shell_fields(membrane, X_ref, Y_ref, D, limbus))
    return MindlinShell.on_reference(membrane, X_ref, Y_ref, D, limbus, G_t, h)
