"""The pictures people see: ``render()`` frames of every current id show the cloth, the target and
each gripper at 320 × 240 in the colours of :mod:`cloth_gym.envs.palette`; ``"rgb"`` observations
keep their own markers; the docs carry the palette's legend and the expert GIFs."""

from __future__ import annotations

import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import cloth_gym  # noqa: F401  (registers the ids)
from cloth_gym.envs import CURRENT_IDS, V1, palette

ROOT = Path(__file__).resolve().parents[1]

#: Least pixels (of 320 × 240) each thing covers in its own colour in an env's first frame. Measured
#: on seeds 0–4: the hanging ribbon 188–259 px (the square cloths thousands), the target 108–760
#: (Drape's hem line the least), a gripper 62–263 (a 1.5 cm sphere, smallest at the ribbon's
#: distance). The limits are about half the least measured: a cloth of 100 px, a target marker of
#: 50 px and a gripper disc about 6 px across. The observation camera and markers fail them: no
#: target in DrapeOntoTable, RibbonDrop's gripper (a 0.8 cm sphere) 11–12 px.
MIN_CLOTH_PX, MIN_TARGET_PX, MIN_GRIPPER_PX = 100, 50, 30


def shaded_as(frame: np.ndarray, rgb, tol: float = 10.0) -> np.ndarray:
    """(H, W) bool: pixels whose colour is ``s·rgb``, a shade s in [0.3, 1] of ``rgb`` (the renderer
    lights a face by a factor from its ambient 0.35 up to 1), each channel within ``tol``."""
    f = frame.astype(float)
    c = np.asarray(rgb, dtype=float)
    s = f @ c / (c @ c)
    return (s >= 0.3) & (s <= 1.02) & (np.abs(f - s[..., None] * c).max(axis=-1) <= tol)


def gripper_pixels(env, frame: np.ndarray) -> list[int]:
    """Per gripper, the pixels in its palette colour within its projected sphere (plus 2 px)."""
    u = env.unwrapped
    g = u.physics.grippers
    cam = u._picture_camera()
    h, w = frame.shape[:2]
    centres, depth = cam.project(g.position, w, h)
    rows, cols = np.mgrid[0:h, 0:w]
    holding = np.bincount(g.held_by + 1, minlength=g.count + 1)[1:] > 0
    out = []
    for k in range(g.count):
        r = cam.scale(h) * u.gripper_config.grasp_radius_cm / depth[k] + 2.0
        disc = (cols + 0.5 - centres[k, 0]) ** 2 + (rows + 0.5 - centres[k, 1]) ** 2 <= r * r
        out.append(int((shaded_as(frame, palette.gripper_rgb(g.closed[k], holding[k])) & disc).sum()))
    return out


def first_frame(env_id: str, seed: int = 0, **kwargs):
    env = gym.make(env_id, render_mode="rgb_array", **kwargs)
    env.reset(seed=seed)
    return env, env.render()


@pytest.mark.parametrize("env_id", CURRENT_IDS)
def test_the_first_frame_shows_cloth_target_and_each_gripper_in_their_colours(env_id):
    env, frame = first_frame(env_id)
    assert frame.shape == (240, 320, 3)
    cloth = int(shaded_as(frame, palette.CLOTH_RGB).sum())
    target = int(shaded_as(frame, palette.TARGET_RGB).sum())
    grippers = gripper_pixels(env, frame)
    assert cloth >= MIN_CLOTH_PX and target >= MIN_TARGET_PX, (cloth, target)
    assert len(grippers) == env.unwrapped.n_grippers and min(grippers) >= MIN_GRIPPER_PX, grippers


def test_the_counts_fail_when_the_target_or_a_gripper_leaves_the_view():
    env, _ = first_frame("cloth_gym/CornerLift-v2")
    u = env.unwrapped
    u.target = np.array([0.0, 400.0, 5.0])  # far behind the table, out of the picture
    u.physics.grippers.position[0] = (0.0, 0.0, -30.0)  # under the table top
    frame = env.render()
    assert shaded_as(frame, palette.TARGET_RGB).sum() < MIN_TARGET_PX
    assert gripper_pixels(env, frame)[0] < MIN_GRIPPER_PX
    assert shaded_as(frame, palette.CLOTH_RGB).sum() >= MIN_CLOTH_PX


def test_a_gripper_is_green_open_red_closed_on_nothing_and_magenta_holding():
    env = gym.make("cloth_gym/CornerLift-v2", render_mode="rgb_array")
    u = env.unwrapped
    colour = lambda: u._picture_markers(u.physics)[0][2]  # noqa: E731
    env.reset(seed=0)  # the gripper starts 5–10 cm above the table
    assert colour() == palette.GRIPPER_OPEN_RGB
    env.step([0.0, 0.0, 0.0, 1.0])
    assert colour() == palette.GRIPPER_CLOSED_RGB and not (u.physics.grippers.held_by >= 0).any()
    env.reset(seed=0, options={"gripper_start": "corner"})
    env.step([0.0, 0.0, 0.0, 1.0])
    assert colour() == palette.GRIPPER_HOLDING_RGB and (u.physics.grippers.held_by == 0).any()
    assert gripper_pixels(env, env.render())[0] >= MIN_GRIPPER_PX


def test_rgb_observations_keep_the_task_camera_and_their_markers():
    """A held gripper is red in an ``"rgb"`` observation (the markers policies trained on), magenta
    in a ``render()`` frame; the observation is the task's camera with :meth:`_markers`."""
    from cloth_gym.render import Renderer

    env = gym.make("cloth_gym/DrapeOntoTable-v1", observation_mode="rgb", image_size=160, render_mode="rgb_array")
    obs, _ = env.reset(seed=0)
    u = env.unwrapped
    assert (u.physics.grippers.held_by >= 0).any()
    expected = Renderer(160, 160, camera=u._camera()).render_scene(u.physics.model, u.physics.state,
                                                                  markers=u._markers(u.physics))
    np.testing.assert_array_equal(obs, expected)
    closed, holding = palette.GRIPPER_CLOSED_RGB, palette.GRIPPER_HOLDING_RGB
    assert shaded_as(obs, closed).sum() > 0 and not shaded_as(obs, holding).any()
    frame = env.render()
    assert shaded_as(frame, holding).sum() > 0 and not shaded_as(frame, closed).any()


def test_the_palette_is_the_renderers_and_the_v1_targets():
    from cloth_gym.render.renderer import DEFAULT_CLOTH_RGB, OBSTACLE_RGB, PLANE_RGB

    assert (palette.CLOTH_RGB, palette.TABLE_RGB, palette.FLOOR_RGB) == (DEFAULT_CLOTH_RGB, OBSTACLE_RGB, PLANE_RGB)
    assert tuple(V1["target_rgb"]) == palette.TARGET_RGB
    for env_id in CURRENT_IDS:
        assert tuple(gym.make(env_id).unwrapped.target_rgb) == palette.TARGET_RGB, env_id
    colours = [rgb for _, rgb, _ in palette.LEGEND]
    assert len(set(colours)) == len(colours)


@pytest.mark.parametrize("page", ["corner_lift.md", "drape_onto_table.md", "ribbon_drop.md"])
def test_each_env_page_opens_with_its_gif_and_carries_the_legend(page):
    """``python scripts/docs_pictures.py`` writes both; rerun it when the palette changes."""
    text = (ROOT / "docs" / "envs" / page).read_text(encoding="utf-8")
    gif = re.match(r"# \w+\n\n!\[[^\]]*\]\(\.\./img/([\w-]+\.gif)\)", text)
    assert gif and (ROOT / "docs" / "img" / gif.group(1)).is_file(), page
    assert f"<!-- legend -->\n{palette.legend_markdown()}\n<!-- /legend -->" in text


def test_the_docs_gifs_are_short():
    gifs = sorted((ROOT / "docs" / "img").glob("*.gif"))
    assert len(gifs) == 3 and sum(g.stat().st_size for g in gifs) < 3e6


def test_the_pictures_script_writes_the_legend_between_its_markers(tmp_path):
    import shutil
    import subprocess
    import sys

    shutil.copytree(ROOT / "docs" / "envs", tmp_path / "envs")
    page = tmp_path / "envs" / "ribbon_drop.md"
    page.write_text(re.sub(r"<!-- legend -->\n.*?<!-- /legend -->", "<!-- legend -->\nstale\n<!-- /legend -->",
                           page.read_text(encoding="utf-8"), flags=re.S), encoding="utf-8")
    subprocess.run([sys.executable, str(ROOT / "scripts" / "docs_pictures.py"), "--docs", str(tmp_path), "--no-gifs"],
                   check=True, capture_output=True, timeout=120)
    for name in ("corner_lift.md", "drape_onto_table.md", "ribbon_drop.md"):
        assert (tmp_path / "envs" / name).read_text() == (ROOT / "docs" / "envs" / name).read_text(), name
