"""The batched env at its boundary: all N actions checked before any sub-env steps (a bad one a
typed error naming it, every sub-env's state unchanged), typed errors for ragged actions, masked
actions and bad seeds, and pickling mid-episode."""

from __future__ import annotations

import copy
import pickle

import gymnasium as gym
import numpy as np
import pytest

import cloth_gym  # noqa: F401  (registers the ids)
from cloth_gym import ConfigError, ConfigTypeError

ENV_ID = "cloth_gym/CornerLift-v0"
N = 3


@pytest.fixture
def vec():
    env = gym.make_vec(ENV_ID, num_envs=N, vectorization_mode="vector_entry_point", threads=2)
    env.reset(seed=7)
    env.step(np.tile([0.2, 0.0, 0.3, 1.0], (N, 1)))
    yield env
    env.close()


def _states(vec):
    return [e.unwrapped.get_state() for e in vec.envs]


def _assert_unchanged(vec, before):
    for e, b in zip(vec.envs, before):
        a = e.unwrapped.get_state()
        np.testing.assert_array_equal(a.state.particle_q, b.state.particle_q)
        np.testing.assert_array_equal(a.grippers["position"], b.grippers["position"])
        assert a.elapsed_steps == b.elapsed_steps and a.state.step == b.state.step


@pytest.mark.parametrize("bad_row", [0, 1, N - 1])
@pytest.mark.parametrize("bad, error", [
    (np.array([np.nan, 0.0, 0.0, 0.0]), ConfigError),
    (np.array([0.0, np.inf, 0.0, 0.0]), ConfigError),
])
def test_one_bad_action_among_n_steps_no_sub_env(vec, bad_row, bad, error):
    before = _states(vec)
    actions = np.tile([0.1, 0.1, 0.1, 1.0], (N, 1))
    actions[bad_row] = bad
    with pytest.raises(error) as info:
        vec.step(actions)
    assert info.value.field == f"actions[{bad_row}]"
    _assert_unchanged(vec, before)
    vec.step(np.tile([0.1, 0.1, 0.1, 1.0], (N, 1)))  # and the batch steps on


@pytest.mark.parametrize("actions, error, field", [
    ([[0.0] * 4, [0.0] * 4, [0.0] * 3], ConfigError, "actions[2]"),  # ragged
    (np.array([np.zeros(4), np.zeros(4), np.zeros(3)], dtype=object), ConfigError, "actions[2]"),
    ("abc", ConfigTypeError, "actions"),
    (np.float64(1.0), ConfigTypeError, "actions"),
    ([[0.0] * 4, [0.0] * 4, ["a", 0, 0, 0]], ConfigTypeError, "actions[2]"),
    (np.zeros((N, 5)), ConfigError, "actions[0]"),
    (np.zeros((N - 1, 4)), ConfigError, "actions"),
    (np.ma.masked_array(np.zeros((N, 4)), mask=np.eye(N, 4, dtype=bool)), ConfigError, "actions"),
    (np.zeros((N, 4), dtype=complex), ConfigTypeError, "actions[0]"),
])
def test_malformed_action_batches_are_typed_errors(vec, actions, error, field):
    before = _states(vec)
    with pytest.raises(error) as info:
        vec.step(actions)
    assert info.value.field == field, str(info.value)
    _assert_unchanged(vec, before)


def test_a_masked_single_action_is_refused():
    env = gym.make(ENV_ID).unwrapped
    env.reset(seed=0)
    with pytest.raises(ConfigError, match="masked"):
        env.step(np.ma.masked_array(np.zeros(4), mask=[0, 1, 0, 0]))
    env.step(np.ma.masked_array(np.zeros(4)))  # nothing masked: an ordinary action


@pytest.mark.parametrize("seed, error, field", [
    (True, ConfigTypeError, "seed"),
    (1.5, ConfigTypeError, "seed"),
    ("abc", ConfigTypeError, "seed"),
    (-1, ConfigError, "seed"),
    ([0, 1], ConfigError, "seed"),
    ([0, True, 2], ConfigTypeError, "seed[1]"),
    ([0, -3, 2], ConfigError, "seed[1]"),
])
def test_bad_seeds_are_typed_errors(vec, seed, error, field):
    with pytest.raises(error) as info:
        vec.reset(seed=seed)
    assert info.value.field == field


def test_the_batched_env_pickles_mid_episode_and_continues_identically(vec):
    twins = [pickle.loads(pickle.dumps(vec)), copy.deepcopy(vec)]
    actions = np.tile([0.3, -0.2, 0.4, 1.0], (N, 1))
    want = [vec.step(actions) for _ in range(3)]
    for twin in twins:
        got = [twin.step(actions) for _ in range(3)]
        for (oa, ra, ta, ua, _), (ob, rb, tb, ub, _) in zip(want, got):
            np.testing.assert_array_equal(oa, ob)
            np.testing.assert_array_equal(ra, rb)
            np.testing.assert_array_equal(ta, tb)
            np.testing.assert_array_equal(ua, ub)
        twin.close()
