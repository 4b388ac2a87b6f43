"""The batched vector env: bit-identical to single envs, Gymnasium's autoreset and info conventions,
and SB3 training through its VecEnv adapter."""

import numpy as np
import pytest

import gymnasium as gym
from gymnasium.vector import AutoresetMode

import cloth_gym  # noqa: F401  (registers the ids)
from cloth_gym import ConfigError
from cloth_gym.envs.vector import BatchedVectorEnv

ENV_IDS = ["cloth_gym/CornerLift-v0", "cloth_gym/DrapeOntoTable-v0", "cloth_gym/RibbonDrop-v0", "cloth_gym/CornerLift-v1",
           "cloth_gym/DrapeOntoTable-v1", "cloth_gym/RibbonDrop-v1"]


def _singles(env_id, n, seed, actions, **kwargs):
    """N single envs run as NEXT_STEP autoreset would: the observations and rewards of each step."""
    envs = [gym.make(env_id, **kwargs) for _ in range(n)]
    obs = [np.stack([e.reset(seed=seed + i)[0] for i, e in enumerate(envs)])]
    rewards, dones = [], []
    ended = [False] * n
    for a in actions:
        row, rew, done = [], [], []
        for i, e in enumerate(envs):
            if ended[i]:
                o, _ = e.reset()
                r, ended[i] = 0.0, False
            else:
                o, r, term, trunc, _ = e.step(a[i])
                ended[i] = term or trunc
            row.append(o)
            rew.append(r)
            done.append(ended[i])
        obs.append(np.stack(row))
        rewards.append(rew)
        dones.append(done)
    return np.array(obs), np.array(rewards), np.array(dones)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_make_vec_equals_single_envs_bit_for_bit_across_resets(env_id):
    n, steps = 3, 14
    venv = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", max_episode_steps=5,
                        threads=2)
    assert isinstance(venv.unwrapped, BatchedVectorEnv)
    assert venv.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    rng = np.random.default_rng(4)
    actions = rng.uniform(-1, 1, (steps, n) + venv.single_action_space.shape).astype(np.float32)
    obs, infos = venv.reset(seed=20)
    got_obs, got_rew, got_done = [obs], [], []
    for a in actions:
        obs, rew, term, trunc, infos = venv.step(a)
        assert obs.shape == venv.observation_space.shape and venv.observation_space.contains(obs)
        got_obs.append(obs)
        got_rew.append(rew)
        got_done.append(term | trunc)
    venv.close()
    want_obs, want_rew, want_done = _singles(env_id, n, 20, actions, max_episode_steps=5)
    assert want_done.sum() >= n * 2  # episodes ended and were reset within the run
    np.testing.assert_array_equal(np.array(got_obs), want_obs)
    np.testing.assert_array_equal(np.array(got_rew), want_rew)
    np.testing.assert_array_equal(np.array(got_done), want_done)


def test_one_two_and_three_threads_give_the_same_bits_and_vector_info():
    runs = []
    for threads in (1, 2, 3):
        venv = gym.make_vec("cloth_gym/CornerLift-v0", num_envs=3, vectorization_mode="vector_entry_point",
                            threads=threads)
        assert venv.unwrapped.threads == threads
        venv.reset(seed=[7, 3, 5])
        acts = np.random.default_rng(1).uniform(-1, 1, (6, 3, 4)).astype(np.float32)
        out = [venv.step(a) for a in acts]
        info = out[-1][4]
        assert info["_is_success"].all() and info["is_success"].dtype == np.bool_
        assert isinstance(info["diverged"], np.ndarray) and info["diverged"].shape == (3,)
        runs.append(np.array([o[0] for o in out]))
        venv.close()
    np.testing.assert_array_equal(runs[0], runs[1])
    np.testing.assert_array_equal(runs[0], runs[2])
    assert not np.array_equal(runs[0][:, 0], runs[0][:, 1])  # the seeds made different cloths


def _stepped_batch(threads: int = 2):
    """A batch of 4 CornerLift-v0 envs on ``threads`` threads, reset and stepped once with zero actions;
    returns it and the zero actions."""
    venv = gym.make_vec("cloth_gym/CornerLift-v0", num_envs=4, vectorization_mode="vector_entry_point",
                        threads=threads)
    venv.reset(seed=0)
    act = np.zeros((4, 4), dtype=np.float32)
    venv.step(act)
    return venv, act


def test_threads_start_the_sub_envs_whose_last_step_was_slowest_first():
    import threading

    venv, act = _stepped_batch()
    u = venv.unwrapped
    assert (u._step_seconds > 0).all()  # every sub-env's step was timed
    started, lock = [], threading.Lock()
    step_untimed = u._step_one_untimed

    def record(i, action, mode):
        with lock:
            started.append(i)
        return step_untimed(i, action, mode)

    u._step_one_untimed = record
    u._step_seconds[:] = [1e-3, 4e-3, 2e-3, 3e-3]  # as if sub-env 1's last step was the slowest, 0's the fastest
    venv.step(act)
    venv.close()
    # one queue hands the calls out in that order; the two threads may record neighbours in either order
    assert set(started[:2]) == {1, 3} and set(started[2:]) == {2, 0}


def test_each_sub_envs_thread_and_cpu_time_are_reported():
    venv, _ = _stepped_batch()
    u = venv.unwrapped
    # the sub-envs' thread CPU time is within their wall time (the two clocks' granularity aside)
    assert (u.last_step_cpu_seconds > 0).all()
    assert u.last_step_cpu_seconds.sum() <= 1.05 * u.last_step_seconds.sum() + 5e-5
    assert set(u.last_step_threads) <= {0, 1}
    venv.close()
    one, _ = _stepped_batch(threads=1)
    assert list(one.unwrapped.last_step_threads) == [0, 0, 0, 0]  # one thread: the calling thread steps all
    one.close()


def test_a_failing_sub_env_raises_the_lowest_ones_error_after_every_sub_env_stepped():
    venv, act = _stepped_batch()
    u = venv.unwrapped
    stepped = []
    step_untimed = u._step_one_untimed

    def fail_two(i, action, mode):
        stepped.append(i)
        if i in (1, 3):
            raise ValueError(f"sub-env {i} failed")
        return step_untimed(i, action, mode)

    u._step_one_untimed = fail_two
    u._step_seconds[:] = [1e-3, 2e-3, 3e-3, 4e-3]  # sub-env 3 starts first, 1 third
    with pytest.raises(ValueError, match="sub-env 1 failed"):
        venv.step(act)
    venv.close()
    assert sorted(stepped) == [0, 1, 2, 3]


def test_same_step_autoreset_returns_the_final_observation_in_info():
    venv = gym.make_vec("cloth_gym/CornerLift-v0", num_envs=2, vectorization_mode="vector_entry_point",
                        max_episode_steps=3, autoreset_mode=AutoresetMode.SAME_STEP)
    single = gym.make("cloth_gym/CornerLift-v0", max_episode_steps=3)
    venv.reset(seed=1)
    o1, _ = single.reset(seed=1)
    a = np.zeros((2, 4), dtype=np.float32)
    a[:, 2] = 1.0
    for k in range(3):
        obs, _, term, trunc, info = venv.step(a)
        o1, *_ = single.step(a[0])
    assert trunc.all() and not term.any()
    assert info["_final_obs"].all()
    np.testing.assert_array_equal(info["final_obs"][0], o1)
    assert info["final_info"]["_is_success"].all()
    np.testing.assert_array_equal(obs[0], single.reset()[0])  # the next episode's first observation


def test_sub_envs_pass_gymnasiums_env_checker():
    from gymnasium.utils.env_checker import check_env

    venv = gym.make_vec("cloth_gym/CornerLift-v0", num_envs=2, vectorization_mode="vector_entry_point")
    for env in venv.unwrapped.envs:
        check_env(env.unwrapped, skip_render_check=True)
    venv.close()


def test_bad_arguments_name_the_field():
    with pytest.raises(ConfigError, match="autoreset_mode"):
        gym.make_vec("cloth_gym/CornerLift-v0", num_envs=1, vectorization_mode="vector_entry_point",
                     autoreset_mode="sometimes")
    with pytest.raises(ConfigError, match="threads"):
        gym.make_vec("cloth_gym/CornerLift-v0", num_envs=1, vectorization_mode="vector_entry_point", threads=0)
    with pytest.raises(ConfigError, match="num_envs"):
        gym.make_vec("cloth_gym/CornerLift-v0", num_envs=0, vectorization_mode="vector_entry_point")
    venv = gym.make_vec("cloth_gym/CornerLift-v0", num_envs=2, vectorization_mode="vector_entry_point")
    venv.reset(seed=0)
    with pytest.raises(ConfigError, match="actions"):
        venv.step(np.zeros((3, 4), dtype=np.float32))
    with pytest.raises(ConfigError, match="seed"):
        venv.reset(seed=[1, 2, 3])
    venv.close()


def test_sb3_adapter_equals_sb3s_own_vec_env():
    from stable_baselines3.common.env_util import make_vec_env

    from cloth_gym.agents.vec_env import BatchedVecEnv

    n = 2
    kwargs = {"max_episode_steps": 6}
    batched = make_vec_env("cloth_gym/CornerLift-v0", n_envs=n, seed=5, env_kwargs=kwargs, vec_env_cls=BatchedVecEnv)
    dummy = make_vec_env("cloth_gym/CornerLift-v0", n_envs=n, seed=5, env_kwargs=kwargs)
    np.testing.assert_array_equal(batched.reset(), dummy.reset())
    rng = np.random.default_rng(1)
    ended = 0
    for k in range(13):
        a = rng.uniform(-1, 1, (n, 4)).astype(np.float32)
        batched.step_async(a)
        dummy.step_async(a)
        o1, r1, d1, i1 = batched.step_wait()
        o2, r2, d2, i2 = dummy.step_wait()
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(d1, d2)
        for x, y in zip(i1, i2):
            assert x["is_success"] == y["is_success"]
            if "terminal_observation" in y:
                ended += 1
                np.testing.assert_array_equal(x["terminal_observation"], y["terminal_observation"])
                assert x["TimeLimit.truncated"] == y["TimeLimit.truncated"]
                assert x["episode"]["l"] == y["episode"]["l"] == 6
    assert ended == 2 * n  # each sub-env's time limit ended two episodes
    assert batched.get_attr("elapsed_steps") == dummy.get_attr("elapsed_steps")
    batched.close()


def test_rl_zoo3_trains_on_the_batched_vec_env(tmp_path, monkeypatch):
    """rl-baselines3-zoo builds its envs with ExperimentManager.default_vec_env_cls when set."""
    import sys

    from rl_zoo3.exp_manager import ExperimentManager
    from rl_zoo3.train import train as zoo_train

    from cloth_gym.agents.vec_env import BatchedVecEnv

    made = []

    class Recording(BatchedVecEnv):
        def __init__(self, env_fns, **kwargs):
            super().__init__(env_fns, **kwargs)
            made.append(self)

    monkeypatch.setattr(ExperimentManager, "default_vec_env_cls", Recording)
    monkeypatch.setattr(sys, "argv", ["train", "--algo", "sac", "--env", "cloth_gym/CornerLift-v0", "-n", "64",
                                      "--gym-packages", "cloth_gym", "-f", str(tmp_path), "--eval-freq", "-1",
                                      "--seed", "1", "--log-interval", "-1", "-params", "n_envs:2",
                                      "learning_starts:32", "batch_size:16", "policy:'MlpPolicy'"])
    zoo_train()
    assert made and made[0].num_envs == 2
    assert list(tmp_path.rglob("*.zip"))  # the trained model was saved


def test_lock_scaling_replays_the_recorded_episodes_with_the_kernels_slept():
    """scripts/lock_scaling.py: the batch replayed on 2 threads, and as 2 processes of one thread,
    with every implicit kernel call a sleep of its recorded length, gives the recorded observations
    at every step and spends the recorded kernel time asleep rather than computing; a tape whose
    kernel wrote other positions is caught, in one process and in a process of two."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "lock_scaling.py"
    spec = importlib.util.spec_from_file_location("lock_scaling_script", path)
    ls = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ls)
    env_id = "cloth_gym/CornerLift-v2"
    tape, actions, observations, _ = ls.record(env_id, 4, 6)
    assert sum(len(c) for c in tape.calls) >= 4 and np.all(tape.held > 0)
    row = ls.replay(env_id, tape, actions, observations, 2, warm=0)
    # every recorded call slept for its time less the part that holds the lock (spun instead)
    to_sleep = sum(c[0] - min(c[0], h) for calls, h in zip(tape.calls, tape.held) for c in calls)
    assert row["env_step_slept_ms"] * 1e-3 * 6 * 4 == pytest.approx(to_sleep, rel=1e-9) and to_sleep > 0
    # asleep in the kernels, not computing them: a thread's CPU time and its sleep fit in its wall time
    assert row["env_step_cpu_ms"] + row["env_step_slept_ms"] <= row["env_step_ms"] * 1.05
    split = ls.replay_in_processes(env_id, tape, actions, observations, 2, 2, warm=0)
    assert split["processes"] == 2 and split["env_step_slept_ms"] * 1e-3 * 6 * 4 == pytest.approx(to_sleep, rel=1e-9)
    tape.calls[3][-1][2][0][0, 2] += 1.0  # sub-env 3's last kernel call now moves a particle 1 cm higher
    with pytest.raises(RuntimeError, match="differs from the recording at vector step"):
        ls.replay(env_id, tape, actions, observations, 2, warm=0)
    with pytest.raises(RuntimeError, match="replay process 1 .sub-envs 2–3.*differs from the recording"):
        ls.replay_in_processes(env_id, tape, actions, observations, 2, 2, warm=0)


@pytest.mark.parametrize("env_id", ["cloth_gym/CornerLift-v2", "cloth_gym/DrapeOntoTable-v2", "cloth_gym/RibbonDrop-v4"])
def test_of_the_kernels_an_env_step_calls_only_the_implicit_step_releases_the_lock(env_id, monkeypatch):
    """The compiled kernels an env step calls from Python: the implicit step, milliseconds long,
    releases the interpreter lock, so that a batch's other threads run their Python meanwhile; every
    other one, microseconds long, keeps it (``njit_brief``: a release would let another thread's
    Python in, which the caller would then wait out)."""
    from numba.core.registry import CPUDispatcher

    from cloth_gym.agents.experts import make_expert

    env = gym.make(env_id)
    env.reset(seed=0)
    expert = make_expert(env)
    called = set()
    call = CPUDispatcher.__call__  # what a call from Python runs (compiled callers do not pass here)

    def counted(kernel, *args, **kwargs):
        called.add(kernel)
        return call(kernel, *args, **kwargs)

    monkeypatch.setattr(CPUDispatcher, "__call__", counted)
    for _ in range(3):
        env.step(expert.act())
    releases = {k.py_func.__name__: k.targetoptions.get("nogil", False) for k in called}
    assert releases.pop("run_implicit") is True
    assert len(releases) >= 3 and not any(releases.values()), releases


def test_scalar_infos_batch_as_gymnasiums_add_info_or_decline():
    """The one-call-per-key batching of the sub-envs' infos gives Gymnasium's arrays (values,
    dtypes, masks, key order) where it applies, and declines (None) where it does not."""
    from types import SimpleNamespace

    from gymnasium.vector import VectorEnv

    from cloth_gym.envs.vector import scalar_infos

    def gymnasium_way(infos):
        out, holder = {}, SimpleNamespace(num_envs=len(infos))
        for i, info in enumerate(infos):
            out = VectorEnv._add_info(holder, out, info, i)
        return out

    same = [{"reward_reach": 0.5 * i, "is_success": i == 1, "slips": i, "strain": np.float32(i)} for i in range(3)]
    got, want = scalar_infos(same), gymnasium_way(same)
    assert list(got) == list(want)
    for k in want:
        assert got[k].dtype == want[k].dtype and np.array_equal(got[k], want[k]), k
    declined = [
        [{"a": 1.0}, {"a": 1}],  # another type
        [{"a": 1.0}, {"b": 1.0}],  # another key
        [{"a": 1.0}, {"a": 1.0, "b": 2.0}],  # a key more
        [{"material": "cotton"}, {"material": "denim"}],  # not a number
        [{"d": np.bool_(True)}, {"d": np.bool_(False)}],  # NumPy's bool is no number: Gymnasium makes objects
        [{"t": np.timedelta64(1, "s")}, {"t": np.timedelta64(2, "s")}],  # a NumPy "number" Gymnasium cannot batch
        [{"_a": 0.5, "a": 1.0}, {"_a": 0.5, "a": 1.0}],  # a key named as another's mask
    ]
    for infos in declined:
        assert scalar_infos(infos) is None, infos
