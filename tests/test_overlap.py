"""Learning while the envs step (cloth_gym.agents.overlap): the env step and the gradient steps run at
once, the transitions are those of the plain env, every gradient step of the plain algorithm is
taken at the same point of the run, and overlapped runs repeat bit for bit."""

import json
import threading

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

from cloth_gym import ConfigError
from cloth_gym.agents.config import load_train_config
from cloth_gym.agents.overlap import OverlappedVecEnv, find_overlapped, overlapped
from cloth_gym.agents.training import train

ENV_ID = "cloth_gym/CornerLift-v0"


def test_the_env_step_and_while_stepping_run_at_once_on_two_threads():
    """A handshake that completes only if both sides run at the same time: the env's step waits for
    the learner's signal and the learner for the env's (each with a long timeout)."""
    env_in_step, learner_in = threading.Event(), threading.Event()
    seen = {}

    class Handshake(gym.Wrapper):
        def step(self, action):
            env_in_step.set()
            seen["env saw the learner"] = learner_in.wait(60)
            seen["env thread"] = threading.get_ident()
            return self.env.step(action)

    def learner():
        learner_in.set()
        seen["learner saw the env"] = env_in_step.wait(60)
        seen["learner thread"] = threading.get_ident()

    venv = OverlappedVecEnv(make_vec_env(ENV_ID, n_envs=1, seed=0, wrapper_class=Handshake))
    venv.reset()
    venv.while_stepping = learner
    venv.step(np.zeros((1, 4), dtype=np.float32))
    venv.close()
    assert seen["env saw the learner"] and seen["learner saw the env"]
    assert seen["env thread"] != seen["learner thread"] == threading.get_ident()


def test_an_overlapped_env_steps_the_same_transitions_as_the_plain_one():
    plain = make_vec_env(ENV_ID, n_envs=2, seed=3)
    over = OverlappedVecEnv(make_vec_env(ENV_ID, n_envs=2, seed=3))
    assert find_overlapped(over) is over and find_overlapped(plain) is None
    np.testing.assert_array_equal(plain.reset(), over.reset())
    acts = np.random.default_rng(0).uniform(-1, 1, (12, 2, 4)).astype(np.float32)
    for a in acts:
        for x, y in zip(plain.step(a)[:3], over.step(a)[:3]):  # obs, rewards, dones
            np.testing.assert_array_equal(x, y)
    plain.close()
    over.close()


class _Pretrain(BaseCallback):
    """Gradient steps at the start of training, as ExpertDemos' pretraining takes them; then records
    the model's update count at every env step."""

    def __init__(self):
        super().__init__()
        self.updates = []

    def _on_training_start(self):
        self.model.train(gradient_steps=5, batch_size=self.model.batch_size)

    def _on_step(self):
        self.updates.append(self.model._n_updates)
        return True


def _learn(algo_cls, venv):
    model = algo_cls("MlpPolicy", venv, seed=1, device="cpu", learning_starts=10, batch_size=16, train_freq=1,
                     gradient_steps=2, buffer_size=1000, policy_kwargs={"net_arch": [16]})
    # the pretraining needs samples: ten random transitions, stored as collect_rollouts would
    obs = venv.reset()
    for _ in range(10):
        act = np.random.default_rng(0).uniform(-1, 1, (1, 4)).astype(np.float32)
        nxt, rew, done, info = venv.step(act)
        model.replay_buffer.add(obs, nxt, act, rew, done, info)
        obs = nxt
    cb = _Pretrain()
    model.learn(total_timesteps=40, callback=cb)
    return model, cb.updates


def test_overlapped_sac_takes_every_gradient_step_when_the_plain_one_does_and_repeats_bit_for_bit():
    """At every env step the overlapped learner has taken as many gradient steps as the plain one
    (the pretraining's at once, then those owed by the previous collection), none is left at the
    end, and two overlapped runs give the same network."""
    plain, plain_updates = _learn(SAC, make_vec_env(ENV_ID, n_envs=1, seed=0))
    runs = [_learn(overlapped(SAC), OverlappedVecEnv(make_vec_env(ENV_ID, n_envs=1, seed=0))) for _ in range(2)]
    assert plain_updates[0] == 5 and plain_updates[-1] > 5
    for model, updates in runs:
        assert type(model).__name__ == "OverlappedSAC"
        assert updates == plain_updates
        assert model._n_updates == plain._n_updates and model._owed_steps == 0
        assert find_overlapped(model.env).while_stepping is None  # learn() unhooked itself
    for a, b in zip(runs[0][0].policy.parameters(), runs[1][0].policy.parameters()):
        assert torch.equal(a, b)
    # the policy acted one update behind, so the networks are not the plain run's
    assert not all(torch.equal(a, b) for a, b in zip(plain.policy.parameters(), runs[0][0].policy.parameters()))


def test_train_with_overlap_records_it_and_refuses_on_policy_algorithms(tmp_path):
    cfg = load_train_config("sac", ENV_ID, overrides={"n_timesteps": 64, "learning_starts": 32, "batch_size": 32,
                                                      "train_freq": 8, "gradient_steps": 1})
    res = train(cfg, tmp_path / "run", seed=0, eval_freq=0, overlap=True)
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert run["overlap"] is True and res.env_steps == 64
    assert SAC.load(tmp_path / "run" / "model.zip", device="cpu")._n_updates == 4  # after steps 40, 48, 56, 64
    with pytest.raises(ConfigError, match="overlap.*off-policy"):
        overlapped(PPO)
    with pytest.raises(ConfigError, match="overlap"):
        train(load_train_config("ppo", ENV_ID), tmp_path / "ppo", seed=0, eval_freq=0, overlap=True)
