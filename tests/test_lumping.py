"""The lattice is the cloth the user asked for (area lumping), and the strain-rate damping leaves
rigid motion alone: mass, centre of mass and moments of inertia of the shape; free fall at ½gt²;
a spinning cloth keeps its spin."""

import math

import numpy as np
import pytest

from cloth_gym import load_material
from cloth_gym.sim import Disc, ForceOptions, Rectangle, build_cloth
from cloth_gym.sim.implicit import ImplicitEuler

G = 978.8
W = 0.01576  # thick cotton, g/cm²


@pytest.mark.parametrize("sigma", [4.0, 2.0, 1.0, 0.5])
def test_a_40_cm_square_weighs_1600_W_with_its_centroid_and_inertia(sigma):
    m = build_cloth(Rectangle(40.0, 40.0), "thick_cotton", sigma=sigma, origin=(3.0, -2.0, 7.0))
    mass = m.particle_mass
    assert mass.sum() == pytest.approx(1600 * W, rel=1e-12)
    com = (mass[:, None] * m.particle_q0).sum(0) / mass.sum()
    np.testing.assert_allclose(com, (3.0, -2.0, 7.0), atol=1e-12)
    # moment of inertia about the normal axis through the centre: M·(a² + b²)/12 for the sheet; the
    # lattice's sums are the trapezoidal rule's, off by M·σ²/3 (second order in σ)
    r2 = ((m.particle_q0[:, :2] - com[:2]) ** 2).sum(1)
    exact = 1600 * W * (2 * 40.0 ** 2) / 12
    assert (mass * r2).sum() == pytest.approx(exact + 1600 * W * sigma ** 2 / 3, rel=1e-12)


def test_uniform_lumping_is_the_papers_larger_lattice():
    m = build_cloth(Rectangle(40.0, 40.0), "thick_cotton", sigma=1.0, options=ForceOptions.paper())
    assert m.particle_mass.sum() == pytest.approx(41 * 41 * W)  # (L + σ)² of fabric: +5.1 %
    assert np.all(m.edge_width == 1.0) and np.all(m.bend_width == 1.0)


def test_outline_elements_stand_for_half_a_strip():
    m = build_cloth(Rectangle(3.0, 2.0), "thick_cotton", sigma=1.0)  # 4 × 3 particles
    i, j = m.particle_grid[m.edge_indices[:, 0]].T
    i2, j2 = m.particle_grid[m.edge_indices[:, 1]].T
    on_outline = ((m.edge_dir == 0) & ((j == 0) | (j == 2))) | ((m.edge_dir == 1) & ((i == 0) | (i == 3)))
    np.testing.assert_array_equal(m.edge_width, np.where(on_outline, 0.5, 1.0))
    # the widths tile the cloth: Σ w·σ² over each direction's edges is the area, 3 × 2 cm²
    assert m.edge_width[m.edge_dir == 0].sum() == pytest.approx(6.0)
    assert m.edge_width[m.edge_dir == 1].sum() == pytest.approx(6.0)


@pytest.mark.parametrize("sigma", [2.0, 1.0, 0.5])
def test_a_disc_weighs_its_area_centred(sigma):
    m = build_cloth(Disc(25.0), "thin_wool", sigma=sigma)
    assert m.particle_mass.sum() == pytest.approx(0.01343 * math.pi * 12.5 ** 2, rel=1e-12)
    com = (m.particle_mass[:, None] * m.particle_q0).sum(0) / m.particle_mass.sum()
    np.testing.assert_allclose(com, 0.0, atol=1e-12)
    assert m.particle_mass.min() > 0


def test_free_fall_with_damping_on_and_air_off_is_half_g_t_squared():
    """The material's damping (strain-rate, on) and no air: a falling cloth is not slowed. Backward
    Euler's known offset after n steps of h: ½g·t² + ½g·h·t (x_n = −g·h²·n(n+1)/2). The linear
    solves run to 1e-12 so that the comparison is to round-off, not to the CG tolerance."""
    m = build_cloth(Rectangle(10.0, 10.0), "thick_cotton", sigma=1.0, options=ForceOptions(air=False))
    s = m.state()
    h, n = 0.01, 50
    ImplicitEuler(max_dt=h, tol=1e-12).advance(m, s, None, n * h, h)
    t = n * h
    drop = m.particle_q0[:, 2] - s.particle_q[:, 2]
    np.testing.assert_allclose(drop, 0.5 * G * t * t + 0.5 * G * h * t, rtol=1e-9)
    absolute = build_cloth(Rectangle(10.0, 10.0), "thick_cotton", sigma=1.0,
                           options=ForceOptions.paper(air=False))
    s = absolute.state()
    ImplicitEuler(max_dt=h).advance(absolute, s, None, n * h, h)
    assert (absolute.particle_q0[:, 2] - s.particle_q[:, 2]).mean() < 0.95 * 0.5 * G * t * t  # the paper's damping slows it


@pytest.mark.parametrize("scheme", ["euler", "bdf2"])
def test_a_spinning_cloth_keeps_its_angular_velocity_with_damping_on(scheme):
    """Weightless, no air: a cloth spinning in its plane at 2 rad/s keeps the angular momentum it
    keeps with no damping at all (the integrator's own loss) when the strain-rate damping is on;
    the paper's absolute damping (λ = 0.5/s) takes e^(−0.25) of it away in 0.5 s."""
    def spun(damping, model):
        m = build_cloth(Rectangle(10.0, 10.0), "thin_wool", sigma=1.0, gravity=(0, 0, 0),
                        options=ForceOptions(air=False, damping=damping, damping_model=model))
        s = m.state()
        s.particle_qd[:] = np.cross((0.0, 0.0, 2.0), s.particle_q)
        L0 = (m.particle_mass[:, None] * np.cross(s.particle_q, s.particle_qd)).sum(0)[2]
        ImplicitEuler(max_dt=1e-3, scheme=scheme, tol=1e-10).advance(m, s, None, 0.5, 1e-3)
        return (m.particle_mass[:, None] * np.cross(s.particle_q, s.particle_qd)).sum(0)[2] / L0

    undamped = spun(False, "strain-rate")
    assert undamped > 0.98
    # within 0.1 %: the damping's pair forces act along edges and exert no torque, but they damp
    # the radial breathing the start excites, which moves the integrator's own loss a little
    assert spun(True, "strain-rate") == pytest.approx(undamped, rel=1e-3)
    assert spun(True, "absolute") == pytest.approx(undamped * math.exp(-0.25), rel=0.01)


def test_material_strain_damping_is_data():
    wool = load_material("thin_wool")
    assert wool.strain_damping > 0
    d = wool.to_dict()
    assert d["strain_damping_s"] == wool.strain_damping
    assert type(wool).from_dict({**d, "strain_damping_s": 1e-4}).strain_damping == 1e-4


def test_a_clamp_s_joints_bend_over_half_a_segment():
    """Hand values of ``Model.bend_length``: a strip of 5 particles with the first two pinned (a clamp):
    the triple centred on the clamp's edge bends over ½ σ, the others over σ; with three pinned the
    triple inside the clamp has length 0; a single pinned particle clamps nothing."""
    m = build_cloth(Rectangle(4.0, 0.0 + 1.0), "thin_wool", sigma=1.0)  # 5 × 2 particles
    along = m.bend_dir == 0
    first = m.particle_q0[m.bend_indices[:, 0], 0]  # the x of each triple's first particle
    x = m.particle_q0[:, 0]
    for pinned_up_to, expect in [(-2.0, [1.0, 1.0, 1.0]), (-1.0, [0.5, 1.0, 1.0]), (0.0, [0.0, 0.5, 1.0])]:
        lengths = m.with_pinned(np.nonzero(x <= pinned_up_to)[0]).bend_length
        for k, x0 in enumerate((-2.0, -1.0, 0.0)):
            assert np.all(lengths[along & (first == x0)] == expect[k])
    assert np.all(m.with_pinned([0]).bend_length == 1.0)


@pytest.mark.slow
@pytest.mark.parametrize("direction", ["warp", "weft"])
def test_a_clamped_strip_bends_to_the_heavy_elastica_at_second_order(direction):
    """The cantilever bending test: a wool strip clamped horizontally, 4 cm beyond the clamp, hangs its
    tip as the continuum heavy elastica says (an ODE with the material's M(K), solved here to 1e-10):
    within 3 % at σ = 0.5 cm, and the error falls at second order, by 3.5–4.5× each time σ halves
    over σ = 1, 0.5, 0.25 (measured 3.66 and 3.78 warp, 3.44 and 3.77 weft; counting a clamp's joint
    as bending over a whole σ gave first order, about 2×, and 7.9 % at σ = 0.5)."""
    from cloth_gym.scenes.cantilever import (cantilever_strip, cantilever_tip_drop, heavy_elastica_tip_drop,
                                             settle_cantilever)

    ref = heavy_elastica_tip_drop("thin_wool", 4.0, direction)
    assert 3.0 < ref < 3.7  # a strip 4 cm long droops most of its length: far from the linear regime
    errors = []
    for sigma in (1.0, 0.5, 0.25):
        m = cantilever_strip("thin_wool", 4.0, sigma, direction=direction)
        state = settle_cantilever(m)
        assert np.abs(state.particle_qd).max() < 1e-6  # at rest
        errors.append(cantilever_tip_drop(m, state) / ref - 1.0)
    assert abs(errors[1]) < 0.03
    for coarse, fine in zip(errors, errors[1:]):
        assert 3.3 < coarse / fine < 4.5
