"""The cornea registry: its names are the choices of ``cornea``, the older ``shell`` maps by the
transverse shear modulus, every model implements the one interface, and options a model does
not use are refused when given and dropped when a preset set them."""

import math

import numpy as np
import pytest

from airpuff_core import ParameterError, RunParams
from airpuff_core.cornea.build import MODELS, cornea_for_run
from airpuff_core.cornea.interface import CorneaModel
from airpuff_core.cornea.registry import CORNEAS, model_name
from airpuff_core.cornea.tissue import ElasticTissue, ViscoelasticTissue, tissue_for_run
from airpuff_core.params import CHOICES


def test_the_registry_names_are_the_choices_of_cornea():
    assert tuple(CORNEAS) == ("membrane", "kirchhoff", "mindlin")
    assert CHOICES["cornea"] == ("membrane", "kirchhoff", "mindlin", "shell")
    assert list(MODELS) == list(CORNEAS)
    assert all(cls.name == name for name, cls in MODELS.items())


def test_the_older_spelling_shell_is_the_shell_of_its_shear_modulus():
    assert model_name("shell", 0.0) == "kirchhoff"
    assert model_name("shell", 9.48) == "mindlin"
    assert model_name("membrane", 9.48) == "membrane"
    assert RunParams(cornea="shell").cornea == "kirchhoff"
    assert RunParams(cornea="shell", transverse_shear_modulus=5.0).cornea == "mindlin"
    assert RunParams(model="clinical").cornea == "mindlin"
    assert RunParams(model="clinical", transverse_shear_modulus=0).cornea == "kirchhoff"


@pytest.mark.parametrize("options,name,accepted", [
    ({"cornea": "membrane", "transverse_shear_modulus": 5.0}, "transverse_shear_modulus",
     r"0\.0 with cornea membrane"),
    ({"cornea": "kirchhoff", "transverse_shear_modulus": 5.0}, "transverse_shear_modulus",
     r"0\.0 with cornea kirchhoff \(it has no transverse shear modulus; a number in "
     r"\(0, 100000\] kPa with cornea mindlin\)"),
    ({"transverse_shear_modulus": 5.0}, "transverse_shear_modulus",  # the paper's membrane
     r"with cornea membrane"),
    ({"cornea": "mindlin"}, "transverse_shear_modulus",  # the paper preset's G_t = 0
     r"a number in \(0, 100000\] kPa with cornea mindlin \(cornea kirchhoff"),
    ({"cornea": "mindlin", "transverse_shear_modulus": 0.0}, "transverse_shear_modulus",
     r"\(0, 100000\] kPa with cornea mindlin"),
    ({"cornea": "membrane", "limbus": "pinned"}, "limbus",
     r"'clamped' with cornea membrane .*with cornea kirchhoff or mindlin"),
])
def test_options_a_cornea_does_not_use_are_refused_naming_the_parameter(options, name, accepted):
    with pytest.raises(ParameterError, match=rf"^invalid {name}=.*accepted .*{accepted}") as err:
        RunParams(**options)
    assert err.value.name == name and "\n" not in str(err.value)


def test_a_preset_value_that_does_not_apply_to_the_chosen_cornea_is_dropped():
    for cornea in ("membrane", "kirchhoff"):
        p = RunParams(model="clinical", cornea=cornea)
        assert (p.cornea, p.transverse_shear_modulus) == (cornea, 0.0)
        assert p.ve_g == 0.58  # the tissue law applies to any model
    assert RunParams(model="clinical", cornea="mindlin").transverse_shear_modulus == 12.33
    clinical = RunParams(model="clinical")
    assert clinical.replace(cornea="membrane").transverse_shear_modulus == 0.0
    assert clinical.replace(cornea="kirchhoff", limbus="pinned").limbus == "pinned"
    assert RunParams(model="clinical", limbus="pinned").limbus == "pinned"


@pytest.mark.parametrize("options", [{}, {"cornea": "kirchhoff"},
                                     {"cornea": "mindlin", "transverse_shear_modulus": 9.48}])
def test_every_model_implements_the_interface_and_reports_its_diagnostics(options):
    params = RunParams(**options)
    phi = np.linspace(0.0, math.radians(params.alpha0), 21)
    model = cornea_for_run(params, phi)
    assert isinstance(model, CorneaModel) and model.name == params.cornea
    d = model.diagnostics()
    si = params.si()
    # Laplace's law at the prestretch: the stress-free radius is R / lambda0
    assert d["R_ref_mm"] == pytest.approx(params.R / d["prestretch"], rel=1e-12)
    E0, h, nu = si.E0_Pa, si.thickness_m, si.nu
    expected_D = 0.0 if params.cornea == "membrane" else E0 * h ** 3 / (12 * (1 - nu * nu))
    assert d["bending_rigidity_N_m"] == pytest.approx(expected_D, rel=1e-14)
    assert model.resultant_rows == (5 if params.cornea == "mindlin" else 4)


def test_the_tissue_law_of_a_run():
    params = RunParams(model="clinical", cornea="membrane")
    phi = np.linspace(0.0, math.radians(params.alpha0), 21)
    model = cornea_for_run(params, phi)
    X, Y = model.R_ref * np.sin(phi), model.R_ref * np.cos(phi)
    tissue = tissue_for_run(params.si(), model, X, Y)
    assert isinstance(tissue, ViscoelasticTissue) and tissue.viscoelastic
    assert tissue.previous.shape == (model.resultant_rows, model.n)
    elastic = tissue_for_run(RunParams().si(), model, X, Y)
    assert isinstance(elastic, ElasticTissue) and not elastic.viscoelastic
    assert elastic.stored_energy(elastic.overstress) == 0.0
    assert elastic.overstress_work(X, Y, X, Y, None, None) == 0.0
