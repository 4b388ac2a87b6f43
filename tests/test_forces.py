"""Force values against hand computation (docs/physics.md: forces, Breen's model) and against energies."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from cloth_gym import load_material
from cloth_gym.sim import Control, ForceOptions, Rectangle, build_cloth, compute_forces
from cloth_gym.sim.forces import (breen_bend_torque, breen_shear_torque, breen_stretch_tension, eval_bending,
                                  eval_shear, eval_stretch, kes_bend_torque, kes_shear_torque,
                                  kes_stretch_tension)

from conftest import lattice_areas, only

G = 978.8
SIG = 0.5
COTTON = load_material("thick_cotton")
WOOL = load_material("thin_wool")
STRETCH = np.array([[36.77, 38.38], [35.37, 6.71]])


def _edge_force(x1, d=0, breen=False):
    x = np.array([[0.0, 0.0, 0.0], [x1, 0.0, 0.0]])
    f = np.zeros((2, 3))
    eval_stretch(x, np.array([[0, 1]], np.int32), np.array([d], np.int32), np.array([SIG]), np.ones(1), STRETCH,
                 0.1, breen, 1.0e5, f)
    return f


def test_stretch_plus_one_percent_cotton_warp():
    f = _edge_force(SIG * 1.01)
    expected = (36.77 + 38.38) * SIG * 978.8
    np.testing.assert_allclose(f[0], [expected, 0, 0], rtol=1e-10)  # pulled towards the other end
    np.testing.assert_allclose(f[1], [-expected, 0, 0], rtol=1e-10)


def test_stretch_minus_one_percent_is_alpha_times_and_pushes_apart():
    f = _edge_force(SIG * 0.99)
    expected = 0.1 * (36.77 + 38.38) * SIG * 978.8
    np.testing.assert_allclose(f[0], [-expected, 0, 0], rtol=1e-10)
    np.testing.assert_allclose(f[1], [expected, 0, 0], rtol=1e-10)


def test_stretch_weft_uses_weft_curve():
    f = _edge_force(SIG * 1.02, d=1)
    np.testing.assert_allclose(f[0, 0], (35.37 * 2 + 6.71 * 4) * SIG * G, rtol=1e-10)


def test_breen_stretch_hand_values():
    # r = 0.55: 5 C0 (0.05)^4 / 0.5^5 = 100 dyne pulling; r = 0.45: C0 (2.3)(0.05)^4 / 0.25 = 5.75 pushing
    np.testing.assert_allclose(_edge_force(0.55, breen=True)[0], [100.0, 0, 0], rtol=1e-10)
    np.testing.assert_allclose(_edge_force(0.45, breen=True)[0], [-5.75, 0, 0], rtol=1e-10)


def _hand_M(K, c, x0=0.004):
    return c[0] * K / np.sqrt(K + x0) + c[1] * K + c[2] * K * K


PSIS = [0.05, 0.3, 1.0, 2.0, 3 * np.pi / 4, 2.8]


@pytest.mark.parametrize("psi", PSIS)
@pytest.mark.parametrize("length", [1.0, 0.5])
def test_kes_bending_torque_and_force(psi, length):
    """Hand values; ``length`` ½ is a triple at a clamp, whose curvature is ψ over σ/2."""
    c = (0.097, 0.082, 0.0008)
    K = 3.0 / (2 * SIG * length) * np.sin(2 * psi / 3)
    T = _hand_M(K, c) * SIG * G
    if length == 1.0:
        assert math.isclose(kes_bend_torque(psi, *c, SIG, 0.004), T, rel_tol=1e-12)
    # geometry: a = (-σ, 0, 0), b = 0, c = σ(cos ψ, sin ψ, 0)  ⇒  f_a = −(T/σ) ŷ
    x = np.array([[-SIG, 0, 0], [0, 0, 0], [SIG * np.cos(psi), SIG * np.sin(psi), 0]])
    f = np.zeros((3, 3))
    eval_bending(x, np.array([[0, 1, 2]], np.int32), np.array([0], np.int32), np.ones(1), np.full(1, length),
                 np.array([c, c]), SIG, 0.004, False, f)
    np.testing.assert_allclose(f[0], [0, -T / SIG, 0], atol=1e-9 * T)
    assert math.isclose(np.linalg.norm(f[2]), T / SIG, rel_tol=1e-10)


@pytest.mark.parametrize("psi", PSIS)
def test_breen_bending_torque(psi):
    c = WOOL.bending.mean().as_array()
    theta = np.pi - psi
    if theta > np.pi / 4:
        K = 2 / SIG * np.cos(theta / 2)
    else:
        a, b = 2 / SIG * np.cos(np.pi / 8), 1 / SIG * np.sin(np.pi / 8)
        K = (np.pi / 4) ** 2 * b / theta + a - np.pi / 4 * b
    dM = c[1] + 2 * c[2] * K  # wool has no root term
    T = G * SIG / 2 * (_hand_M(K, c) + dM) * np.sin(theta / 2)
    assert math.isclose(breen_bend_torque(psi, *c, SIG, 0.004), T, rel_tol=1e-12)


def test_breen_curvature_is_continuous_at_quarter_pi():
    c = WOOL.bending.mean().as_array()
    eps = 1e-9
    lo = breen_bend_torque(3 * np.pi / 4 - eps, *c, SIG, 0.004)
    hi = breen_bend_torque(3 * np.pi / 4 + eps, *c, SIG, 0.004)
    assert math.isclose(lo, hi, rel_tol=1e-6)


@pytest.mark.parametrize("curves", [WOOL.bending.mean().as_array(), np.array([0.0, 0.0615, 0.0034])],
                         ids=["wool", "cotton-without-root-term"])
def test_torque_peaks_fig3b(curves):
    """Paper fig. 3(b): Breen's torque peaks near π/2, the proposed one at 3π/4.

    Breen's curve is compared on its main branch ψ ≤ 3π/4 (θ ≥ π/4), the range
    the paper plots: past it the (π/4)²β/θ branch of K(θ) turns into a fold
    barrier that grows without bound as θ → 0."""
    psi = np.linspace(1e-3, np.pi - 1e-3, 4001)
    tk = np.array([kes_bend_torque(p, *curves, SIG, 0.004) for p in psi])
    assert abs(psi[np.argmax(tk)] - 3 * np.pi / 4) < 2e-3
    main = psi[psi <= 3 * np.pi / 4]
    tb = np.array([breen_bend_torque(p, *curves, SIG, 0.004) for p in main])
    peak = np.argmax(tb)
    assert abs(main[peak] - np.pi / 2) < 0.1 * np.pi
    assert tb[-1] < 0.95 * tb[peak] and tb[0] < 0.95 * tb[peak]  # an interior maximum


@pytest.mark.parametrize("phi_deg", [-20.0, -3.0, 0.5, 5.0, 30.0])
def test_shear_torque_eq15_and_force_direction(phi_deg):
    c = COTTON.shear.mean().as_array()
    phi = np.radians(phi_deg)
    a = abs(phi_deg)
    Fbar = c[0] * a / np.sqrt(a + 0.004) + c[1] * a + c[2] * a * a
    T = G / 4 * Fbar * np.cos(phi) * SIG ** 2
    assert math.isclose(kes_shear_torque(phi, *c, SIG, 0.004), T, rel_tol=1e-12)
    assert math.isclose(breen_shear_torque(phi, *c, SIG, 0.004), G / 5 * SIG ** 3 / 4 * Fbar * np.cos(phi),
                        rel_tol=1e-12)
    gamma = np.pi / 2 + phi
    x = np.array([[SIG, 0, 0], [0, 0, 0], [SIG * np.cos(gamma), SIG * np.sin(gamma), 0]])
    f = np.zeros((3, 3))
    eval_shear(x, np.array([[0, 1, 2]], np.int32), c, SIG, 0.004, False, f)
    # a is pushed towards c when the angle opened (φ > 0), away when it closed
    np.testing.assert_allclose(f[0], [0, np.sign(phi) * T / SIG, 0], atol=1e-9 * T)


# ---------------------------------------------------------------- energies and gradients
def _element_terms(model, x):
    """(coordinate, signed generalised force law) per element, for the forces switched on."""
    from cloth_gym.sim.forces import bend_angle

    o = model.options
    breen = o.model == "breen"
    s = model.sigma
    terms = []
    if o.stretch:
        for (a, b), d, w in zip(model.edge_indices, model.edge_dir, model.edge_width):
            c1, c2 = model.stretch_coef[d]
            if breen:
                law = lambda r, w=w: w * breen_stretch_tension(r, s, o.breen_c0)
            else:
                law = lambda r, c1=c1, c2=c2, w=w: w * kes_stretch_tension(100 * (r - s) / s, c1, c2, 0.1, s)
            terms.append((lambda x, a=a, b=b: np.linalg.norm(x[b] - x[a]), law))
    if o.bending:
        blaw = breen_bend_torque if breen else kes_bend_torque
        for (a, b, c), d, w, ell in zip(model.bend_indices, model.bend_dir, model.bend_width, model.bend_length):
            if ell == 0.0:  # inside a clamp: no force
                continue
            k = model.bend_coef[d]  # a triple turning over ell·σ: its law at that length, per unit width
            terms.append((lambda x, a=a, b=b, c=c: bend_angle(x, a, b, c)[0],
                          lambda p, k=k, w=w, ell=ell: w / ell * blaw(p, k[0], k[1], k[2], s * ell,
                                                                       o.sqrt_reg_curvature)))
    if o.shear:
        slaw = breen_shear_torque if breen else kes_shear_torque
        k = model.shear_coef
        for a, b, c in model.shear_indices:
            def gamma(x, a=a, b=b, c=c):
                u, w = x[a] - x[b], x[c] - x[b]
                return math.atan2(np.linalg.norm(np.cross(u, w)), u @ w) - np.pi / 2
            terms.append((gamma, lambda p: math.copysign(slaw(p, k[0], k[1], k[2], s, o.sqrt_reg_shear), p)))
    return terms


def _minus_grad_energy(model, x, h=1e-6):
    """−∂E/∂x by central differences, E = Σ ∫ law dq over each element's coordinate q.

    ``E(x+h) − E(x−h)`` is integrated exactly over [q(x−h), q(x+h)] so the
    difference carries no quadrature noise."""
    terms = _element_terms(model, x)
    g = np.zeros_like(x)
    for p in range(x.shape[0]):
        for k in range(3):
            xp, xm = x.copy(), x.copy()
            xp[p, k] += h
            xm[p, k] -= h
            dE = 0.0
            for q, law in terms:
                qm, qp = q(xm), q(xp)
                if qm != qp:
                    dE += quad(law, qm, qp, epsabs=0, epsrel=1e-12)[0]
            g[p, k] = -dE / (2 * h)
    return g


@pytest.mark.parametrize("model_kind", ["kes", "breen"])
@pytest.mark.parametrize("force", ["stretch", "bending", "shear"])
def test_force_is_minus_energy_gradient(model_kind, force, rng):
    m = build_cloth(Rectangle(1.0, 1.0), "thick_cotton", sigma=0.5, options=only(**{force: True}, model=model_kind))
    s = m.state()
    s.particle_q += rng.normal(0, 0.06, s.particle_q.shape)
    f = compute_forces(m, s)
    g = _minus_grad_energy(m, s.particle_q)
    np.testing.assert_allclose(f, g, atol=1e-6 * np.abs(f).max(), rtol=1e-5)
    assert np.abs(f).max() > 0


@pytest.mark.parametrize("model_kind", ["kes", "breen"])
def test_a_clamps_bending_is_minus_its_energy_gradient(model_kind, rng):
    """With two columns pinned (a clamp: triples of length ½ and 0) bending is still conservative."""
    m = build_cloth(Rectangle(1.5, 1.0), "thick_cotton", sigma=0.5, options=only(bending=True, model=model_kind))
    m = m.with_pinned(np.nonzero(m.particle_q0[:, 0] < -0.2)[0])
    assert {0.5, 1.0} <= set(m.bend_length)
    s = m.state()
    s.particle_q += rng.normal(0, 0.06, s.particle_q.shape)
    f = compute_forces(m, s)
    np.testing.assert_allclose(f, _minus_grad_energy(m, s.particle_q), atol=1e-6 * np.abs(f).max(), rtol=1e-5)


@pytest.mark.parametrize("model_kind", ["kes", "breen"])
def test_internal_forces_have_no_net_force_or_torque(model_kind, rng):
    m = build_cloth(Rectangle(3.0, 2.0), "thin_wool", sigma=0.5,
                    options=only(stretch=True, bending=True, shear=True, model=model_kind))
    s = m.state()
    s.particle_q += rng.normal(0, 0.1, s.particle_q.shape)
    f = compute_forces(m, s)
    scale = np.abs(f).max()
    np.testing.assert_allclose(f.sum(axis=0), 0, atol=1e-10 * scale * m.particle_count)
    torque = np.cross(s.particle_q - 7.0, f).sum(axis=0)
    np.testing.assert_allclose(torque, 0, atol=1e-10 * scale * m.particle_count * 10)


def test_rest_state_has_no_internal_force():
    m = build_cloth(Rectangle(3.0, 3.0), "thick_cotton", sigma=0.5,
                    options=only(stretch=True, bending=True, shear=True))
    assert np.abs(compute_forces(m, m.state())).max() < 1e-9


def test_gravity_damping_and_air_hand_values():
    # a 2 × 2 cm cloth at σ = 0.5: 5 × 5 particles carrying W·σ² inside, half on an edge, a quarter at a corner
    area = 0.25 * lattice_areas(5, 5)
    mass = 0.01576 * area
    m = build_cloth(Rectangle(2.0, 2.0), "thick_cotton", sigma=0.5,
                    options=only(gravity=True, damping=True, damping_model="absolute"))
    np.testing.assert_allclose(m.particle_mass, mass, rtol=1e-14)
    s = m.state()
    s.particle_qd[:] = [10.0, 0, 0]
    f = compute_forces(m, s)
    np.testing.assert_allclose(f, np.stack([-0.5 * mass * 10.0, 0 * mass, -mass * G], axis=1))
    # the strain-rate damping leaves a cloth moving as one body alone: gravity only
    m = build_cloth(Rectangle(2.0, 2.0), "thick_cotton", sigma=0.5, options=only(gravity=True, damping=True))
    np.testing.assert_allclose(compute_forces(m, s), np.stack([0 * mass, 0 * mass, -mass * G], axis=1))

    m = build_cloth(Rectangle(2.0, 2.0), "thick_cotton", sigma=0.5, options=only(air=True))
    s = m.state()
    s.particle_qd[:] = [0, 0, -100.0]  # falling flat: |n·u| = 100
    np.testing.assert_allclose(compute_forces(m, s), np.stack([0 * area, 0 * area, 0.3e-4 * area * 1e4], axis=1))
    s.particle_qd[:] = [30.0, 0, 0]  # sliding in its own plane: no drag
    np.testing.assert_allclose(compute_forces(m, s), 0, atol=1e-15)
    s.particle_qd[:] = 0.0
    wind = Control(wind=np.array([0, 0, 50.0]))  # still cloth in an upward wind is pushed up
    np.testing.assert_allclose(compute_forces(m, s, wind), np.stack([0 * area, 0 * area, 0.3e-4 * area * 2500], axis=1))


@pytest.mark.parametrize("r", [0.40, 0.47, 0.499, 0.501, 0.52, 0.6])
def test_stretch_slopes_are_derivatives_of_the_laws(r):
    from cloth_gym.sim.forces import breen_stretch_slope, kes_stretch_slope

    h = 1e-7
    for d, (c1, c2) in enumerate(STRETCH):
        eps = lambda rr: 100 * (rr - SIG) / SIG
        fd = (kes_stretch_tension(eps(r + h), c1, c2, 0.1, SIG) - kes_stretch_tension(eps(r - h), c1, c2, 0.1, SIG)) / (2 * h)
        assert math.isclose(kes_stretch_slope(eps(r), c1, c2, 0.1), fd, rel_tol=1e-5)
    fd = (breen_stretch_tension(r + h, SIG, 1e5) - breen_stretch_tension(r - h, SIG, 1e5)) / (2 * h)
    assert math.isclose(breen_stretch_slope(r, SIG, 1e5), fd, rel_tol=1e-5, abs_tol=1e-6)


@pytest.mark.parametrize("model_kind", ["kes", "breen"])
def test_strain_rate_damping_leaves_rigid_motion_alone_and_dissipates(model_kind, rng):
    """On a deformed cloth, the strain-rate damping of a rigid velocity field (a translation plus a
    rotation about any axis) is zero; for any other velocity field it does negative work."""
    from cloth_gym.sim.forces import eval_strain_damping

    m = build_cloth(Rectangle(4.0, 3.0), "thick_cotton", sigma=0.5,
                    options=ForceOptions(model=model_kind, gravity=False, air=False))
    x = m.particle_q0 * 1.03 + rng.normal(0, 0.05, m.particle_q0.shape)
    omega, vel = rng.normal(size=3) * 2.0, rng.normal(size=3) * 50.0
    rigid = vel + np.cross(omega, x - x.mean(axis=0))
    f = np.zeros_like(x)
    eval_strain_damping(x, rigid, m.force_data, f)
    u = rng.normal(size=x.shape)
    fu = np.zeros_like(x)
    eval_strain_damping(x, u, m.force_data, fu)
    assert np.abs(f).max() <= 1e-9 * np.abs(fu).max()
    assert np.sum(fu * u) < 0.0
