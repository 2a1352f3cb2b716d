"""Viscoelasticity in the shell cornea: the kernel's total resultants relax as G(t) after a strain
step, g = 0 is the elastic law bit for bit, the relaxed rest state stays still, and the energy
budget of a full coarse run closes.

Reference values: the relaxation function G(t) = 1 - g (1 - exp(-t/tau)) and the equilibrium-law
resultants of the two states, computed by the kernels' elastic path (mode 0)."""

import math

import numpy as np
import pytest

from airpuff_core import RunParams, simulate
from airpuff_core.cornea.build import build_shell
from airpuff_core.cornea.tissue import NO_HISTORY, ViscoelasticTissue
from airpuff_core.kernels.shell import shell_internal_forces, shell_work, work_rows
from airpuff_core.kernels.viscoelastic import relaxation_function
from airpuff_core.params import SWEPT
from api import sweep_form
from api.schemas import sweep_request_model
from sweep.grid import SweepSpec

P0 = 16 * 133.322  # Pa
R = 7e-3  # m


def _shell(n=14):
    phi = np.linspace(0.0, math.radians(60.0), n)
    return build_shell(phi, R, P0, 0.5e6, 0.5e-3, 0.5, 240.0, 1000.0, "clamped")


def _resultants(m, X, Y, mode=0, history=NO_HISTORY):
    """Total N1, N2 (per segment) and M_s, M_theta (per node) after one kernel evaluation."""
    work = shell_work(m.n)
    Fx, Fy = np.empty(m.n), np.empty(m.n)
    shell_internal_forces(X, Y, m.L0, m.S0, m.A0, *m.bending_args(), m.Ebar, m.nu, m.k, m.D,
                          work, Fx, Fy, mode, *history)
    _, _, _, N1, N2, _, _, _, Ms, Mt = work_rows(work, m.n)
    return np.concatenate((N1, N2, Ms, Mt)), (Fx, Fy)


def _rest_and_step(m):
    X0, Y0 = m.R_ref * np.sin(m.phi), m.R_ref * np.cos(m.phi)
    X1, Y1 = 1.002 * X0, 1.002 * Y0  # stretched ...
    Y1[3] -= 2e-5  # ... and bent
    return X0, Y0, X1, Y1


def test_strain_step_relaxes_as_G_in_the_shell_kernel():
    """Membrane forces and bending moments of a shell held after a step of strain (applied within
    1 ns) follow S(t) = S_eq0 + (S_eq1 - S_eq0) G(t) / G_inf, to 1e-6 of the step."""
    m = _shell()
    g, tau = 0.3, 10e-3
    X0, Y0, X1, Y1 = _rest_and_step(m)
    history = ViscoelasticTissue(m, [g], [tau], X0, Y0)
    s_eq0, _ = _resultants(m, X0, Y0)
    s_eq1, _ = _resultants(m, X1, Y1)
    step = s_eq1 - s_eq0
    rng = np.random.default_rng(4)
    times, t = [], 0.0
    for dt in np.concatenate(([1e-9], rng.uniform(0.05e-3, 3e-3, 25))):
        history.set_substep(dt)
        trial = history.begin_trial()
        total, _ = _resultants(m, X1, Y1, 2, trial)
        history.commit()
        t += dt
        expected = s_eq0 + step * relaxation_function(t, [g], [tau]) / (1.0 - g)
        assert np.max(np.abs(total - expected)) < 1e-6 * np.max(np.abs(step)), t
        times.append(t)
    assert times[-1] > 3 * tau  # relaxed well past tau
    assert np.max(np.abs(step[-2 * m.n:])) > 0  # the step bends the shell too


def test_zero_g_is_the_elastic_law_bit_for_bit():
    m = _shell()
    X0, Y0, X1, Y1 = _rest_and_step(m)
    history = ViscoelasticTissue(m, [0.0], [10e-3], X0, Y0)
    history.set_substep(1e-5)
    _, (Fx_e, Fy_e) = _resultants(m, X1, Y1)
    _, (Fx_v, Fy_v) = _resultants(m, X1, Y1, 2, history.begin_trial())
    assert np.array_equal(Fx_e, Fx_v) and np.array_equal(Fy_e, Fy_v)


def test_relaxed_rest_state_stays_still():
    """E0 is the equilibrium modulus: the clinical preset at rest (pmax = 0) does not move."""
    result = simulate(RunParams(model="clinical", pmax=0.0, t_end=3.0))
    assert np.max(np.abs(result.histories["apex_displacement"])) < 1e-9  # mm
    assert np.max(np.abs(result.histories["tissue_dissipation"])) < 1e-9  # uJ


def test_energy_budget_of_a_full_run_closes():
    """The clinical preset with the Kirchhoff shell, full coarse run: jet work = kinetic + stored
    + dissipated + globe work within 2 % of the largest work the jet has done, at every output
    time; the tissue dissipates (positive, and most of the net work the jet leaves behind).  The
    shear-deformable shell's budget: tests/core/test_mindlin.py."""
    h = simulate(RunParams(model="clinical", transverse_shear_modulus=0.0)).histories
    w_max = np.max(np.abs(h["jet_work"]))
    assert w_max > 1.0  # uJ
    assert np.max(np.abs(h["energy_residual"])) < 0.02 * w_max
    assert h["tissue_dissipation"][-1] > 0.5 * h["jet_work"][-1] > 0
    assert np.min(h["tissue_dissipation"]) > -1e-3 * w_max


def test_clinical_preset_and_explicit_options():
    """The clinical preset sets the shell, the compliant globe and the fitted viscoelastic
    parameters (clinical_published Kling et al.'s); explicit options override it, also through the HTTP request model and the
    browser's form (whose omitted preset parameters stay None, so that the preset fills them)."""
    p = RunParams(model="clinical")
    assert (p.cornea, p.globe, p.ve_g, p.ve_tau) == ("mindlin", "compliant", 0.58, 10.0)
    published = RunParams(model="clinical_published")
    assert (published.ve_g, published.transverse_shear_modulus) == (0.3, 9.48)
    paper = RunParams()
    assert (paper.cornea, paper.globe, paper.ve_g) == ("membrane", "rigid", 0.0)
    assert RunParams(model="clinical", ve_g=0.1).ve_g == 0.1
    assert RunParams(model="clinical").replace(model="paper").ve_g == 0.0
    body = sweep_request_model(10)(E0=[0.5], IOP=[16.0], model="clinical", globe="rigid")
    values = body.model_dump()
    values.pop("retry_failed", None)  # a job option, not a run's (as api/routes.py does)
    axes = {k: values.pop(k) for k in SWEPT}
    point = SweepSpec(**axes, options=values).validate().validated_points()[0]
    assert (point.cornea, point.globe, point.ve_g, point.ve_tau) == ("mindlin", "rigid", 0.58,
                                                                     10.0)
    # the browser's sweep form leaves the preset's fields empty, so the preset fills them
    form = {**sweep_form.defaults(), "model": "clinical", "E0": "0.5", "IOP": "16"}
    body, errors = sweep_form.request_from_form(form, 10)
    assert not errors and not {"cornea", "globe", "ve_g", "ve_tau"} & set(body)
    values = sweep_request_model(10)(**body).model_dump()
    values.pop("retry_failed", None)
    axes = {k: values.pop(k) for k in SWEPT}
    point = SweepSpec(**axes, options=values).validate().validated_points()[0]
    assert (point.cornea, point.globe, point.ve_g) == ("mindlin", "compliant", 0.58)


def test_apex_moment_is_the_bending_law_at_the_apex():
    """M_s at the apex = D (1 + nu) K with K = 2 (psi_0 - psi_ref_0) / L0_0 (symmetry: K_s =
    K_theta there), plus the stored overstresses; 0 on the homothetic rest shape."""
    m = _shell()
    X0, Y0 = m.R_ref * np.sin(m.phi), m.R_ref * np.cos(m.phi)
    assert abs(m.apex_moment(1.01 * X0, 1.01 * Y0)) < 1e-12 * m.D / m.R_ref
    Y1 = Y0.copy()
    Y1[0] -= 1e-5  # flatten the apex
    psi0 = math.atan2(Y1[0] - Y1[1], X0[1] - X0[0])
    K = 2.0 * (psi0 - m.psi_ref[0]) / m.dual_length[0]
    assert m.apex_moment(X0, Y1) == pytest.approx(m.D * (1 + m.nu) * K, rel=1e-12)
    q = np.zeros((2, 4, m.n))
    q[:, 2, 0] = (1e-4, 2e-4)
    assert m.apex_moment(X0, Y1, q) == pytest.approx(m.D * (1 + m.nu) * K + 3e-4, rel=1e-12)
