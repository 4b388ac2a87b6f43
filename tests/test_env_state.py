"""Exact save and restore of an env's episode: ``get_state``/``set_state``, pickling and deepcopy
mid-episode, each replayed bit for bit."""

import copy
import pickle

import gymnasium as gym
import numpy as np
import pytest

import cloth_gym  # noqa: F401  (registers the env ids)
from cloth_gym import ConfigError, ConfigTypeError, ResetNeeded
from cloth_gym.agents.experts import make_expert
from replay import play, same

IDS = ["cloth_gym/CornerLift-v0", "cloth_gym/DrapeOntoTable-v0", "cloth_gym/RibbonDrop-v0", "cloth_gym/CornerLift-v1",
       "cloth_gym/DrapeOntoTable-v1", "cloth_gym/RibbonDrop-v1"]


def _expert_actions(env_id, seed, n):
    """n actions of the scripted expert from ``reset(seed)``: the cloth is grasped and carried."""
    env = gym.make(env_id).unwrapped
    env.reset(seed=seed)
    expert = make_expert(env)
    actions = []
    for _ in range(n):
        a = expert.act()
        actions.append(a)
        env.step(a)
    return actions


@pytest.mark.parametrize("env_id", IDS)
def test_set_state_replays_bit_for_bit_with_a_grasp_held(env_id):
    """Mid-episode, a gripper holding the cloth: snapshot, step on, restore, replay the same actions:
    the same observations, rewards and infos, bit for bit; twice from the same snapshot."""
    actions = _expert_actions(env_id, 3, 30)
    env = gym.make(env_id).unwrapped
    env.reset(seed=3)
    play(env, actions[:12])
    assert env.physics.grippers.held_by.max() >= 0  # something is held
    snap = env.get_state()
    first = play(env, actions[12:])
    for _ in range(2):
        env.set_state(snap)
        same(first, play(env, actions[12:]))


def test_set_state_restores_a_sleeping_cloth_and_the_random_generator():
    """CornerLift with random actions: its cloth on the table falls asleep (no solve); a snapshot of
    it replays exactly, and the env's np_random continues the same stream."""
    env = gym.make("cloth_gym/CornerLift-v0").unwrapped
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    open_actions = [np.array([*rng.uniform(-1, 1, 3), -1.0], dtype=np.float32) for _ in range(30)]
    play(env, open_actions[:20])
    assert env.physics.state.solver.asleep
    snap = env.get_state()
    draws = env.np_random.random(3)
    first = play(env, open_actions[20:])
    env.set_state(snap)
    np.testing.assert_array_equal(env.np_random.random(3), draws)
    same(first, play(env, open_actions[20:]))
    assert env.elapsed_steps == 30


@pytest.mark.parametrize("env_id", IDS)
def test_a_pickled_or_deep_copied_env_continues_mid_episode(env_id):
    """pickle and copy.deepcopy of an env in the middle of an episode continue it identically (they
    used to give a never-reset env that refused to step)."""
    actions = _expert_actions(env_id, 4, 20)
    env = gym.make(env_id).unwrapped
    env.reset(seed=4)
    play(env, actions[:8])
    twins = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env)]
    rest = play(env, actions[8:])
    for twin in twins:
        assert twin.elapsed_steps == 8
        same(rest, play(twin, actions[8:]))


def test_a_snapshot_pickles_and_keeps_its_task_state():
    env = gym.make("cloth_gym/RibbonDrop-v0").unwrapped
    env.reset(seed=1)
    snap = pickle.loads(pickle.dumps(env.get_state()))
    target = env.target_center.copy()
    env.reset(seed=2)
    assert not np.array_equal(env.target_center, target)
    env.set_state(snap)
    np.testing.assert_array_equal(env.target_center, target)
    np.testing.assert_array_equal(env.physics.state.particle_q, snap.state.particle_q)
    assert env.physics.state.particle_q is not snap.state.particle_q  # copied in: the snapshot stays reusable


def test_snapshots_are_refused_where_they_do_not_belong():
    corner = gym.make("cloth_gym/CornerLift-v0").unwrapped
    with pytest.raises(ResetNeeded):
        corner.get_state()
    corner.reset(seed=0)
    ribbon = gym.make("cloth_gym/RibbonDrop-v0").unwrapped
    ribbon.reset(seed=0)
    with pytest.raises(ConfigError, match="snapshot.env: was taken from a CornerLiftEnv"):
        ribbon.set_state(corner.get_state())
    with pytest.raises(ConfigError, match="snapshot.model: has 121 particles"):
        gym.make("cloth_gym/CornerLift-v0", sigma=1.0).unwrapped.set_state(corner.get_state())
    with pytest.raises(ConfigTypeError, match="snapshot"):
        corner.set_state({"state": None})


def test_the_restored_generator_survives_reading_its_seed():
    """Gymnasium reseeds an env whose generator has no seed recorded when ``np_random_seed`` is read:
    the snapshot carries the seed too, so a restored (or unpickled) env keeps its restored stream."""
    env = gym.make("cloth_gym/CornerLift-v0").unwrapped
    env.reset(seed=11)
    snap = env.get_state()
    twin = pickle.loads(pickle.dumps(env))
    draws = env.np_random.random(4)
    for other in (twin, gym.make("cloth_gym/CornerLift-v0").unwrapped):
        other.set_state(snap)
        assert other.np_random_seed == 11
        np.testing.assert_array_equal(other.np_random.random(4), draws)


def test_an_env_made_with_another_envs_sim_settings_pickles():
    """``sim=env.unwrapped.sim`` (a read-only mapping) is kept as a plain dict, so the env pickles."""
    a = gym.make("cloth_gym/CornerLift-v0", sim={"scheme": "bdf2"}).unwrapped
    b = gym.make("cloth_gym/CornerLift-v0", sim=a.sim).unwrapped
    b.reset(seed=0)
    c = pickle.loads(pickle.dumps(b))
    assert dict(c.sim) == dict(a.sim) and copy.deepcopy(b).sim["scheme"] == "bdf2"
