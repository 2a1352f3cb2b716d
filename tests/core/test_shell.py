"""Shell cornea (bending stiffness): forces against finite differences of an independently written
energy, D = 0 against the membrane, the clamped plate against p a^4 / (64 D), a self-equilibrated
load on a prestressed spherical cap against the linear shallow-shell solution (Hankel transform),
the stable sub-step against the eigenfrequencies, and the rest state."""

import math

import numpy as np
import pytest
import xarray as xr

from airpuff_core import ParameterError, RunParams, simulate
from airpuff_core.cornea.build import build_shell, shell_on_meridian
from airpuff_core.cornea.kirchhoff import plate_rigidity
from airpuff_core.cornea.reference import build_membrane, static_equilibrium
from airpuff_core.dataset import params_from_dataset, write_netcdf
from airpuff_core.loads.air_jet import AirJet
from airpuff_core.kernels.membrane import internal_forces

P0 = 16 * 133.322  # Pa
R = 7e-3  # m


def reference_membrane(m, X, Y):
    """(W_membrane per segment [J/m^2], segment angles psi [rad]) written out from the
    definitions (numpy, not the kernels): Green-Lagrange strains, the Fung law."""
    dx, dy = np.diff(X), np.diff(Y)
    E1 = 0.5 * ((dx ** 2 + dy ** 2) / m.L0 ** 2 - 1)
    E2 = 0.5 * (((X[:-1] + X[1:]) / m.S0) ** 2 - 1)
    quad = E1 ** 2 + E2 ** 2 + 2 * m.nu * E1 * E2
    W_m = 0.5 * m.Ebar * quad if m.k == 0 else 0.5 * m.Ebar / m.k * np.expm1(m.k * quad)
    return W_m, np.arctan2(-dy, dx)


def reference_energy(m, X, Y):
    """Pi = sum_s A0_s W_membrane + sum_i A_i W_bending, written out from the definitions
    (numpy, not the kernels): Fung membrane, Reissner bending strains, linear bending law."""
    W_m, psi = reference_membrane(m, X, Y)
    Xr = m.x_ref
    dpsi, dref = np.diff(psi), np.diff(m.psi_ref)
    l = m.dual_length
    Ks = np.zeros(m.n)
    Kt = np.zeros(m.n)
    Ks[0] = Kt[0] = 2 * (psi[0] - m.psi_ref[0]) / l[0]  # mirror segment at the apex
    Ks[1:-1] = (dpsi - dref) / l[1:-1]
    Kt[1:-1] = (np.sin(0.5 * (psi[:-1] + psi[1:]))
                - np.sin(0.5 * (m.psi_ref[:-1] + m.psi_ref[1:]))) / Xr[1:-1]
    if m.limbus == 1:  # clamped: the tangent at the limbus keeps its reference angle
        Ks[-1] = (m.psi_ref[-1] - psi[-1]) / l[-1]
    W_b = 0.5 * m.D * (Ks ** 2 + Kt ** 2 + 2 * m.nu * Ks * Kt)
    return float(np.sum(m.A0 * W_m)), float(np.sum(m.node_area * W_b))


def perturbed_arc(n, seed, amplitude=2e-5, angle=60.0):
    phi = np.linspace(0, math.radians(angle), n)
    rng = np.random.default_rng(seed)
    X = 1.01 * R * np.sin(phi) + rng.uniform(-amplitude, amplitude, n)
    Y = 1.01 * R * np.cos(phi) + rng.uniform(-amplitude, amplitude, n)
    X[0] = 0.0
    return phi, X, Y


@pytest.mark.parametrize("limbus", ["clamped", "pinned"])
@pytest.mark.parametrize("k", [0.0, 240.0])
def test_forces_are_minus_energy_gradient(limbus, k):
    phi, X, Y = perturbed_arc(12, 5)
    m = build_shell(phi, R, P0, 0.5e6, 0.5e-3, 0.5, k, 1000.0, limbus)
    assert m.energy(X, Y) == pytest.approx(reference_energy(m, X, Y), rel=1e-12)
    Fx, Fy = m.forces(X, Y, np.zeros(m.n))
    eps = 1e-9
    scale = max(np.abs(Fx).max(), np.abs(Fy).max())
    for i in range(1, m.n):
        for arr, F in ((X, Fx), (Y, Fy)):
            arr[i] += eps
            up = sum(reference_energy(m, X, Y))
            arr[i] -= 2 * eps
            down = sum(reference_energy(m, X, Y))
            arr[i] += eps
            assert -(up - down) / (2 * eps) == pytest.approx(F[i], rel=1e-5, abs=1e-7 * scale)


def test_bending_forces_are_minus_bending_energy_gradient_at_large_rotation():
    """A strongly bent state (the apex region pushed through, as after applanation): the bending
    part alone (k = 0, D large) still equals -dPi/dX."""
    phi = np.linspace(0, math.radians(60), 10)
    m = build_shell(phi, R, P0, 0.5e6, 1.0e-3, 0.3, 0.0, 1000.0)
    X = R * np.sin(phi)
    Y = R * np.cos(phi) - 2e-3 * np.exp(-(X / 1.5e-3) ** 2)  # concave centre
    Fx, Fy = m.forces(X, Y, np.zeros(m.n))
    Fmx, Fmy = np.empty_like(X), np.empty_like(X)
    internal_forces(X, Y, m.L0, m.S0, m.A0, m.Ebar, m.nu, m.k, Fmx, Fmy)
    Fbx, Fby = Fx - Fmx, Fy - Fmy
    eps = 1e-9
    for i in range(1, m.n - 1):
        for arr, F in ((X, Fbx), (Y, Fby)):
            arr[i] += eps
            up = reference_energy(m, X, Y)[1]
            arr[i] -= 2 * eps
            down = reference_energy(m, X, Y)[1]
            arr[i] += eps
            assert -(up - down) / (2 * eps) == pytest.approx(F[i], rel=1e-5,
                                                              abs=1e-7 * np.abs(Fbx).max())


def test_zero_rigidity_gives_the_membrane_forces_exactly():
    phi, X, Y = perturbed_arc(26, 7)
    shell = build_shell(phi, R, P0, 0.5e6, 0.5e-3, 0.5, 240.0, 1000.0)
    membrane = build_membrane(phi, R, P0, 0.5e6, 0.5e-3, 0.5, 240.0, 1000.0)
    shell.D = 0.0
    q = np.linspace(P0, 0.5 * P0, 26)
    Fs = shell.forces(X, Y, q)
    Fm = membrane.forces(X, Y, q)
    assert np.array_equal(Fs[0], Fm[0]) and np.array_equal(Fs[1], Fm[1])


def test_homothetic_arc_has_no_bending_strain():
    """The drawn arc is the reference scaled by lambda0: no bending energy, and the bending adds
    nothing to the forces there."""
    phi = np.linspace(0, math.radians(60), 26)
    m = build_shell(phi, R, P0, 0.5e6, 0.5e-3, 0.5, 240.0, 1000.0)
    X, Y = R * np.sin(phi), R * np.cos(phi)
    assert m.energy(X, Y)[1] < 1e-25
    Fx, Fy = m.forces(X, Y, np.full(26, P0))
    m.D = 0.0
    Gx, Gy = m.forces(X, Y, np.full(26, P0))
    assert np.abs(Fx - Gx).max() < 1e-12 * np.abs(Gx).max()


@pytest.mark.parametrize("nu", [0.0, 0.5])
def test_clamped_plate_centre_deflection(nu):
    """Clamped circular plate (a = 5 mm, h = 0.5 mm) under a uniform pressure that bends it by
    h / 1000: w(0) = p a^4 / (64 D) within 1 %."""
    a, h, E0 = 5e-3, 0.5e-3, 0.5e6
    D = plate_rigidity(E0, h, nu)
    n = 26
    X = np.linspace(0.0, a, n)
    Y = np.zeros(n)
    plate = shell_on_meridian(X, Y, E0, h, nu, 0.0, 1000.0, "clamped")
    w_theory = 1e-3 * h
    p = 64 * D * w_theory / a ** 4
    _, Yd, residual = static_equilibrium(plate, X, Y, np.full(n, p))
    assert residual < 1e-6
    assert Yd[0] == pytest.approx(w_theory, rel=0.01)


def test_clamped_plate_converges_at_second_order():
    a, h, E0, nu = 5e-3, 0.5e-3, 0.5e6, 0.3
    D = plate_rigidity(E0, h, nu)
    p = 64 * D * 1e-3 * h / a ** 4
    errors = []
    for n in (11, 21, 41):
        X = np.linspace(0.0, a, n)
        plate = shell_on_meridian(X, np.zeros(n), E0, h, nu, 0.0, 1000.0)
        _, Yd, _ = static_equilibrium(plate, X, np.zeros(n), np.full(n, p))
        errors.append(abs(Yd[0] / (p * a ** 4 / (64 * D)) - 1))
    order = [math.log2(errors[i] / errors[i + 1]) for i in range(2)]
    assert min(order) > 1.8


def shallow_shell_apex_deflection(load, ell, D, Eh, N, Rc):
    """Apex deflection [m] of an infinite prestressed spherical shell under the self-equilibrated
    load p(r) = load (1 - r^2/ell^2) exp(-r^2/ell^2), by Hankel transform of

        D del^4 w - N del^2 w + (E h - 2 N) w / R^2 = p,

    w(0) = int_0^inf p^(k) k dk / (D k^4 + N k^2 + (E h - 2 N) / R^2),
    p^(k) = load ell^4 k^2 / 8 exp(-k^2 ell^2 / 4).  The term -2 N w / R^2 is the follower IOP
    on the pressurised sphere: a normal displacement w lowers the curvature by w / R^2 in both
    directions, and the prestress N = p0 R / 2 then carries less of the pressure."""
    k = np.linspace(0.0, 60.0 / ell, 200001)
    f = load * ell ** 4 * k ** 3 / 8 * np.exp(-k ** 2 * ell ** 2 / 4) / (
        D * k ** 4 + N * k ** 2 + (Eh - 2 * N) / Rc ** 2)
    return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(k)))


@pytest.mark.parametrize("Rc,angle,E0", [(7e-3, 60.0, 0.5e6), (20e-3, 30.0, 2e6)])
def test_prestressed_cap_against_linear_shallow_shell(Rc, angle, E0):
    """A small self-equilibrated load (zero net force: a net force travels to the clamped edge by
    membrane action, an effect of the finite cap that the infinite-shell transform lacks; with
    the Gaussian jet it made the cap 7-20 % stiffer) on the IOP-prestressed cap, linear SVK
    membrane (k = 0): apex deflection within 3 % of the shallow-shell solution.  The remaining
    difference is the prestretch (1-1.5 %) and the cap's depth, which linear shallow theory
    neglects."""
    h, nu, ell = 0.5e-3, 0.5, 1.5e-3
    n = 81
    phi = np.linspace(0, math.radians(angle), n)
    m = build_shell(phi, Rc, P0, E0, h, nu, 0.0, 1000.0)
    X0, Y0 = Rc * np.sin(phi), Rc * np.cos(phi)
    Xr, Yr, res_rest = static_equilibrium(m, X0, Y0, np.full(n, P0))
    load = 0.01 * P0
    r2 = (X0 / ell) ** 2
    _, Yl, res_load = static_equilibrium(m, Xr, Yr, P0 + load * (1 - r2) * np.exp(-r2))
    assert max(res_rest, res_load) < 1e-8
    w = Yl[0] - Yr[0]
    w_theory = shallow_shell_apex_deflection(load, ell, m.D, E0 * h, P0 * Rc / 2, Rc)
    assert w == pytest.approx(w_theory, rel=0.03)


@pytest.mark.parametrize("n", [26, 50, 100])
@pytest.mark.parametrize("E0,nu", [(0.5e6, 0.5), (2e6, 0.0)])
def test_stable_substep_bounds_the_highest_frequency(n, E0, nu):
    """The sub-step rule's frequency estimate bounds the largest eigenfrequency of the linearised
    shell (M^-1 K at the rest state), and is not far above it."""
    phi = np.linspace(0, math.radians(60), n)
    m = build_shell(phi, R, P0, E0, 0.5e-3, nu, 240.0, 1000.0)
    X, Y = R * np.sin(phi), R * np.cos(phi)
    q = np.full(n, P0)
    free = [(0, 1)] + [(i, c) for i in range(1, n - 1) for c in (0, 1)]
    K = np.zeros((len(free), len(free)))
    eps = 1e-10
    for j, (i, c) in enumerate(free):
        plus = [X.copy(), Y.copy()]
        plus[c][i] += eps
        minus = [X.copy(), Y.copy()]
        minus[c][i] -= eps
        Fp, Fm = m.forces(*plus, q), m.forces(*minus, q)
        K[:, j] = [-(Fp[cc][ii] - Fm[cc][ii]) / (2 * eps) for ii, cc in free]
    inv_mass = np.array([1.0 / m.mass[i] for i, _ in free])
    omega = math.sqrt(np.linalg.eigvals(inv_mass[:, None] * K).real.max())
    estimate = m.max_frequency(X, Y)
    assert omega <= estimate
    assert omega > 0.6 * estimate
    assert m.stable_substep(X, Y) * omega < 2.0  # Verlet's limit


def test_rest_state_stays_on_the_drawn_arc():
    """Newton's equilibrium of the shell under the IOP, from the homothetic reference, lies on
    the drawn arc to O(dphi^2), as the membrane's does (bending changes the deviation, not its
    order: 4.9e-5 mm against 4.1e-5 mm at 26 nodes)."""
    deviations = []
    for n in (26, 51):
        phi = np.linspace(0, math.radians(60), n)
        X0, Y0 = R * np.sin(phi), R * np.cos(phi)
        q = np.full(n, P0)
        shell = build_shell(phi, R, P0, 0.5e6, 0.5e-3, 0.5, 240.0, 1000.0)
        membrane = build_membrane(phi, R, P0, 0.5e6, 0.5e-3, 0.5, 240.0, 1000.0)
        Xs, Ys, res_s = static_equilibrium(shell, X0, Y0, q)
        Xm, Ym, _ = static_equilibrium(membrane, X0, Y0, q)
        assert res_s < 1e-9
        dev_shell = np.max(np.hypot(Xs - X0, Ys - Y0))
        dev_membrane = np.max(np.hypot(Xm - X0, Ym - Y0))
        assert dev_shell < 0.01 * R * phi[1] ** 2
        assert 0.5 < dev_shell / dev_membrane < 2.0
        deviations.append(dev_shell)
    assert math.log2(deviations[0] / deviations[1]) > 1.8


def test_model_preset_and_explicit_options():
    assert RunParams().model == "paper" and RunParams().cornea == "membrane"
    assert RunParams(model="clinical").cornea == "mindlin"  # the preset's shell, G_t > 0
    assert RunParams(model="clinical", cornea="membrane").cornea == "membrane"
    assert RunParams(model="paper", cornea="shell").cornea == "kirchhoff"  # G_t = 0
    assert RunParams(model="clinical").replace(model="paper").cornea == "membrane"
    assert RunParams(model="clinical").replace(E0=0.3).cornea == "mindlin"
    for name, bad in (("cornea", "plate"), ("model", "clinic"), ("limbus", "free")):
        with pytest.raises(ParameterError, match=f"invalid {name}=.*accepted one of"):
            RunParams(**{name: bad})


def test_shell_run_parameters_round_trip_through_netcdf(tmp_path):
    """A short coupled shell run: the cornea, limbus and model options are in the netCDF and
    read back as the same RunParams; the solver reports the bending rigidity it used."""
    params = RunParams(model="clinical", limbus="pinned", t_end=0.2)
    result = simulate(params)
    path = write_netcdf(result.to_dataset(), tmp_path / "shell.nc")
    with xr.open_dataset(path) as ds:
        assert ds.attrs["cornea"] == "mindlin" and ds.attrs["limbus"] == "pinned"
        assert ds.attrs["model"] == "clinical"
        assert ds.attrs["title"].startswith("airpuff: coupled mindlin / MFPM")
        assert params_from_dataset(ds) == params
        D = ds.attrs["solver_bending_rigidity_N_m"]
    assert D == pytest.approx(plate_rigidity(0.5e6, 0.5e-3, 0.5), rel=1e-12)


def test_free_vibration_conserves_energy():
    """Verlet at the stable sub-step, no load and no jet: a shell set vibrating about its
    stress-free reference (bending and stretching) keeps its kinetic plus elastic energy to
    Verlet's O(dt^2) oscillation, without drift, over 5000 sub-steps (the forces are the exact
    gradient of the energy the kernel reports, and the sub-step is stable)."""
    n = 26
    phi = np.linspace(0, math.radians(60), n)
    m = build_shell(phi, R, P0, 0.5e6, 0.5e-3, 0.5, 240.0, 1000.0)
    X, Y = m.R_ref * np.sin(phi), m.R_ref * np.cos(phi)
    Y[:-1] += 2e-5 * np.cos(1.5 * math.pi * phi[:-1] / phi[-1])  # a smooth bending mode [m]
    VX, VY = np.zeros(n), np.zeros(n)
    zero = np.zeros(n)
    jet = AirJet(RunParams(pmax=0.0).si(), m.phi)  # the paper's jet with pmax 0: no load

    def total_energy():
        return 0.5 * np.sum(m.mass * (VX ** 2 + VY ** 2)) + sum(m.energy(X, Y))

    e0 = total_energy()
    dt_sub = m.stable_substep(X, Y)
    energies = []
    kinetic = []
    for _ in range(50):
        m.advance(X, Y, VX, VY, zero, zero, 0.0, 100 * dt_sub, 100, jet)
        energies.append(total_energy())
        kinetic.append(0.5 * np.sum(m.mass * (VX ** 2 + VY ** 2)))
    energies = np.array(energies)
    assert np.all(np.isfinite(energies))
    assert max(kinetic) > 0.3 * e0  # it does vibrate
    assert np.max(np.abs(energies - e0)) < 3e-3 * e0  # measured 9e-4
    assert abs(energies[-10:].mean() - energies[:10].mean()) < 2e-4 * e0  # no drift (1.4e-5)
