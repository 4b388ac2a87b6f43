"""Contact that holds: no step the API accepts puts a particle through an obstacle, cloth pushed
into one by the strain limiter or the collision pass is put back, a start state inside one is
refused naming the particle, and strain past the model's guard is a divergence."""

import gymnasium as gym
import numpy as np
import pytest

import cloth_gym  # noqa: F401  (registers the env ids)
from cloth_gym import ConfigError, InsideObstacle, SimulationDiverged
from cloth_gym.sim import ForceOptions, Rectangle, SymplecticEuler, build_cloth
from cloth_gym.sim.implicit import ImplicitEuler
from cloth_gym.sim.model import STRAIN_GUARD_PERCENT
from cloth_gym.sim.obstacles import (Box, Cylinder, Plane, Sphere, collide_particles, keep_outside, pack_obstacles,
                                     signed_distance)


THICKNESS = 0.1


def _collide(ob, start, end):
    """One particle moved from ``start`` to ``end`` in a step of 1 s against obstacle ``ob``."""
    types, params, mu = pack_obstacles([ob], 0.0)
    x = np.array([end], dtype=float)
    v = np.array(end, dtype=float)[None, :] - np.array(start, dtype=float)[None, :]
    touching = -np.ones(1, dtype=np.int64)
    collide_particles(x, v, np.array([start], dtype=float), np.ones(1), types, params, mu, 0.0, THICKNESS,
                      touching, np.zeros((1, 3)), 1.0)
    return x[0], v[0], touching[0]


# a segment straight through the middle of each shape, far longer than the shape is thick, the
# entry point (at the contact thickness) worked out by hand, and a segment that passes it by
# 0.05 cm more than the thickness
THROUGH = [
    (Box((0, 0, 0), (5, 5, 0.5)), (1, 2, 300), (1, 2, -300), (1, 2, 0.5 + THICKNESS), (1, 5.0 + THICKNESS + 0.05)),
    (Sphere((0, 0, 0), 1.0), (0, 0, 400), (0, 0, -400), (0, 0, 1 + THICKNESS), (1 + THICKNESS + 0.05, 0)),
    (Cylinder((0, 0, 2), 3.0, 0.5), (0, 1, 500), (0, 1, -500), (0, 1, 2 + THICKNESS), (3 + THICKNESS + 0.05, 0)),
    (Plane((0, 0, 0), (0, 0, 1)), (0, 0, 1e4), (0, 0, -1e4), (0, 0, THICKNESS), None),
]


@pytest.mark.parametrize("ob, start, end, entry, beside", THROUGH, ids=["box", "sphere", "cylinder", "plane"])
def test_a_step_through_a_thin_shape_stops_at_its_entry(ob, start, end, entry, beside):
    """Hundreds of cm in one step through a shape 1–2 cm thick: the particle stops where its path first
    comes within the contact thickness (8 samples along the path would all miss the shape), and its
    velocity into the surface is gone; the same path moved sideways to pass the shape by 0.05 cm more
    than the thickness is left alone."""
    x, v, touching = _collide(ob, start, end)
    np.testing.assert_allclose(x, entry, atol=1e-9)
    t, prm, _ = pack_obstacles([ob], 0.0)
    d, *n = signed_distance(t[0], prm[0], *x)
    assert touching == 0 and np.dot(v, n) >= 0.0
    if beside is not None:
        start, end = (*beside, start[2]), (*beside, end[2])
        x, v, touching = _collide(ob, start, end)
        np.testing.assert_array_equal(x, end)
        assert touching == -1


@pytest.mark.parametrize("max_dt", [0.5, 10.0])  # 10 s: the largest max_dt ImplicitEuler accepts
def test_a_cloth_on_a_thin_box_rests_on_it_at_the_largest_steps(max_dt):
    """A cloth dropped onto a 4 cm thick box top with implicit steps of 0.5 s and 10 s (the first step's
    free fall alone is 245 cm and 981 m) lands on it and stays there."""
    m = build_cloth(Rectangle(20, 20), "thick_cotton", sigma=2.0, origin=(0, 0, 20),
                    obstacles=[Box((0, 0, 0), (25, 25, 2))])
    s = m.state()
    integ = ImplicitEuler(max_dt=max_dt)
    for _ in range(3):
        integ.step(m, s, None, max_dt)
        np.testing.assert_allclose(s.particle_q[:, 2], 2.0 + m.contact_thickness, atol=1e-9)


def test_keep_outside_puts_back_only_particles_inside():
    """Hand values: a particle 0.3 cm under the floor moving down goes onto the surface with its
    downward velocity removed; one inside the contact thickness (above the surface) is left alone."""
    types, params, _ = pack_obstacles([Plane()], 0.3)
    x = np.array([[1.0, 2.0, -0.3], [0.0, 0.0, 0.05], [0.0, 0.0, -0.2]])
    v = np.array([[3.0, 0.0, -4.0], [0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    touching = -np.ones(3, dtype=np.int64)
    inv_mass = np.array([1.0, 1.0, 0.0])  # the third is pinned: the simulator does not move it
    assert keep_outside(x, v, inv_mass, types, params, np.zeros((1, 3)), touching) == 1
    np.testing.assert_array_equal(x, [[1.0, 2.0, 0.0], [0.0, 0.0, 0.05], [0.0, 0.0, -0.2]])
    np.testing.assert_array_equal(v, [[3.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    np.testing.assert_array_equal(touching, [0, -1, -1])


def _edge_strain_percent(model, q):
    e = model.edge_indices
    return 100.0 * (np.linalg.norm(q[e[:, 1]] - q[e[:, 0]], axis=1) / model.edge_rest_length - 1.0)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_ribbon_pressed_into_the_floor_stays_above_it(seed):
    """RibbonDrop with the gripper driven down into the floor and dragged about at random for 6 s, the
    ribbon piling up under it (self-collision on): every particle stays above the floor, and every
    observation the env returns is within the strain guard (an episode past it ends truncated with
    ``info["diverged"]``). Self-collision used to push the lower layers of the pile up to 0.66 cm into
    the floor, stretching an edge by 584 % (seed 2)."""
    env = gym.make("cloth_gym/RibbonDrop-v0")
    env.reset(seed=seed)
    physics = env.unwrapped.physics
    rng = np.random.default_rng(seed)
    for _ in range(120):
        action = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), -1.0, 1.0], dtype=np.float32)
        obs, _, _, truncated, info = env.step(action)
        assert np.all(np.isfinite(obs))
        if info["diverged"]:
            assert truncated
            break
        q = physics.state.particle_q
        assert q[:, 2].min() >= -physics.model.contact_thickness
        assert _edge_strain_percent(physics.model, q).max() <= STRAIN_GUARD_PERCENT["kes"]
    assert physics.grippers.position[0, 2] <= 1.0  # it did press down to the floor


def test_a_cloth_started_inside_a_box_is_refused_naming_the_particle():
    """A cloth laid through a box: InsideObstacle names the deepest particle (one of the cloth's, at the
    box's centre), the box and the depth, and the state is left as it was."""
    box = Box((0, 0, 0), (5, 5, 2))
    m = build_cloth(Rectangle(20, 20), "thick_cotton", sigma=2.0, origin=(0, 0, 0), obstacles=[Plane((0, 0, -10)), box])
    s = m.state()
    q0 = s.particle_q.copy()
    for integ in (ImplicitEuler(), SymplecticEuler(on_unstable="substep")):
        with pytest.raises(InsideObstacle) as err:
            integ.step(m, s, None, 1e-3)
        e = err.value
        assert 0 <= e.particle < m.particle_count and e.obstacle == 1 and "Box" in str(e)
        t, prm, _ = pack_obstacles([box], 0.0)
        assert signed_distance(t[0], prm[0], *s.particle_q[e.particle])[0] == pytest.approx(-e.depth_cm)
        assert e.depth_cm == pytest.approx(2.0)  # the box's half height: the deepest any particle is
        np.testing.assert_array_equal(s.particle_q, q0)


def test_a_cloth_started_within_the_thickness_is_pushed_out():
    """0.05 cm into a table top (less than the 0.1 cm contact thickness) is contact, not an error."""
    m = build_cloth(Rectangle(10, 10), "thick_cotton", sigma=2.0, origin=(0, 0, 1.95),
                    obstacles=[Box((0, 0, 0), (20, 20, 2))])
    s = m.state()
    ImplicitEuler().step(m, s, None, 1e-2)
    assert s.particle_q[:, 2].min() >= 2.0


def _stretched(model_kind):
    """A 2 × 2 cm cloth with one corner pulled 3 cm out (an edge at 300 % strain), gravity off."""
    m = build_cloth(Rectangle(2, 2), "thick_cotton", sigma=1.0,
                    options=ForceOptions(model=model_kind, gravity=False, air=False))
    s = m.state()
    s.particle_q[0] += (-3.0, 0.0, 0.0)
    return m, s


def test_strain_past_the_kes_guard_is_a_divergence():
    """One linearised pass leaves the 300 % edge past the KES model's 100 % guard: a divergence.
    Solved to convergence (``retry_diverged``, the default, runs the call again so), backward
    Euler relaxes so stiff an edge within the step, and the call goes on."""
    m, s = _stretched("kes")
    assert m.strain_guard_percent == 100.0
    with pytest.raises(SimulationDiverged) as err:
        ImplicitEuler(max_dt=1e-4, retry_diverged=False).step(m, s, None, 1e-4)
    assert err.value.reason == "strain" and err.value.value > 100.0 and 0 <= err.value.particle < m.particle_count
    m, s = _stretched("kes")
    ImplicitEuler(max_dt=1e-4, max_strain_percent=1000.0, retry_diverged=False).step(m, s, None, 1e-4)  # own guard
    m, s = _stretched("kes")
    integ = ImplicitEuler(max_dt=1e-4)
    integ.step(m, s, None, 1e-4)
    assert integ.retried and _edge_strain_percent(m, s.particle_q).max() < 100.0


def test_breens_model_has_no_strain_guard():
    """Breen's springs stretch by design: 300 % strain is not a divergence."""
    m, s = _stretched("breen")
    assert m.strain_guard_percent is None
    ImplicitEuler(max_dt=1e-4).step(m, s, None, 1e-4)
    assert _edge_strain_percent(m, s.particle_q).max() > 100.0


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 2, 3])
def test_a_ribbon_thrown_at_the_floor_at_5_m_s_stays_bounded_with_self_collision(seed):
    """RibbonDrop's ribbon and integrator (self-collision on, 10 ms substeps, the largest any env takes
    with self-collision, and its 1 % limiter) thrown at the floor at 500 cm/s, sideways up to 150 cm/s:
    it lands and folds onto itself with every edge far inside the strain guard (measured: at most
    16 % over seeds 0–5; 60 % at 20 ms substeps) and every particle above the floor."""
    env = gym.make("cloth_gym/RibbonDrop-v0")
    env.reset(seed=seed)
    physics = env.unwrapped.physics
    model, integ = physics.model, physics.integrator
    state = model.state()  # free: no gripper
    state.particle_q[:] = physics.state.particle_q
    rng = np.random.default_rng(seed)
    state.particle_qd[:] = (rng.uniform(-150, 150), rng.uniform(-150, 150), -500.0)
    worst = 0.0
    for _ in range(20):
        integ.step(model, state, None, 0.05)
        worst = max(worst, _edge_strain_percent(model, state.particle_q).max())
        assert state.particle_q[:, 2].min() >= 0.0
    assert worst < 30.0


def test_a_cloth_resting_at_zero_thickness_is_not_refused():
    """Contact leaves particles within round-off (~1e-16 cm) of a surface, on its inside too; with a
    contact thickness of 0 that must not read as a start inside the obstacle on the next call."""
    m = build_cloth(Rectangle(10, 10), "thick_cotton", sigma=1.0, origin=(0, 0, 4.0),
                    obstacles=[Plane((0, 0, 0), (0.3, 0.1, 1.0)), Sphere((0, 0, -30), 29.5)], contact_thickness=0.0)
    for integ in (ImplicitEuler(max_dt=1e-2), SymplecticEuler(on_unstable="substep")):
        s = m.state()
        for _ in range(40):
            integ.step(m, s, None, 1e-2)


def test_tunnelling_search_rejects_sliding_paths_without_searching():
    """A particle sliding along just above a plane or a box top, its path parallel to the surface: the
    samples' convexity bound rejects the path (exact for a plane), so it is left where it went."""
    for ob in (Plane((0, 0, 0), (0, 0, 1)), Box((0, 0, -1), (50, 50, 1))):
        start, end = (-3.0, 0.0, 1.05 * THICKNESS), (3.0, 0.5, 1.05 * THICKNESS)
        x, v, touching = _collide(ob, start, end)
        np.testing.assert_array_equal(x, end)
        assert touching == -1


def test_a_strain_limiter_at_or_above_the_guard_is_refused():
    m = build_cloth(Rectangle(2, 2), "thick_cotton", sigma=1.0)
    with pytest.raises(ConfigError, match="strain_limit_percent"):
        ImplicitEuler(strain_limit_percent=150.0).step(m, m.state(), None, 1e-3)
    ImplicitEuler(strain_limit_percent=150.0, max_strain_percent=1000.0).step(m, m.state(), None, 1e-3)
