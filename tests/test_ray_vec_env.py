"""Sub-envs in Ray actors (cloth_gym.agents.ray_vec_env.RayVecEnv): bit-identical to SB3's
DummyVecEnv over episodes with resets, a dead or failing actor is a typed error naming it within
seconds, and training runs on it through scripts/train.py and rl-baselines3-zoo (a local Ray)."""

import sys
import time

import numpy as np
import pytest

ray = pytest.importorskip("ray")  # the cluster extra; the dev extra installs it

import cloth_gym  # noqa: E402,F401  (registers the ids)
from cloth_gym import ConfigError, RemoteEnvError  # noqa: E402

pytestmark = pytest.mark.slow

KW = {"observation_mode": "keypoints", "max_episode_steps": 4}


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray for the module (each RayVecEnv then leaves it running)."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def _venvs(cls_kwargs, n=3):
    from stable_baselines3.common.env_util import make_vec_env

    from cloth_gym.agents.ray_vec_env import RayVecEnv

    remote = make_vec_env("cloth_gym/CornerLift-v2", n_envs=n, seed=5, env_kwargs=KW, vec_env_cls=RayVecEnv,
                          vec_env_kwargs=cls_kwargs)
    local = make_vec_env("cloth_gym/CornerLift-v2", n_envs=n, seed=5, env_kwargs=KW)
    return remote, local


def test_ray_vec_env_equals_dummy_vec_env_and_names_a_dead_actor(local_ray):
    remote, local = _venvs({"envs_per_actor": 2})
    assert remote.groups == [[0, 1], [2]]
    np.testing.assert_array_equal(remote.reset(), local.reset())
    rng = np.random.default_rng(0)
    ended = 0
    for step in range(10):  # 4-step episodes: two resets of every sub-env
        a = rng.uniform(-1, 1, (3, 4)).astype(np.float32)
        o1, r1, d1, i1 = remote.step(a)
        o2, r2, d2, i2 = local.step(a)
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(d1, d2)
        for x, y in zip(i1, i2, strict=True):
            assert set(x) == set(y), step
            for k in y:
                if k == "terminal_observation":
                    ended += 1
                    np.testing.assert_array_equal(x[k], y[k])
                elif k == "episode":  # its "t" is wall time
                    assert (x[k]["r"], x[k]["l"]) == (y[k]["r"], y[k]["l"])
                else:
                    assert x[k] == y[k], (step, k)
    assert ended == 2 * 3
    assert remote.get_attr("elapsed_steps") == local.get_attr("elapsed_steps")
    assert remote.get_attr("elapsed_steps", [2, 0]) == local.get_attr("elapsed_steps", [2, 0])
    assert remote.env_method("get_wrapper_attr", "control_dt", indices=[2, 1]) == \
        local.env_method("get_wrapper_attr", "control_dt", indices=[2, 1]) == [0.05, 0.05]
    # a method that does not exist: the actor's error comes back typed, naming the actor
    with pytest.raises(RemoteEnvError, match="actor 1") as err:
        remote.env_method("no_such_method", indices=[2])
    assert err.value.sub_envs == [2]
    # an actor killed mid-run: the next step names it within seconds, no hang
    ray.kill(remote._actors[0])
    t0 = time.perf_counter()
    with pytest.raises(RemoteEnvError, match="died") as err:
        remote.step(np.zeros((3, 4), dtype=np.float32))
    assert time.perf_counter() - t0 < 10.0
    assert (err.value.actor, err.value.sub_envs) == (0, [0, 1])
    remote.close()
    local.close()


@pytest.mark.parametrize("kwargs, field", [
    ({"envs_per_actor": 0}, "envs_per_actor"),
    ({"envs_per_actor": 1.5}, "envs_per_actor"),
    ({"threads_per_actor": 0}, "threads_per_actor"),
    ({"timeout_s": -1.0}, "timeout_s"),
    ({"envs_per_actor": 1, "threads_per_actor": 2}, "envs_per_actor"),  # 2 actors × 2 threads > 2 CPUs
])
def test_bad_options_are_config_errors(local_ray, kwargs, field):
    from cloth_gym.agents.ray_vec_env import RayVecEnv

    with pytest.raises(ConfigError) as err:
        RayVecEnv([lambda: None, lambda: None], **kwargs)
    assert err.value.field == field


def test_train_script_and_rl_zoo3_train_on_ray(local_ray, tmp_path, monkeypatch):
    import json
    import subprocess
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    run = tmp_path / "run"
    cmd = [sys.executable, str(root / "scripts" / "train.py"), "--algo", "sac", "--env", "cloth_gym/CornerLift-v2",
           "--run-dir", str(run), "--eval-freq", "0", "--vec-env", "ray", "--n-envs", "2", "--envs-per-actor", "1",
           "--set", "n_timesteps=64", "learning_starts=32", "batch_size=16", "env_kwargs={observation_mode: keypoints}"]
    subprocess.run(cmd, check=True, cwd=root, timeout=900, capture_output=True)
    info = json.loads((run / "run.json").read_text())
    assert info["vec_env"] == "ray" and info["n_envs"] == 2 and info["ray"]["envs_per_actor"] == 1
    assert (run / "model.zip").is_file()

    from rl_zoo3.exp_manager import ExperimentManager
    from rl_zoo3.train import train as zoo_train

    from cloth_gym.agents.ray_vec_env import RayVecEnv

    made = []

    class Recording(RayVecEnv):
        def __init__(self, env_fns, **kwargs):
            super().__init__(env_fns, **kwargs)
            made.append(self)

    monkeypatch.setattr(ExperimentManager, "default_vec_env_cls", Recording)
    monkeypatch.setattr(sys, "argv", ["train", "--algo", "sac", "--env", "cloth_gym/CornerLift-v2", "-n", "64",
                                      "--gym-packages", "cloth_gym", "-f", str(tmp_path / "zoo"), "--eval-freq", "-1",
                                      "--seed", "1", "--log-interval", "-1", "-params", "n_envs:2",
                                      "learning_starts:32", "batch_size:16", "policy:'MlpPolicy'"])
    zoo_train()
    assert made and made[0].num_envs == 2 and len(made[0].groups) == 2
    assert list((tmp_path / "zoo").rglob("*.zip"))
