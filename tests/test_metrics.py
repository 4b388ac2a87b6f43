"""Drape metrics: shadow area, drape coefficient, outline and node count, force fields, settle time."""

import math

import numpy as np
import pytest

from cloth_gym.errors import ConfigError
from cloth_gym.metrics import (cloth_rest_area, cloth_shadow_area, drape_coefficient, drape_coefficient_from_area,
                               force_fields, force_vectors, node_count, outline_angles, outline_radius, settle_time,
                               shadow_area)
from cloth_gym.sim import Disc, Rectangle, build_cloth, compute_forces
from conftest import only


def fan(R, m=720, center=(0.0, 0.0)):
    """Points on a circle of radius R (cm) plus its centre, and the fan of triangles between them."""
    th = 2 * np.pi * np.arange(m) / m
    pts = np.r_[[center], np.c_[center[0] + R * np.cos(th), center[1] + R * np.sin(th)]]
    tris = np.array([[0, 1 + k, 1 + (k + 1) % m] for k in range(m)])
    return pts, tris


# ------------------------------------------------------------------ shadow area / drape coefficient
def test_circle_shadow_area_and_hand_computed_dc():
    R, h = 10.0, 0.05
    pts, tris = fan(R)
    a = shadow_area(pts, tris, resolution_cm=h)
    assert a == pytest.approx(math.pi * R * R, abs=2 * math.pi * R * h / 2)  # perimeter × h/2
    # DC = (πR² − πr²)/(A − πr²) with A = π·15², r = 5: 75/200
    dc = drape_coefficient_from_area(a, math.pi * 15 ** 2, 5.0)
    assert dc == pytest.approx(0.375, abs=0.005)
    # coarser grid, same answer within its error
    assert shadow_area(pts, tris, resolution_cm=0.5) == pytest.approx(math.pi * R * R, abs=2 * math.pi * R * 0.25)


def test_shadow_is_a_union_not_a_sum_nor_a_hull():
    tri = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])
    one = shadow_area(tri, [[0, 1, 2]], 0.01)
    assert one == pytest.approx(8.0, rel=0.01)
    assert shadow_area(np.r_[tri, tri], [[0, 1, 2], [3, 4, 5]], 0.01) == pytest.approx(one)  # overlap once
    far = np.r_[tri, tri + 20.0]
    assert shadow_area(far, [[0, 1, 2], [3, 4, 5]], 0.01) == pytest.approx(2 * one)  # no convex hull
    # a rectangle folded in half along x = 0 shades half its area
    m = build_cloth(Rectangle(10.0, 6.0), sigma=0.5)
    s = m.state()
    fold = s.particle_q[:, 0] > 0
    s.particle_q[fold, 0] *= -1
    s.particle_q[fold, 2] += 0.5
    assert cloth_shadow_area(m, s, 0.02) == pytest.approx(30.0, rel=0.02)
    # z is ignored
    assert shadow_area(np.c_[tri, [1.0, 5.0, -3.0]], [[0, 1, 2]], 0.01) == pytest.approx(one)


def test_flat_disc_drape_coefficient_is_one():
    model = build_cloth(Disc(30.0), sigma=0.5)
    state = model.state()
    assert cloth_rest_area(model) == pytest.approx(math.pi * 15 ** 2, rel=0.05)
    for dz in (0.0, 25.0):  # height does not matter
        state.particle_q[:, 2] = dz
        assert drape_coefficient(model, state, pedestal_radius_cm=9.0) == pytest.approx(1.0, abs=0.01)
    # shifted disc, pedestal centre given explicitly
    state.particle_q[:, :2] += (3.0, -2.0)
    assert drape_coefficient(model, state, 9.0, center_xy=(3.0, -2.0)) == pytest.approx(1.0, abs=0.01)
    # a draped disc (outer ring pulled towards the centre) has DC < 1
    s2 = model.state()
    r = np.linalg.norm(s2.particle_q[:, :2], axis=1)
    out = r > 9.0
    s2.particle_q[out, :2] *= (9.0 + 0.5 * (r[out] - 9.0))[:, None] / r[out, None]
    dc = drape_coefficient(model, s2, 9.0)
    assert 0.3 < dc < 0.7
    with pytest.raises(ConfigError) as e:
        drape_coefficient(model, state, pedestal_radius_cm=20.0)
    assert e.value.field == "pedestal_radius_cm"


# ------------------------------------------------------------------ outline and nodes
def test_outline_radius_of_a_circle():
    R = 7.0
    pts, _ = fan(R, m=720, center=(2.0, -1.0))
    r = outline_radius(pts[1:], center_xy=(2.0, -1.0), n_bins=360)
    assert r.shape == (360,)
    np.testing.assert_allclose(r, R, rtol=1e-12)
    # 8 points: empty bins are interpolated; with the polygon's edges the chords are seen
    th = 2 * np.pi * (np.arange(8) + 0.25) / 8
    oct_ = np.c_[R * np.cos(th), R * np.sin(th)]
    np.testing.assert_allclose(outline_radius(oct_, (0.0, 0.0)), R, rtol=1e-12)
    edges = np.array([[k, (k + 1) % 8] for k in range(8)])
    re = outline_radius(oct_, (0.0, 0.0), edges=edges)
    assert re.max() == pytest.approx(R) and re.min() == pytest.approx(R * math.cos(math.pi / 8), rel=2e-3)
    # the angle convention: a bump towards +y lands in the bins around θ = π/2
    bump = np.r_[pts[1:], [[2.0, -1.0 + 2 * R]]]
    k = int(np.argmax(outline_radius(bump, (2.0, -1.0))))
    assert abs(outline_angles()[k] - math.pi / 2) < 2 * math.pi / 360


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_node_count_of_noisy_cosines(seed):
    rng = np.random.default_rng(seed)
    th = outline_angles(360)
    R, a = 12.0, 1.5
    for n in range(3, 13):
        r = R + a * np.cos(n * th + rng.uniform(0, 2 * np.pi)) + 0.1 * a * rng.standard_normal(th.size)
        assert node_count(r) == n, n
    assert node_count(np.full(360, R)) == 0


def test_node_count_of_a_draped_outline():
    """Separate folds of unequal height and width (not a cosine) are all counted."""
    th = outline_angles(360)
    rng = np.random.default_rng(7)
    for n in (5, 7, 9):
        centres = rng.uniform(0, 2 * np.pi) + np.arange(n) * 2 * np.pi / n + rng.uniform(-0.1, 0.1, n)
        r = np.full(th.size, 10.0)
        for c, height, width in zip(centres, rng.uniform(1.5, 3.0, n), rng.uniform(0.1, 0.2, n)):
            d = np.angle(np.exp(1j * (th - c)))
            r += height * np.exp(-0.5 * (d / width) ** 2)
        r += 0.1 * rng.standard_normal(th.size)
        assert node_count(r) == n


# ------------------------------------------------------------------ force fields
def test_force_fields_of_a_stretched_cloth():
    model = build_cloth(Rectangle(4.0, 3.0), sigma=0.5, options=only(stretch=True, bending=True, shear=True))
    s = model.state()
    s.particle_q[:, 0] *= 1.1  # stretched along the warp, still flat and square
    ff = force_fields(model, s)
    assert set(ff) == {"stretch", "bending", "shear"}
    assert all(v.shape == (model.particle_count,) for v in ff.values())
    assert ff["stretch"].max() > 0
    assert np.all(ff["bending"] == 0) and np.all(ff["shear"] == 0)


@pytest.mark.parametrize("law", ["kes", "breen"])
def test_force_fields_sum_to_the_internal_force(law, rng):
    base = build_cloth(Rectangle(4.0, 3.0), sigma=0.5)
    s = base.state()
    s.particle_q += rng.normal(0, 0.05, s.particle_q.shape)
    s.particle_qd += rng.normal(0, 5.0, s.particle_qd.shape)  # must not matter (damping/air off)
    internal = build_cloth(Rectangle(4.0, 3.0), sigma=0.5, options=only(stretch=True, bending=True, shear=True,
                                                                          model=law))
    total = compute_forces(internal, s)
    fv = force_vectors(internal, s)
    assert all(np.abs(f).max() > 0 for f in fv.values())
    np.testing.assert_allclose(fv["stretch"] + fv["bending"] + fv["shear"], total, rtol=1e-12,
                               atol=1e-9 * np.abs(total).max())
    # the full model (gravity, air, damping on) gives the same internal fields
    full = build_cloth(Rectangle(4.0, 3.0), sigma=0.5, options=only(stretch=True, bending=True, shear=True,
                                                                      gravity=True, air=True, damping=True,
                                                                      model=law))
    for k, v in force_fields(full, s).items():
        np.testing.assert_array_equal(v, np.linalg.norm(fv[k], axis=1))
    # a force switched off in the model's options is zero
    no_bend = build_cloth(Rectangle(4.0, 3.0), sigma=0.5, options=only(stretch=True, shear=True, model=law))
    assert np.all(force_fields(no_bend, s)["bending"] == 0)


# ------------------------------------------------------------------ settle time
def test_settle_time_of_a_decaying_series():
    t = np.linspace(0.0, 5.0, 501)
    ke = 100.0 * np.exp(-2.0 * t) * (1 + 0.5 * np.cos(20 * t))  # decaying, oscillating
    thr = 1.0
    ts = settle_time(ke, t, thr)
    k = int(np.searchsorted(t, ts))
    assert np.all(ke[k:] < thr) and ke[k - 1] >= thr
    # the envelope 150·e^(−2t) crosses 1 at ln(150)/2; the last peak above it is within a period (π/10 s)
    assert math.log(150.0) / 2.0 - math.pi / 10 <= ts <= math.log(150.0) / 2.0
    assert settle_time(ke, t, 1e-9) is None
    assert settle_time(ke, t, 1e9) == 0.0
    with pytest.raises(ConfigError) as e:
        settle_time(ke, t[:-1], thr)
    assert e.value.field == "times"


def test_bad_input_names_the_field():
    pts, tris = fan(5.0, m=16)
    cases = [
        (lambda: shadow_area(pts[:, :1], tris), "points_xy"),
        (lambda: shadow_area(pts, tris + 100), "tris"),
        (lambda: shadow_area(pts, tris, resolution_cm=0.0), "resolution_cm"),
        (lambda: shadow_area(pts * [1, np.nan], tris), "points_xy"),
        (lambda: drape_coefficient_from_area(10.0, 5.0, 3.0), "pedestal_radius_cm"),
        (lambda: outline_radius(pts, n_bins=2), "n_bins"),
        (lambda: outline_radius(pts, center_xy=(0.0,)), "center_xy"),
        (lambda: node_count(np.ones(4)), "r_theta"),
        (lambda: node_count(np.ones(64), rel_prominence=0.0), "rel_prominence"),
    ]
    for fn, field in cases:
        with pytest.raises(ConfigError) as e:
            fn()
        assert e.value.field == field, (field, e.value)
