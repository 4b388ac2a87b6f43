"""Static obstacles: distances, continuous detection, resting contact, friction."""

import math

import numpy as np
import pytest

from cloth_gym import ConfigError
from cloth_gym.sim import Rectangle, SymplecticEuler, build_cloth
from cloth_gym.sim.implicit import ImplicitEuler
from cloth_gym.sim.obstacles import Box, Cylinder, Plane, Sphere, pack_obstacles, signed_distance

from conftest import only


def _sd(ob, p):
    t, prm, _ = pack_obstacles([ob], 0.3)
    return signed_distance(t[0], prm[0], *p)


@pytest.mark.parametrize("ob, point, d, n", [
    (Plane((0, 0, 1), (0, 0, 2)), (3, 4, 5), 4.0, (0, 0, 1)),
    (Sphere((1, 1, 1), 2.0), (1, 1, 5), 2.0, (0, 0, 1)),
    (Sphere((0, 0, 0), 2.0), (0, 1, 0), -1.0, (0, 1, 0)),
    (Box((0, 0, -1), (10, 10, 1)), (0, 0, 0.5), 0.5, (0, 0, 1)),
    (Box((0, 0, -1), (10, 10, 1)), (13, 14, -1), 5.0, (0.6, 0.8, 0)),
    (Box((0, 0, -1), (10, 10, 1)), (9.5, 0, -1), -0.5, (1, 0, 0)),
    (Cylinder((0, 0, 0), 5.0, 20.0), (0, 0, 2), 2.0, (0, 0, 1)),
    (Cylinder((0, 0, 0), 5.0, 20.0), (8, 0, -3), 3.0, (1, 0, 0)),
    (Cylinder((0, 0, 0), 5.0, 20.0), (8, 0, 4), 5.0, (0.6, 0, 0.8)),
])
def test_signed_distance_hand_values(ob, point, d, n):
    got = _sd(ob, point)
    assert math.isclose(got[0], d, abs_tol=1e-12)
    np.testing.assert_allclose(got[1:], n, atol=1e-12)


def test_bad_obstacles():
    with pytest.raises(ConfigError, match="Box.half_extents"):
        pack_obstacles([Box((0, 0, 0), (1, -1, 1))], 0.3)
    with pytest.raises(ConfigError, match="Sphere.radius"):
        pack_obstacles([Sphere((0, 0, 0), float("nan"))], 0.3)
    with pytest.raises(ConfigError, match="obstacles"):
        pack_obstacles(["table"], 0.3)


@pytest.mark.parametrize("integrator", ["explicit", "implicit"])
def test_drop_from_two_metres_onto_thin_table_does_not_tunnel(integrator):
    """A small cloth falls 2 m (6.3 m/s at impact, several cm per step) onto a 1 cm thick table top."""
    table = Box((0, 0, -0.5), (20, 20, 0.5))
    m = build_cloth(Rectangle(4.0, 4.0), "thin_wool", sigma=1.0, origin=(0, 0, 200.0), obstacles=[table],
                    options=only(gravity=True, stretch=True, bending=True, shear=True, damping=True))
    s = m.state()
    integ = SymplecticEuler(on_unstable="substep") if integrator == "explicit" else ImplicitEuler(max_dt=5e-3)
    lowest = math.inf
    for _ in range(150):
        integ.step(m, s, None, 1e-2)
        lowest = min(lowest, s.particle_q[:, 2].min())
    assert lowest >= m.contact_thickness - 1e-9
    np.testing.assert_allclose(s.particle_q[:, 2], m.contact_thickness, atol=0.05)  # at rest on the top


@pytest.mark.parametrize("angle_deg, slides", [(10.0, False), (30.0, True)])
def test_friction_on_tilted_plane(angle_deg, slides):
    """μ = 0.3 (atan μ = 16.7°): a cloth lying on a plane tilted below that angle stays, above it slides."""
    a = math.radians(angle_deg)
    normal = (math.sin(a), 0.0, math.cos(a))
    R = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    plane = Plane((0, 0, 0), normal, friction=0.3)
    m = build_cloth(Rectangle(4.0, 4.0), "thin_wool", sigma=1.0, rotation=R,
                    origin=0.1 * np.array(normal), obstacles=[plane],
                    options=only(gravity=True, stretch=True, bending=True, shear=True))
    s = m.state()
    SymplecticEuler(on_unstable="substep").advance(m, s, None, 0.5, 1e-2)
    moved = np.linalg.norm(s.particle_q - m.particle_q0, axis=1).mean()
    if slides:
        # sliding: distance ½·g(sin a − μ cos a)·t²
        expected = 0.5 * 978.8 * (math.sin(a) - 0.3 * math.cos(a)) * 0.25
        assert abs(moved - expected) < 0.01 * expected
    else:
        assert moved < 0.01
