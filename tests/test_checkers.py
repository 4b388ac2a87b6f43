"""The current ids as a user meets them: Gymnasium's and SB3's env checkers pass in full (render
checks included, every advertised render mode made), no "out of date" warning, and "human" is
advertised only where pygame is installed.

Cost: about 10 s with the kernel cache warm (DrapeOntoTable-v1 and CornerLift-v2 most of it); a cold
cache adds the first compile of the simulator kernels.
"""

import subprocess
import sys
import warnings

import gymnasium as gym
import pytest

import cloth_gym  # noqa: F401  (registers the ids)
from cloth_gym.envs import CURRENT_IDS, ENV_SPECS


def test_current_ids_are_the_newest_version_of_each_task():
    newest = {}
    for env_id in ENV_SPECS:
        name, version = env_id.rsplit("-v", 1)
        newest[name] = max(newest.get(name, 0), int(version))
    assert sorted(CURRENT_IDS) == sorted(f"{name}-v{v}" for name, v in newest.items())


@pytest.mark.parametrize("env_id", CURRENT_IDS)
def test_both_env_checkers_pass_on_each_current_id(env_id, monkeypatch):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")  # "human" (where pygame is installed) without a display
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*out of date.*")
        env = gym.make(env_id)
    check_env(env.unwrapped)  # makes the env again in every advertised render mode
    env.close()
    env = gym.make(env_id, render_mode="rgb_array")
    sb3_check_env(env.unwrapped, warn=True)
    env.close()


def test_human_advertised_only_with_pygame():
    code = """
import sys
sys.modules["pygame"] = None  # an install without pygame
import gymnasium as gym
import cloth_gym
from cloth_gym.errors import ConfigError
from cloth_gym.envs.ribbon_drop import RibbonDropEnv
env = gym.make("cloth_gym/RibbonDrop-v1")
assert "human" not in env.metadata["render_modes"], env.metadata
assert {"rgb_array", "depth_array"} <= set(env.metadata["render_modes"])
# gym.make wraps the rgb_array env in Gymnasium's HumanRendering, which names pygame at reset
env = gym.make("cloth_gym/RibbonDrop-v1", render_mode="human")
try:
    env.reset(seed=0)
except gym.error.DependencyNotInstalled as e:
    assert "pygame" in str(e), e
else:
    raise AssertionError("render_mode='human' worked without pygame")
try:  # the class itself says what is missing
    RibbonDropEnv(render_mode="human")
except ConfigError as e:
    assert "pygame" in str(e), e
else:
    raise AssertionError("RibbonDropEnv(render_mode='human') accepted without pygame")
"""
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
