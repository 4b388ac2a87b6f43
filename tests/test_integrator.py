"""Explicit integration: free fall, pins, stability limit, divergence, settling, anisotropy."""

import math

import numpy as np
import pytest

from cloth_gym import ConfigError, SimulationDiverged, StabilityError, load_material
from cloth_gym.sim import ForceOptions, Rectangle, SymplecticEuler, build_cloth, explicit_stability_limit

from conftest import only

G = 978.8


@pytest.mark.parametrize("material, sigma, direction, table", [
    ("thick_cotton", 0.5, "warp", 3.3e-5),
    ("thick_cotton", 2.0, "warp", 1.3e-4),
    ("thin_wool", 0.5, "warp", 8.3e-5),
    ("thin_wool", 2.0, "weft", 4.1e-4),
])
def test_stability_limit_reproduces_spec_table(material, sigma, direction, table):
    m = build_cloth(Rectangle(4 * sigma, 4 * sigma), material, sigma=sigma)
    est = explicit_stability_limit(m)
    got = getattr(est, f"dt_limit_{direction}_s")
    assert abs(got - table) / table < 0.02  # the table has two significant digits
    assert est.dt_limit_s <= est.dt_limit_stretch_s <= got * (1 + 1e-12) or direction == "weft"


def _perturbed_run(m, dt, steps, amplitude, seed=0):
    s = m.state()
    s.particle_q += np.random.default_rng(seed).normal(0, amplitude, s.particle_q.shape)
    SymplecticEuler(on_unstable="ignore").advance(m, s, None, steps * dt, dt)
    return s


@pytest.mark.parametrize("material, sigma", [("thick_cotton", 0.5), ("thin_wool", 2.0)])
def test_stability_estimate_is_sharp(material, sigma):
    """Undamped cloth with a smooth (α = 1) stretch law, small perturbation
    (linear regime): stable at 0.9× the estimate for thousands of steps,
    diverges with the typed error at 1.15×."""
    mat = load_material(material).replace(compression_factor=1.0)
    m = build_cloth(Rectangle(10 * sigma, 10 * sigma), mat, sigma=sigma,
                    options=only(stretch=True, bending=True, shear=True))
    lim = explicit_stability_limit(m).dt_limit_s
    s = _perturbed_run(m, 0.9 * lim, 6000, 1e-6 * sigma)
    assert np.abs(s.particle_q - m.particle_q0).max() < 1e-4 * sigma
    with pytest.raises(SimulationDiverged):
        _perturbed_run(m, 1.15 * lim, 6000, 1e-6 * sigma)


def test_default_safety_handles_the_tension_compression_kink():
    """With the measured α = 0.1 the law has a kink at ε = 0: 0.9× the linear
    limit blows up, the default safety (0.5×) stays bounded."""
    m = build_cloth(Rectangle(5.0, 5.0), "thick_cotton", sigma=0.5,
                    options=only(stretch=True, bending=True, shear=True))
    lim = explicit_stability_limit(m).dt_limit_s
    assert SymplecticEuler().safety == 0.5
    s = _perturbed_run(m, 0.5 * lim, 12000, 1e-6)
    assert np.abs(s.particle_q - m.particle_q0).max() < 1e-4
    with pytest.raises(SimulationDiverged):
        _perturbed_run(m, 0.9 * lim, 12000, 1e-6)


def test_free_fall_is_half_g_t_squared():
    m = build_cloth(Rectangle(2.0, 2.0), "thick_cotton", sigma=0.5, options=only(gravity=True))
    s = m.state()
    dt, n = 1e-4, 3000
    SymplecticEuler().advance(m, s, None, n * dt, dt)
    t = n * dt
    # symplectic Euler: z_n = -g dt² n(n+1)/2 exactly; the continuous ½gt² within ½·g·t·dt
    np.testing.assert_allclose(s.particle_q[:, 2], -G * dt * dt * n * (n + 1) / 2, rtol=1e-9)
    assert np.all(np.abs(s.particle_q[:, 2] + 0.5 * G * t * t) <= 0.5 * G * t * dt * (1 + 1e-6))
    np.testing.assert_allclose(s.particle_q[:, :2], m.particle_q0[:, :2], atol=1e-12)
    assert math.isclose(s.time, t, rel_tol=1e-12) and s.step == n


def _hang(material, warp_vertical: bool, size=10.0, sigma=1.0, damping=5.0, duration=3.0):
    """Square hung by its top edge in the x–z plane; warp (or weft) vertical."""
    def frame(lx, ly):  # rotation with columns: images of local x, local y, normal
        return np.column_stack([lx, ly, np.cross(lx, ly)]).astype(float)
    down_x = frame([0, 0, -1], [1, 0, 0])  # warp (local x) hangs along -z
    down_y = frame([1, 0, 0], [0, 0, -1])  # weft (local y) hangs along -z
    mat = load_material(material).replace(damping=damping)
    # the absolute damping (λ = ``damping``, 1/s) settles the hanging cloth's swing, which the
    # strain-rate damping leaves to the air
    m = build_cloth(Rectangle(size, size), mat, sigma=sigma, rotation=down_x if warp_vertical else down_y,
                    options=ForceOptions(damping_model="absolute"))
    top = np.isclose(m.particle_q0[:, 2], m.particle_q0[:, 2].max())
    m = m.with_pinned(top)
    s = m.state()
    SymplecticEuler(on_unstable="substep").advance(m, s, None, duration, 1e-3)
    return m, s


def test_pinned_particles_do_not_move():
    m, s = _hang("thin_wool", True, size=6.0, duration=0.3)
    assert np.array_equal(s.particle_q[m.pinned], m.particle_q0[m.pinned])
    assert np.all(s.particle_qd[m.pinned] == 0)
    assert np.abs(s.particle_q[~m.pinned] - m.particle_q0[~m.pinned]).max() > 1e-4


def _top_edges(m):
    e = m.edge_indices
    return m.pinned[e[:, 0]] ^ m.pinned[e[:, 1]]


def _top_edge_strain(m, s):
    e = m.edge_indices[_top_edges(m)]
    d = s.particle_q[e[:, 1]] - s.particle_q[e[:, 0]]
    return 100 * (np.linalg.norm(d, axis=1) - m.sigma) / m.sigma


@pytest.mark.slow
def test_hanging_cloth_settles_and_warp_weft_differ():
    """Cotton hung by one edge, then rotated 90°: the top edges carry the
    cloth's weight, so their strain solves F̂_d(ε)·σ·G·Σw = weight with
    the warp or weft curve (Σw the top edges' widths, in σ: the cloth's width over σ). Warp and weft must come out different, each as its
    own curve predicts."""
    cotton = load_material("thick_cotton")
    strains = {}
    for warp_vertical, curve in ((True, cotton.stretch.warp), (False, cotton.stretch.weft)):
        m, s = _hang("thick_cotton", warp_vertical)
        speed = np.linalg.norm(s.particle_qd, axis=1).max()
        assert speed < 1e-3  # settled (cm/s)
        eps = _top_edge_strain(m, s)
        assert np.ptp(eps) < 1e-3 * eps.mean()  # the outline's half-width edges carry half the load
        width = m.edge_width[_top_edges(m)].sum()
        weight = m.particle_mass[~m.pinned].sum() * G  # dyne
        stress = weight / width / (m.sigma * G)  # gf/cm
        expected = (-curve.c1 + math.sqrt(curve.c1 ** 2 + 4 * curve.c2 * stress)) / (2 * curve.c2)
        assert abs(eps.mean() - expected) / expected < 0.02
        strains[warp_vertical] = eps.mean()
    ratio = strains[False] / strains[True]
    assert ratio > 1.03  # weft is softer than warp (35.37 vs 36.77 gf/cm per %)
    assert abs(ratio - 36.77 / 35.37) < 0.01


def test_dt_above_limit_is_refused_with_the_limit():
    m = build_cloth(Rectangle(4.0, 4.0), "thick_cotton", sigma=0.5)
    integ = SymplecticEuler()
    lim = integ.stability(m).dt_limit_s
    with pytest.raises(StabilityError) as info:
        integ.step(m, m.state(), None, 2e-4)  # the paper's dt
    assert f"{lim:.3g}" in str(info.value) and "0.0002 s" in str(info.value)
    assert info.value.limit == pytest.approx(lim)
    sub = SymplecticEuler(on_unstable="substep")
    s = m.state()
    out = sub.step(m, s, None, 2e-4)
    assert out.substeps == math.ceil(2e-4 / (0.5 * lim)) and out.dt_sub <= 0.5 * lim
    assert s.step == out.substeps and math.isclose(s.time, 2e-4)


def test_divergence_raises_typed_error_not_nan():
    m = build_cloth(Rectangle(5.0, 5.0), "thick_cotton", sigma=0.5, options=only(stretch=True, shear=True))
    lim = explicit_stability_limit(m).dt_limit_s
    s = m.state()
    s.particle_q += np.random.default_rng(3).normal(0, 0.01, s.particle_q.shape)
    integ = SymplecticEuler(on_unstable="ignore")
    with pytest.raises(SimulationDiverged) as info:
        integ.advance(m, s, None, 1.0, 3 * lim)
    err = info.value
    assert 0 < err.step == s.step and err.time_s == pytest.approx(s.time)
    assert 0 <= err.particle < m.particle_count and err.reason in ("speed", "strain")
    assert f"step {err.step}" in str(err) and f"particle {err.particle}" in str(err)


def test_non_finite_state_names_the_particle():
    m = build_cloth(Rectangle(2.0, 2.0), "thin_wool", sigma=0.5)
    s = m.state()
    s.particle_qd[7, 2] = np.nan
    # the strain-rate damping would spread the bad velocity to the neighbours within the step
    m = build_cloth(Rectangle(2.0, 2.0), "thin_wool", sigma=0.5, options=ForceOptions(damping_model="absolute"))
    with pytest.raises(SimulationDiverged) as info:
        SymplecticEuler().step(m, s, None, 1e-5)
    # refused as handed over, before a step is taken (state.step 0)
    assert info.value.reason == "non-finite" and info.value.particle == 7 and info.value.step == 0 == s.step


@pytest.mark.parametrize("kwargs, field", [
    (dict(safety=0.0), "safety"), (dict(on_unstable="pray"), "on_unstable"),
    (dict(design_strain_percent=-1), "design_strain_percent"),
])
def test_bad_integrator_options(kwargs, field):
    with pytest.raises(ConfigError) as info:
        SymplecticEuler(**kwargs)
    assert info.value.field == field


def test_bad_dt():
    m = build_cloth(Rectangle(2.0, 2.0), "thin_wool", sigma=0.5)
    for dt in (0.0, -1e-4, float("nan")):
        with pytest.raises(ConfigError, match="dt"):
            SymplecticEuler().step(m, m.state(), None, dt)
