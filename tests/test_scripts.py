"""The entry points run end to end (short versions) and write what they promise."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
@pytest.mark.parametrize("integrator", ["implicit", "explicit"])
def test_demo_writes_picture_and_numbers(tmp_path, integrator):
    subprocess.run([sys.executable, str(ROOT / "scripts" / "demo.py"), "--out", str(tmp_path), "--duration", "0.05",
                    "--size", "10", "--integrator", integrator, "--parts", "hanging"], check=True, capture_output=True)
    metrics = json.loads((tmp_path / "demo" / "metrics.json").read_text())
    assert metrics["integrator"] == integrator and metrics["particles"] == 121
    assert 0 < metrics["sag_below_corners_cm"] < 10
    png = (tmp_path / "demo" / "hanging.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def _run(script, *args):
    return subprocess.run([sys.executable, str(ROOT / "scripts" / script), *args], check=True, capture_output=True,
                          text=True)


@pytest.mark.slow
def test_benchmark_writes_its_table(tmp_path):
    _run("benchmark.py", "--out", str(tmp_path), "--sizes", "21", "--duration", "0.04", "--explicit-duration",
         "0.002", "--skip-compile-time")
    data = json.loads((tmp_path / "benchmark" / "benchmark.json").read_text())
    rows = {r["integrator"]: r for r in data["rows"]}
    assert set(rows) == {"implicit", "explicit"}
    for r in rows.values():
        assert r["particles"] == 441 and r["particle_steps_per_s"] > 0 and r["steps"] > 0
    assert "| 21x21 | implicit |" in (tmp_path / "benchmark" / "benchmark.md").read_text()


@pytest.mark.slow
def test_preconditioner_script_shows_multigrid_needs_fewest_iterations(tmp_path):
    _run("preconditioners.py", "--out", str(tmp_path), "--size", "16", "--duration", "0.02")
    rows = json.loads((tmp_path / "preconditioners" / "preconditioners.json").read_text())
    its = {(r["preconditioner"], r["dt_s"]): r["cg_iterations_mean"] for r in rows}
    for dt in (1e-3, 2e-3, 5e-3):
        assert its[("multigrid", dt)] < its[("lines", dt)] <= its[("jacobi", dt)]


@pytest.mark.slow
def test_env_substeps_writes_strain_and_success(tmp_path):
    """The strain limiter's promise, end to end: with it on (2 %), the expert's lift at 25 ms
    substeps stays within a few tenths of the limit; without it the same lift overstretches."""
    _run("env_substeps.py", "--ids", "cloth_gym/CornerLift-v0", "--sim-dt", "0.025", "--limiter", "none", "2",
         "--episodes", "1", "--out", str(tmp_path))
    rows = json.loads((tmp_path / "env_substeps" / "env_substeps.json").read_text())["rows"]
    off, on = rows
    assert off["strain_limiter_percent"] is None and on["strain_limiter_percent"] == 2.0
    assert max(off["max_strain_percent"]) > 5.0
    assert max(on["max_strain_percent"]) < 3.0
    assert on["successes"] == 1 and on["diverged"] == 0


@pytest.mark.slow
def test_profile_script_splits_the_step_into_the_integrators_phases_and_the_env(tmp_path):
    """CornerLift-v0's expert for 30 steps: 5 substeps of 10 ms per 50 ms step, the phases and the env's own
    share add up to the steps' wall time, and the solver's main phases took time."""
    _run("profile_substep.py", "--ids", "cloth_gym/CornerLift-v0", "--steps", "30", "--out", str(tmp_path))
    row = json.loads((tmp_path / "profile" / "profile.json").read_text())["envs"]["cloth_gym/CornerLift-v0"]
    assert row["env_steps"] == 30 and row["substeps"] == 5 * 30
    assert sum(row["phases_s"].values()) + row["env_s"] == pytest.approx(row["wall_s"], rel=1e-6)
    for phase in ("forces", "assembly", "factor", "solve"):
        assert row["phases_s"][phase] > 0.0, phase


@pytest.mark.slow
def test_soak_runs_every_env_under_every_policy_without_an_exception(tmp_path):
    """The soak run, short (the CI version of the 10⁵-step run in docs/soak.md): 600 steps per env,
    at least three episodes (of at most 200 steps), both force models."""
    _run("soak.py", "--steps", "600", "--out", str(tmp_path))
    report = json.loads((tmp_path / "soak.json").read_text())
    from cloth_gym.envs import ENV_SPECS

    assert {r["env_id"] for r in report["rows"]} == set(ENV_SPECS)
    for r in report["rows"]:
        assert r["steps"] == 600 and r["episodes"] >= 3
        assert r["exceptions"] == 0 and r["non_finite_obs"] == 0 and r["outside_space"] == 0
        assert len(r["divergences"]) == r["diverged"]  # each diverged episode says where and why


def test_soak_policies_are_bounded_and_deterministic():
    sys.path.insert(0, str(ROOT / "scripts"))
    from soak import POLICIES, policy_action

    for name in POLICIES:
        for grippers in (1, 2):
            a = [policy_action(name, t, grippers, np.random.default_rng(5)) for t in range(4)]
            b = [policy_action(name, t, grippers, np.random.default_rng(5)) for t in range(4)]
            assert all(np.array_equal(x, y) for x, y in zip(a, b))
            assert all(x.shape == (4 * grippers,) and np.all(np.abs(x) <= 1) for x in a)
    assert np.all(policy_action("press_down", 0, 1, np.random.default_rng(0)) == [0, 0, -1, 1])
    with pytest.raises(ValueError):
        policy_action("dance", 0, 1, np.random.default_rng(0))


def test_jerk_policy_flips_every_axis_each_step_and_keeps_the_grippers_closed():
    """scripts/jerk.py's action: +1 then −1 on every gripper's x, y, z, the grip entry +1 always."""
    sys.path.insert(0, str(ROOT / "scripts"))
    from gymnasium import spaces
    from jerk import MATERIAL, jerk_action

    space = spaces.Box(-1.0, 1.0, (8,), np.float32)
    a0, a1 = jerk_action(space, 0).reshape(2, 4), jerk_action(space, 1).reshape(2, 4)
    assert np.all(a0[:, :3] == 1) and np.all(a1[:, :3] == -1) and np.all(a0[:, 3] == 1) and np.all(a1[:, 3] == 1)
    assert jerk_action(space, 2).dtype == np.float32 and space.contains(jerk_action(space, 3))
    assert {k: MATERIAL[k] for k in ("stretch_scale", "bending_scale", "shear_scale")} == dict.fromkeys(
        ("stretch_scale", "bending_scale", "shear_scale"), (0.25, 4.0))


def test_cloth_gym_command_prints_the_shipped_configs_and_the_envs():
    out = subprocess.run([sys.executable, "-m", "cloth_gym.cli", "configs", "--list"], capture_output=True,
                         text=True, check=True, cwd="/").stdout.split()
    names = {Path(p).relative_to(Path(p).parents[1]).as_posix() for p in out}
    assert {"materials/thick_cotton.yaml", "materials/thin_wool.yaml", "train/sac.yaml", "train/ppo.yaml"} <= names
    assert all(Path(p).is_file() for p in out)
    root = subprocess.run([sys.executable, "-m", "cloth_gym.cli", "configs"], capture_output=True, text=True,
                          check=True, cwd="/").stdout.strip()
    assert all(p.startswith(root) for p in out)
    envs = subprocess.run([sys.executable, "-m", "cloth_gym.cli", "envs"], capture_output=True, text=True,
                          check=True, cwd="/").stdout
    assert "cloth_gym/CornerLift-v0  max_episode_steps=100" in envs and "Box(-1.0, 1.0, (4,)" in envs
    bad = subprocess.run([sys.executable, "-m", "cloth_gym.cli", "dance"], capture_output=True, text=True)
    assert bad.returncode == 2 and "invalid choice" in bad.stderr


def test_drape_top_view_has_a_height_colour_bar_and_a_visible_legend():
    import matplotlib.colors as mcolors

    from cloth_gym.metrics import outline_radius
    from cloth_gym.reports.drape import drape_views
    from cloth_gym.scenes import drape_test

    sc = drape_test("thin_wool", sigma=2.54)
    state = sc.state()
    fig = drape_views(sc, state, outline_radius(state.particle_q[:, :2], sc.center_xy), "flat", size_px=40)
    top, bar = fig.axes[0], fig.axes[-1]  # the colour bar is added last
    assert "height" in bar.get_ylabel()
    for line in top.get_legend().get_lines():  # none white on the legend's white
        assert mcolors.to_rgb(line.get_color()) != (1.0, 1.0, 1.0), line.get_label()


def test_demo_shows_each_env_solved_and_indexes_its_files(tmp_path):
    """``make demo``'s job (drape test left out here; it has its own tests): a GIF per current env id
    of the scripted expert succeeding (the older ids' experts: tests/test_envs.py), and an index
    naming every file it wrote."""
    import imageio.v3 as iio

    run = subprocess.run([sys.executable, str(ROOT / "scripts" / "demo.py"), "--out", str(tmp_path), "--parts", "envs", "hanging",
                          "--size", "6", "--duration", "0.2"], capture_output=True, text=True, timeout=1200)
    assert run.returncode == 0, run.stderr[-3000:]
    index = (tmp_path / "index.md").read_text()
    from cloth_gym.envs import CURRENT_IDS

    for env_id in CURRENT_IDS:
        name = env_id.split("/")[-1]
        summary = json.loads((tmp_path / "envs" / f"{name}.json").read_text())
        assert summary["success_rate"] == 1.0, (env_id, summary)  # the expert solves the seed shown
        frames = iio.imread(tmp_path / "envs" / f"{name}.gif", index=None)
        # an animation (GIF writers merge repeated frames, so not one frame per step) that moves
        assert frames.shape[0] > 10 and (frames[0] != frames[-1]).any(axis=-1).mean() > 0.002
        assert f"envs/{name}.gif" in index
    assert "demo/hanging.png" in index and (tmp_path / "demo" / "hanging.png").is_file()


def test_drape_results_writes_stamped_rows_and_prints_the_table(tmp_path):
    out = tmp_path / "drape.json"
    _run("drape_results.py", "--materials", "thin_wool", "--sigma", "2.54", "--seeds", "0", "1", "--max-time", "1.5",
         "--out", str(out), "--quiet")
    data = json.loads(out.read_text())
    rows = data["rows"]
    assert [(r["material"], r["seed"]) for r in rows] == [("thin_wool", 0), ("thin_wool", 1)]
    assert all(0 < r["drape_coefficient"] <= 1 and r["node_count"] >= 0 for r in rows)
    assert data["stamp"]["command"].startswith("python scripts/drape_results.py --materials thin_wool")
    table = _run("drape_results.py", "--table", str(out)).stdout
    assert "| thin wool | 2.54 | 1 |" in table and "Regenerate with" in table


def test_drape_results_runs_the_library_on_the_cusick_tester(tmp_path):
    """``--materials library`` is every shipped material, ``--geometry cusick`` the 30 cm disc on 18 cm:
    a disc of 30 cm at σ = 3 cm has more particles than the paper's 25.4 cm one."""
    from cloth_gym.materials import available_materials

    out = tmp_path / "drape.json"
    _run("drape_results.py", "--materials", "library", "thin_wool", "--sigma", "3.0", "--max-time", "0.1",
         "--geometry", "cusick", "--out", str(out), "--quiet")
    paper = tmp_path / "paper.json"
    _run("drape_results.py", "--materials", "thin_wool", "--sigma", "3.0", "--max-time", "0.1", "--out", str(paper),
         "--quiet")
    data = json.loads(out.read_text())
    assert data["geometry"] == "cusick" and data["complete"]
    assert sorted(r["material"] for r in data["rows"]) == sorted(available_materials())  # thin_wool once
    wool = next(r for r in data["rows"] if r["material"] == "thin_wool")
    assert wool["particles"] > json.loads(paper.read_text())["rows"][0]["particles"]
