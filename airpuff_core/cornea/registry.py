"""The cornea models a run can choose (``cornea``) and the options each one reads.

This module is the catalogue, light enough for the parameter table to read (it imports no
kernel): a model's name, the cornea-specific options it uses and one line on what it is.  The
classes themselves are found by ``cornea.build.cornea_for_run``; each names itself in its
``name`` attribute.  A new cornea model is a module in ``cornea/`` with its class, an entry here
and its class in ``build.MODELS``.

The options ``CORNEA_OPTIONS`` mean something only for some models (a membrane has no bending,
so no limbus condition and no transverse shear).  An option a model does not use is refused when
it is given with a value other than its neutral one (``ParameterError``), and set to that
neutral value when it came from a ``model`` preset (``resolve_options``).

The older spelling ``shell`` is the shell of the transverse shear modulus: ``mindlin`` when
``transverse_shear_modulus > 0``, ``kirchhoff`` when it is 0.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import ParameterError

# the cornea-specific options and their neutral value (what a model that does not use them has)
CORNEA_OPTIONS = {"transverse_shear_modulus": 0.0, "limbus": "clamped"}
LEGACY_SHELL = "shell"


@dataclass(frozen=True)
class CorneaEntry:
    """A cornea model of the catalogue: its ``cornea`` name, the options of ``CORNEA_OPTIONS``
    it reads, and a description."""

    name: str
    options: tuple[str, ...]
    description: str


CORNEAS: dict[str, CorneaEntry] = {e.name: e for e in [
    CorneaEntry("membrane", (), "the paper's Fung membrane (no bending rigidity)"),
    CorneaEntry("kirchhoff", ("limbus",),
                "Kirchhoff-Love shell: the membrane with bending rigidity D = E0 h^3/(12 (1 - "
                "nu^2)), large rotations, rigid in transverse shear"),
    CorneaEntry("mindlin", ("limbus", "transverse_shear_modulus"),
                "shear-deformable (Reissner-Mindlin) shell: the Kirchhoff shell with directors and "
                "transverse shear stiffness 5/6 G_t h (transverse_shear_modulus > 0)"),
]}

# every spelling ``cornea`` accepts: the models' names and the older ``shell``
CORNEA_CHOICES = (*CORNEAS, LEGACY_SHELL)


def model_name(cornea: str, transverse_shear_modulus: float) -> str:
    """The registry's name for ``cornea``: the older ``shell`` becomes ``mindlin`` with a
    transverse shear modulus above 0 and ``kirchhoff`` with 0; a model's name stays."""
    if cornea == LEGACY_SHELL:
        return "mindlin" if transverse_shear_modulus > 0.0 else "kirchhoff"
    return cornea


def resolve_options(cornea: str, values: dict, from_preset: set, ranges: dict) -> dict:
    """The cornea-specific options of ``values`` (name -> value) for the model ``cornea``
    (a registry name): an option the model does not use keeps its neutral value; given
    explicitly with another value it is an error, taken from a preset it is set back to neutral
    (``from_preset``: the names whose value came from the ``model`` preset).  ``ranges``: the
    accepted range of each numeric option for the models that use it, in words.  Raises
    ParameterError."""
    entry = CORNEAS[cornea]
    resolved = dict(values)
    for name, neutral in CORNEA_OPTIONS.items():
        if name in entry.options or values[name] == neutral:
            continue
        if name in from_preset:
            resolved[name] = neutral
            continue
        users = [e.name for e in CORNEAS.values() if name in e.options]
        raise ParameterError(name, values[name],
                             f"{neutral!r} with cornea {cornea} (it has no {name.replace('_', ' ')}"
                             f"; {ranges.get(name, 'other values')} with cornea "
                             f"{' or '.join(users)})")
    if ("transverse_shear_modulus" in entry.options
            and not resolved["transverse_shear_modulus"] > 0.0):
        raise ParameterError("transverse_shear_modulus", resolved["transverse_shear_modulus"],
                             f"{ranges['transverse_shear_modulus']} with cornea {cornea} (cornea "
                             f"kirchhoff is the shell rigid in transverse shear)")
    return resolved
