import numpy as np
import pytest

from cloth_gym import ConfigError
from cloth_gym.sim import Disc, Rectangle, Ribbon, build_cloth


def test_rectangle_topology_counts():
    nx, ny = 5, 4  # 2.0 x 1.5 cm at sigma 0.5
    m = build_cloth(Rectangle(2.0, 1.5), "thick_cotton", sigma=0.5)
    assert m.particle_count == nx * ny
    assert len(m.edge_indices) == (nx - 1) * ny + nx * (ny - 1)
    assert np.sum(m.edge_dir == 0) == (nx - 1) * ny
    assert len(m.bend_indices) == (nx - 2) * ny + nx * (ny - 2)
    # shear corners: each particle has (#warp nbrs) x (#weft nbrs)
    deg_i = np.array([2] * (nx - 2) + [1, 1])
    deg_j = np.array([2] * (ny - 2) + [1, 1])
    assert len(m.shear_indices) == deg_i.sum() * deg_j.sum()
    assert len(m.tri_indices) == 2 * (nx - 1) * (ny - 1)
    assert np.isclose(m.particle_mass.sum(), 0.01576 * 2.0 * 1.5)  # W × area


def test_warp_along_first_axis_and_rest_lengths():
    m = build_cloth(Rectangle(3.0, 2.0), "thin_wool", sigma=0.5)
    x = m.particle_q0
    d = x[m.edge_indices[:, 1]] - x[m.edge_indices[:, 0]]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 0.5)
    np.testing.assert_allclose(np.abs(d[m.edge_dir == 0]), [[0.5, 0, 0]] * int(np.sum(m.edge_dir == 0)))
    np.testing.assert_allclose(np.abs(d[m.edge_dir == 1]), [[0, 0.5, 0]] * int(np.sum(m.edge_dir == 1)))
    # bend triples are straight lines along their direction; shear corners are right angles
    a, b, c = (x[m.bend_indices[:, k]] for k in range(3))
    np.testing.assert_allclose(b - a, c - b)
    a, b, c = (x[m.shear_indices[:, k]] for k in range(3))
    np.testing.assert_allclose(np.sum((a - b) * (c - b), axis=1), 0.0)
    assert np.all(np.abs((a - b)[:, 1]) == 0) and np.all(np.abs((c - b)[:, 0]) == 0)


def test_triangles_alternate_diagonals_and_face_up():
    m = build_cloth(Rectangle(2.0, 2.0), "thick_cotton", sigma=0.5)
    x = m.particle_q0
    t = m.tri_indices
    n = np.cross(x[t[:, 1]] - x[t[:, 0]], x[t[:, 2]] - x[t[:, 0]])
    assert np.all(n[:, 2] > 0)
    np.testing.assert_allclose(np.abs(n[:, 2]).sum() / 2, 4.0)  # area 2 x 2 cm
    # the mesh uses both diagonal directions equally often
    diag = []
    for tri in t:
        g = m.particle_grid[tri]
        for u in range(3):
            dv = g[(u + 1) % 3] - g[u]
            if abs(dv[0]) == 1 and abs(dv[1]) == 1:
                diag.append(int(dv[0] * dv[1]))
    assert diag.count(1) == diag.count(-1) > 0


def test_disc_and_ribbon():
    m = build_cloth(Disc(10.0), "thick_cotton", sigma=0.5)
    r = np.linalg.norm(m.particle_q0[:, :2], axis=1)
    assert r.max() <= 5.0 + 1e-9
    np.testing.assert_allclose(m.particle_q0.mean(axis=0), 0.0, atol=1e-12)
    area = np.abs(np.cross(*(m.particle_q0[m.tri_indices[:, k]] - m.particle_q0[m.tri_indices[:, 0]]
                             for k in (1, 2)))[:, 2]).sum() / 2
    assert 0.9 * np.pi * 25 < area < np.pi * 25
    rib = build_cloth(Ribbon(30.0, 3.0), "thin_wool", sigma=1.0)
    assert rib.grid_index.shape == (31, 4)


def test_placement_rotation_and_origin():
    R = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], dtype=float)  # local weft (y) -> world z
    m = build_cloth(Rectangle(2.0, 2.0), "thick_cotton", sigma=1.0, origin=(1, 2, 30), rotation=R)
    assert np.allclose(m.particle_q0.mean(axis=0), [1, 2, 30])
    weft = m.edge_indices[m.edge_dir == 1]
    d = m.particle_q0[weft[:, 1]] - m.particle_q0[weft[:, 0]]
    np.testing.assert_allclose(d, [[0, 0, 1.0]] * len(d))


def test_model_arrays_read_only_and_state_independent():
    m = build_cloth(Rectangle(2.0, 2.0), "thick_cotton", sigma=1.0)
    with pytest.raises(ValueError):
        m.particle_q0[0, 0] = 5.0
    s = m.state()
    s.particle_q[0, 0] = 5.0
    assert m.particle_q0[0, 0] != 5.0
    s2 = s.copy()
    s2.particle_q[1, 1] = 7.0
    assert s.particle_q[1, 1] != 7.0


def test_pinned():
    m = build_cloth(Rectangle(2.0, 2.0), "thick_cotton", sigma=1.0, pinned=[0, 2])
    assert list(np.nonzero(m.pinned)[0]) == [0, 2]
    m2 = m.with_pinned(m.corners())
    assert m2.pinned.sum() == 4 and m.pinned.sum() == 2
    with pytest.raises(ConfigError, match="pinned"):
        m.with_pinned([99])
    assert m.index(-1, -1) == m.particle_count - 1


@pytest.mark.parametrize("kwargs, field", [
    (dict(sigma=-1.0), "sigma"),
    (dict(sigma=float("nan")), "sigma"),
    (dict(sigma=0.7), "Rectangle.warp_cm"),
    (dict(rotation=np.diag([1.0, 1.0, -1.0])), "rotation"),
    (dict(origin=(0, 0)), "origin"),
])
def test_bad_lattice_input(kwargs, field):
    with pytest.raises(ConfigError) as info:
        build_cloth(Rectangle(2.0, 2.0), "thick_cotton", **{"sigma": 0.5, **kwargs})
    assert info.value.field == field
