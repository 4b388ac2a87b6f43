"""Headless renderer: exact coverage, depth test, interpolation, determinism, scene, files, bad input."""

import numpy as np
import pytest

from cloth_gym.errors import ConfigError
from cloth_gym.render import Camera, Renderer, colormap, save_gif, save_mp4, save_png
from cloth_gym.render.raster import coverage_count
from cloth_gym.sim import Rectangle, build_cloth
from cloth_gym.sim.obstacles import Box

W = H = 20
BG = (255, 255, 255)


def top_down(half_height=10.0):
    """Orthographic camera looking down −z with world +y up the image: 1 px per cm for a 20 px image,
    world (x, y) ↦ pixel (px, py) = (10 + x, 10 − y)."""
    return Camera.look_at((0, 0, 100), (0, 0, 0), up=(0, 1, 0), ortho_half_height=half_height)


def flat(width=W, height=H, **kw):
    return Renderer(width, height, camera=top_down(), background=BG, ambient=1.0, **kw)


def pixel_centres_world(width=W, height=H):
    """World (x, y) of every pixel centre under :func:`top_down` (1 px per cm)."""
    r, c = np.mgrid[0:height, 0:width]
    return c + 0.5 - width / 2, height / 2 - (r + 0.5)


def inside_strict(px, py, tri):
    """Independent point-in-triangle test (sign of the three cross products, strictly inside)."""
    (ax, ay), (bx, by), (cx, cy) = tri
    d1 = (px - bx) * (ay - by) - (ax - bx) * (py - by)
    d2 = (px - cx) * (by - cy) - (bx - cx) * (py - cy)
    d3 = (px - ax) * (cy - ay) - (cx - ax) * (py - ay)
    neg = (d1 < 0) | (d2 < 0) | (d3 < 0)
    pos = (d1 > 0) | (d2 > 0) | (d3 > 0)
    return ~(neg & pos) & (d1 != 0) & (d2 != 0) & (d3 != 0)


def test_camera_projection_conventions():
    cam = top_down()
    pix, depth = cam.project(np.array([[0.0, 0.0, 0.0], [3.0, 2.0, 5.0]]), W, H)
    np.testing.assert_allclose(pix, [[10, 10], [13, 8]])
    np.testing.assert_allclose(depth, [100, 95])
    persp = Camera.look_at((0, -50, 0), (0, 0, 0), fov_deg=90.0)
    pix, depth = persp.project(np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 10.0]]), 40, 40)
    # f = (H/2)/tan(45°) = 20 px; (x, z) = (10, 10) cm at depth 50 cm → (20 + 4, 20 − 4)
    np.testing.assert_allclose(pix, [[20, 20], [24, 16]])
    np.testing.assert_allclose(depth, [50, 50])


def test_triangle_covers_exactly_the_expected_pixels():
    tri = np.array([[-7.3, -6.1], [8.2, -3.7], [-1.9, 7.6]])  # no pixel centre on an edge
    v = np.c_[tri, np.zeros(3)]
    img = flat().render_meshes([(v, [[0, 1, 2]], (255, 0, 0))])
    x, y = pixel_centres_world()
    expected = inside_strict(x, y, tri)
    drawn = np.any(img != BG, axis=2)
    assert expected.sum() > 50
    np.testing.assert_array_equal(drawn, expected)
    assert np.all(img[drawn] == (255, 0, 0))
    # winding does not matter (two-sided)
    img2 = flat().render_meshes([(v, [[0, 2, 1]], (255, 0, 0))])
    np.testing.assert_array_equal(img2, img)


def test_shared_edges_are_drawn_once():
    """A square split by a diagonal through pixel centres, and a fan of triangles meeting at a pixel
    centre: the fill rule gives every covered pixel to exactly one triangle."""
    sx = np.array([[2.0, 12.0, 12.0], [2.0, 12.0, 2.0]])  # square [2, 12]², diagonal (2,2)-(12,12)
    sy = np.array([[2.0, 2.0, 12.0], [2.0, 12.0, 12.0]])
    cnt = coverage_count(sx, sy, 16, 16)
    assert cnt.max() == 1
    assert cnt.sum() == 100  # pixel centres 2.5 … 11.5 in both axes
    c = (8.5, 8.5)  # pixel centre shared by all fan triangles
    ang = np.linspace(0, 2 * np.pi, 9)[:-1]
    ring = np.c_[c[0] + 6 * np.cos(ang), c[1] + 6 * np.sin(ang)]
    fx = np.array([[c[0], ring[k, 0], ring[(k + 1) % 8, 0]] for k in range(8)])
    fy = np.array([[c[1], ring[k, 1], ring[(k + 1) % 8, 1]] for k in range(8)])
    cnt = coverage_count(fx, fy, 18, 18)
    assert cnt.max() == 1
    assert cnt[8, 8] == 1


def test_depth_test_keeps_the_nearer_triangle():
    tri = [[-8.0, -8.0], [8.0, -7.0], [0.0, 8.0]]
    near = (np.c_[tri, np.full(3, 5.0)], [[0, 1, 2]], (0, 0, 255))  # closer to the eye at z = 100
    far = (np.c_[tri, np.full(3, 1.0)], [[0, 1, 2]], (255, 0, 0))
    for order in ([near, far], [far, near]):
        img = flat().render_meshes(order)
        drawn = np.any(img != BG, axis=2)
        assert drawn.sum() > 50
        assert np.all(img[drawn] == (0, 0, 255))
    # crossing triangles of the same footprint: the tilted one (z = 1 + x/2) is nearer where x > 0
    tilt = (np.c_[tri, 1.0 + 0.5 * np.array(tri)[:, 0]], [[0, 1, 2]], (0, 255, 0))
    img = flat().render_meshes([tilt, far])
    x, _ = pixel_centres_world()
    drawn = np.any(img != BG, axis=2)
    left, right = drawn & (x < -0.25), drawn & (x > 0.25)
    assert left.sum() > 20 and right.sum() > 20
    assert np.all(img[left] == (255, 0, 0))
    assert np.all(img[right] == (0, 255, 0))


def test_vertex_colour_is_interpolated_at_the_centroid():
    # centroid (1.5, 1.5) cm lies on the centre of pixel (row 8, col 11) under the top-down camera
    tri = np.array([[-4.5, -1.5, 0.0], [7.5, -1.5, 0.0], [1.5, 7.5, 0.0]])
    cols = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], dtype=np.uint8)
    img = flat().render_meshes([(tri, [[0, 1, 2]], cols)])
    np.testing.assert_array_equal(img[8, 11], (85, 85, 85))  # 255/3 each
    # perspective, tilted triangle: weights at a pixel centre are the perspective-correct ones
    tri3 = tri + np.array([0.0, 0.0, 1.0]) * tri[:, :1]  # z = x: depth varies across the triangle
    cam = Camera.look_at((1.5, -20, 30), (1.5, 1.5, 1.5), fov_deg=50)
    img = Renderer(W, H, camera=cam, ambient=1.0).render_meshes([(tri3, [[0, 1, 2]], cols)])
    pix, depth = cam.project(tri3, W, H)
    r, c = (int(v) for v in np.floor(pix.mean(axis=0))[::-1])
    p = np.array([c + 0.5, r + 0.5])
    b01 = np.linalg.solve((pix[:2] - pix[2]).T, p - pix[2])
    b = np.r_[b01, 1 - b01.sum()]  # screen-space weights
    bw = (b / depth) / np.sum(b / depth)  # perspective-correct weights
    assert np.abs(bw - b).max() > 0.01  # the check below tells the two apart
    np.testing.assert_allclose(img[r, c].astype(float), bw @ cols.astype(float), atol=0.51)


def test_rendering_is_deterministic():
    rng = np.random.default_rng(0)
    meshes = [(rng.uniform(-10, 10, (30, 3)), rng.integers(0, 30, (40, 3)), rng.integers(0, 256, (30, 3)))]
    cam = Camera.look_at((30, -40, 25), (0, 0, 0))
    imgs = [Renderer(64, 48, camera=cam, ssaa=s).render_meshes(meshes) for s in (1, 1, 2, 2)]
    assert imgs[0].tobytes() == imgs[1].tobytes()
    assert imgs[2].tobytes() == imgs[3].tobytes()
    assert imgs[0].shape == imgs[2].shape == (48, 64, 3)


def test_supersampling_averages_edges():
    v = np.array([[-7.3, -6.1, 0], [8.2, -3.7, 0], [-1.9, 7.6, 0]])
    img = flat(ssaa=2).render_meshes([(v, [[0, 1, 2]], (0, 0, 0))])
    grey = np.unique(img[..., 0])
    assert 0 in grey and 255 in grey and len(grey) > 2  # partial coverage along the edges


def test_render_scene_cloth_over_box():
    box = Box(center=(0, 0, -2.0), half_extents=(4, 4, 2))
    model = build_cloth(Rectangle(12.0, 12.0), sigma=1.0, origin=(0, 0, 0.5), obstacles=[box])
    state = model.state()
    state.particle_q[:, 2] -= 0.02 * (state.particle_q[:, 0] ** 2 + state.particle_q[:, 1] ** 2)  # drooping
    red = np.tile(np.array([255, 0, 0], dtype=np.uint8), (model.particle_count, 1))
    r = Renderer(120, 90, camera=Camera.look_at((25, -35, 5), (0, 0, -1)))
    img = r.render_scene(model, state, particle_colors=red, markers=[((6, 6, 0.5), 0.8, (0, 200, 0))])
    assert img.shape == (90, 120, 3) and img.dtype == np.uint8
    cloth = (img[..., 0] > 0) & (img[..., 1] == 0) & (img[..., 2] == 0)
    grey = (img[..., 0] == img[..., 1]) & (img[..., 1] == img[..., 2]) & (img[..., 0] < 255)
    marker = (img[..., 1] > 0) & (img[..., 0] == 0)
    assert cloth.sum() > 100 and grey.sum() > 20 and marker.sum() > 0
    # default camera frames the cloth: it is in view and not cut at the borders
    img = Renderer(80, 60).render_scene(model, state)
    fg = np.any(img != 255, axis=2)
    assert fg.sum() > 200
    assert not fg[0].any() and not fg[-1].any()
    # obstacles can be hidden; the image differs
    img2 = Renderer(80, 60).render_scene(model, state, show_obstacles=False)
    assert not np.array_equal(img, img2)


def test_render_scene_draws_mesh_obstacles():
    class MeshObstacle:
        vertices = np.array([[-30.0, -30, -5], [30, -30, -5], [0, 30, -5]])
        faces = np.array([[0, 1, 2]])

    import dataclasses

    model = build_cloth(Rectangle(4.0, 4.0), sigma=1.0)
    model = dataclasses.replace(model, obstacles=(MeshObstacle(),))  # bypass packing: rendering only
    img = Renderer(40, 30, background=(0, 0, 0)).render_scene(model, model.state())
    assert np.any(img != 0, axis=2).mean() > 0.5  # the big triangle fills most of the background


def test_render_scene_draws_the_simulator_mesh_obstacle():
    trimesh = pytest.importorskip("trimesh")
    collision = pytest.importorskip("cloth_gym.sim.collision")
    ob = collision.MeshObstacle(trimesh.creation.icosphere(subdivisions=2, radius=3.0),
                                transform=trimesh.transformations.translation_matrix((0, 0, -4)))
    model = build_cloth(Rectangle(10.0, 10.0), sigma=1.0, obstacles=[ob])
    r = Renderer(60, 40, background=(0, 0, 0))
    img = r.render_scene(model, model.state(), particle_colors=(255, 0, 0))
    bare = r.render_scene(model, model.state(), particle_colors=(255, 0, 0), show_obstacles=False)
    grey = (img[..., 0] == img[..., 1]) & (img[..., 1] == img[..., 2]) & (img[..., 0] > 0)
    assert grey.sum() > 10  # the sphere below the cloth shows past its edge
    assert np.array_equal(np.any(img != bare, axis=2), grey)


def test_colormap_uses_matplotlib():
    import matplotlib

    v = np.array([0.0, 0.5, 1.0, np.nan])
    out = colormap(v, "viridis")
    assert out.shape == (4, 3) and out.dtype == np.uint8
    ref = np.round(np.asarray(matplotlib.colormaps["viridis"](np.array([0.0, 0.5, 1.0])))[:, :3] * 255)
    np.testing.assert_array_equal(out[:3], ref)
    np.testing.assert_array_equal(colormap([2.0, 3.0], vmin=0, vmax=1), np.tile(out[2], (2, 1)))  # clipped
    np.testing.assert_array_equal(colormap([1.0, 1.0]), np.tile(out[0], (2, 1)))  # zero range: low end
    with pytest.raises(ConfigError, match="name"):
        colormap(v, "no_such_map")


def test_files_round_trip(tmp_path):
    import imageio.v2 as iio2
    import imageio.v3 as iio

    rng = np.random.default_rng(1)
    frames = [np.full((24, 32, 3), 20 * k, dtype=np.uint8) for k in range(6)]
    frames = [f + rng.integers(0, 5, f.shape, dtype=np.uint8) for f in frames]
    p = save_png(tmp_path / "a" / "b" / "img.png", frames[3])
    np.testing.assert_array_equal(iio.imread(p), frames[3])
    g = save_gif(tmp_path / "gif" / "anim.gif", frames, fps=10)
    back = iio.imread(g, index=None)
    assert back.shape[0] == 6 and back.shape[1:3] == (24, 32)
    m = save_mp4(tmp_path / "mp4" / "anim.mp4", frames, fps=10)
    with iio2.get_reader(m, format="FFMPEG") as rd:
        assert rd.count_frames() == 6
        f0 = rd.get_data(0)
    assert f0.shape == (24, 32, 3)
    assert abs(float(f0.mean()) - float(frames[0].mean())) < 8  # lossy but close
    m = save_mp4(tmp_path / "odd.mp4", [f[:23, :31] for f in frames], fps=5)  # odd sizes padded
    with iio2.get_reader(m, format="FFMPEG") as rd:
        assert rd.get_data(0).shape == (24, 32, 3)


def test_bad_input_names_the_field(tmp_path):
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    r = flat()
    cases = [
        (lambda: Renderer(width=0), "width"),
        (lambda: Renderer(height=-3), "height"),
        (lambda: Renderer(ssaa=3), "ssaa"),
        (lambda: r.render_meshes([(tri[:, :2], [[0, 1, 2]], (1, 2, 3))]), "meshes[0].vertices"),
        (lambda: r.render_meshes([(np.where(tri == 1, np.nan, tri), [[0, 1, 2]], (1, 2, 3))]), "meshes[0].vertices"),
        (lambda: r.render_meshes([(tri, [[0, 1, 3]], (1, 2, 3))]), "meshes[0].faces"),
        (lambda: r.render_meshes([(tri, [[0, 1]], (1, 2, 3))]), "meshes[0].faces"),
        (lambda: r.render_meshes([(tri, [[0, 1, 2]], np.zeros((2, 3), np.uint8))]), "meshes[0].colors"),
        (lambda: r.render_meshes([(tri, [[0, 1, 2]], (300, 0, 0))]), "meshes[0].colors"),
        (lambda: Camera.look_at((0, 0, 1), (0, 0, 0), up=(0, 0, 1)), "up"),
        (lambda: Camera.look_at((0, 0, 1), (0, 0, 1)), "target"),
        (lambda: Camera.look_at((0, 0, np.inf), (0, 0, 1)), "eye"),
        (lambda: top_down().project(np.zeros((3, 3)), 0, 10), "width"),
        (lambda: save_png(tmp_path / "x.png", np.zeros((4, 4, 3))), "img"),
        (lambda: save_gif(tmp_path / "x.gif", [], 10), "frames"),
        (lambda: save_mp4(tmp_path / "x.mp4", [np.zeros((4, 4, 3), np.uint8)], 0), "fps"),
    ]
    for fn, field in cases:
        with pytest.raises(ConfigError) as e:
            fn()
        assert e.value.field == field, (field, e.value)
    model = build_cloth(Rectangle(2.0, 2.0), sigma=1.0)
    s = model.state()
    s.particle_q[0, 0] = np.nan
    with pytest.raises(ConfigError) as e:
        r.render_scene(model, s)
    assert e.value.field == "state.particle_q"
    with pytest.raises(ConfigError) as e:
        r.render_scene(model, model.state(), particle_colors=np.zeros((2, 3), np.uint8))
    assert e.value.field == "particle_colors"
    with pytest.raises(ConfigError) as e:
        r.render_scene(model, model.state(), markers=[((0, 0, 0), -1.0, (0, 0, 0))])
    assert e.value.field == "markers[0].radius"


def test_near_plane_clipping_of_a_floor_behind_the_camera():
    """A 200 cm floor around the camera's foot: the parts behind the eye are clipped, the rest fills
    the lower half of the view (horizon at the image centre) and nothing lands above the horizon."""
    from cloth_gym.render.shapes import plane_mesh

    v, f = plane_mesh((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    cam = Camera.look_at((0.0, 0.0, 10.0), (0.0, 100.0, 10.0), fov_deg=60)  # horizontal view, 10 cm up
    img = Renderer(64, 48, camera=cam, ambient=1.0).render_meshes([(v, f, (0, 0, 0))])
    floor = np.all(img == 0, axis=2)
    assert not floor[:24].any()  # above the horizon: sky
    assert floor[30:].all()  # well below it: floor, including the part whose triangles cross behind the eye


def test_clipping_keeps_triangles_in_front_to_the_bit_and_cuts_the_others_at_the_near_plane():
    """Hand values at near = 1 cm: a triangle wholly in front comes back unchanged, to the bit (so
    a frame with nothing behind the plane may skip the clipping); one wholly behind is dropped; one
    corner behind leaves a quadrilateral, fanned into two triangles; two corners behind leave one
    triangle. A cut edge ends where it crosses z = 1, with its colour interpolated as its position."""
    from cloth_gym.render.raster import clip_near

    front = np.array([[[0.1, 0.2, 3.0], [1.3, 0.0, 2.0], [0.0, 1.7, 1.0]]])
    p, c = clip_near(front, front * 2.0, 1.0)
    assert np.array_equal(p, front) and np.array_equal(c, front * 2.0)
    behind = front - [0.0, 0.0, 5.0]
    assert clip_near(behind, behind, 1.0)[0].shape == (0, 3, 3)
    one_behind = np.array([[[0.0, 0.0, 3.0], [2.0, 0.0, 3.0], [0.0, 2.0, -1.0]]])  # C behind
    p, c = clip_near(one_behind, one_behind, 1.0)
    a, b, ca, bc = [0.0, 0.0, 3.0], [2.0, 0.0, 3.0], [0.0, 1.0, 1.0], [1.0, 1.0, 1.0]  # B→C, C→A cut halfway
    assert np.array_equal(p, [[a, b, bc], [a, bc, ca]]) and np.array_equal(c, p)
    two_behind = np.array([[[0.0, 0.0, 3.0], [2.0, 0.0, -1.0], [0.0, 2.0, -1.0]]])  # only A in front
    p, _ = clip_near(two_behind, two_behind, 1.0)
    assert np.array_equal(p, [[a, [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]])


def test_depth_image_of_a_flat_cloth_seen_from_above():
    """Hand value: an orthogonal view straight down from 30 cm above a flat cloth at z = 0 sees it at
    depth 30 cm wherever it covers the image, and nothing (inf) beyond it; the colour image of the
    same view agrees on which pixels show the cloth."""
    m = build_cloth(Rectangle(10.0, 10.0), "thick_cotton", sigma=1.0)
    cam = Camera.look_at((0, 0, 30.0), (0, 0, 0), up=(0, 1, 0), fov_deg=40)
    r = Renderer(64, 48, camera=cam)
    depth = r.render_scene_depth(m, m.state())
    assert depth.shape == (48, 64) and depth.dtype == np.float32
    cloth = np.isfinite(depth)
    assert cloth[24, 32] and not cloth[0, 0]
    np.testing.assert_allclose(depth[cloth], 30.0, rtol=1e-5)
    rgb = r.render_scene(m, m.state())
    assert np.array_equal(cloth, np.any(rgb != 255, axis=2))
    assert Renderer(64, 48, camera=cam, ssaa=2).render_scene_depth(m, m.state())[24, 32] == pytest.approx(30.0)


def test_env_render_size_camera_and_depth():
    import gymnasium as gym

    import cloth_gym  # noqa: F401

    env = gym.make("cloth_gym/CornerLift-v0", render_mode="rgb_array")
    env.reset(seed=0)
    assert env.render().shape == (240, 320, 3)  # the default size
    env = gym.make("cloth_gym/CornerLift-v0", render_mode="depth_array", render_width=80, render_height=60,
                   camera={"eye": (0, 0, 60.0), "target": (0, 0, 0), "up": (0, 1, 0)})
    env.reset(seed=0, options={"gripper_start": "corner"})  # the gripper away from the middle
    depth = env.render()
    z = env.unwrapped.physics.state.particle_q[:, 2]
    assert depth.shape == (60, 80) and depth.dtype == np.float32
    assert depth[30, 40] == pytest.approx(60.0 - z.mean(), abs=1e-3)  # the flat cloth under the camera
    for bad, field in [({"eye": (0, 0, 1)}, "camera.target"), ({"eye": (0, 0, 1), "target": (0, 0, 0), "zoom": 2},
                                                               "camera.zoom"),
                       ({"eye": (0, -9, 1), "target": (0, 0, 0), "fov_deg": 200}, "camera.fov_deg"),
                       ("top", "camera")]:
        with pytest.raises(ConfigError, match=field):
            gym.make("cloth_gym/CornerLift-v0", camera=bad)
    with pytest.raises(ConfigError, match="render_width"):
        gym.make("cloth_gym/CornerLift-v0", render_width=0)


def test_render_scene_draws_extra_meshes_and_names_a_bad_one():
    m = build_cloth(Rectangle(4.0, 4.0), "thick_cotton", sigma=2.0, origin=(-5.0, 0.0, 0.0))
    square = (np.array([[3.0, -2, 0], [7, -2, 0], [7, 2, 0], [3, 2, 0]]), [[0, 1, 2], [0, 2, 3]], (250, 150, 20))
    img = flat().render_scene(m, m.state(), meshes=[square])
    assert tuple(img[10, 15]) == (250, 150, 20) and tuple(img[10, 5]) != (250, 150, 20)  # world (5, 0), (-5, 0)
    with pytest.raises(ConfigError, match=r"meshes\[0\]"):
        flat().render_scene(m, m.state(), meshes=[(square[0], [[0, 1, 9]], (0, 0, 0))])
    with pytest.raises(ConfigError, match="meshes"):
        flat().render_scene(m, m.state(), meshes=3)
