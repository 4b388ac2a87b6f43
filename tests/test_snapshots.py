"""``set_state`` checks a whole snapshot against the env it enters: every case below a typed error
naming the field (and the env left as it was), and a Hypothesis property test mutating snapshots
field by field, where each example either raises a SnapshotError or, unchanged, replays bit for bit."""

from __future__ import annotations

import dataclasses
import pickle

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cloth_gym  # noqa: F401  (registers the env ids)
from cloth_gym.agents.experts import make_expert
from cloth_gym.envs.snapshot import SNAPSHOT_FORMAT, EnvSnapshot
from cloth_gym.errors import ConfigError, SnapshotError, SnapshotTypeError

ENV_ID = "cloth_gym/CornerLift-v0"


def _env(env_id=ENV_ID, **kw):
    return gym.make(env_id, **kw).unwrapped


def _copy(snap: EnvSnapshot, **changes) -> EnvSnapshot:
    """A copy of ``snap`` whose mutable parts can be edited without touching ``snap``."""
    parts = dict(state=snap.state.copy(), grippers={k: np.copy(v) if isinstance(v, np.ndarray) else v
                                                    for k, v in snap.grippers.items()},
                 task={k: np.copy(v) for k, v in snap.task.items()})
    return dataclasses.replace(snap, **{**parts, **changes})


@pytest.fixture(scope="module")
def lift():
    """A CornerLift-v0 env mid-episode, its gripper holding the corner, and its snapshot."""
    env = _env()
    env.reset(seed=3)
    expert = make_expert(env)
    for _ in range(12):
        env.step(expert.act())
    assert env.physics.grippers.held_by.max() >= 0
    return env, env.get_state()


def _refused(env, snap, field, error=SnapshotError):
    before = env.get_state()
    with pytest.raises(error) as info:
        env.set_state(snap)
    assert info.value.field == field, str(info.value)
    after = env.get_state()  # the env is left as it was
    np.testing.assert_array_equal(after.state.particle_q, before.state.particle_q)
    assert after.task.keys() == before.task.keys() and after.elapsed_steps == before.elapsed_steps
    return info.value


@pytest.mark.parametrize("kwargs, field", [
    (dict(material="thin_wool"), "snapshot.material"),
    (dict(model="breen"), "snapshot.force_model"),
    (dict(integrator="explicit"), "snapshot.integrator"),
    (dict(observation_mode="keypoints"), "snapshot.observation_mode"),
])
def test_a_snapshot_of_another_configuration_is_refused(lift, kwargs, field):
    _, snap = lift
    other = _env(**kwargs)
    other.reset(seed=0)
    err = _refused(other, snap, field)
    assert "this env has" in str(err)


def test_another_version_of_the_same_class_is_refused_by_id():
    v1 = _env("cloth_gym/CornerLift-v1")
    v1.reset(seed=0)
    v2 = _env("cloth_gym/CornerLift-v2")
    v2.reset(seed=0)
    err = _refused(v2, v1.get_state(), "snapshot.env_id")
    assert "cloth_gym/CornerLift-v1" in str(err) and "cloth_gym/CornerLift-v2" in str(err)


def test_a_snapshot_without_a_format_version_or_with_another_is_refused(lift):
    env, snap = lift
    old = object.__new__(EnvSnapshot)  # as a snapshot pickled by an earlier release unpickles
    object.__setattr__(old, "__dict__", {k: v for k, v in snap.__dict__.items() if k != "format"})
    err = _refused(env, pickle.loads(pickle.dumps(old)), "snapshot.format")
    assert "earlier release" in str(err) and f"format {SNAPSHOT_FORMAT}" in str(err)
    _refused(env, _copy(snap, format=SNAPSHOT_FORMAT + 1), "snapshot.format")


def test_task_keys_are_a_fixed_set_and_nothing_else_is_set_on_the_env(lift):
    env, snap = lift
    step = env.step
    _refused(env, _copy(snap, task={"step": 5}), "snapshot.task")
    _refused(env, _copy(snap, task={"target": snap.task["target"], "step": 5}), "snapshot.task")
    _refused(env, _copy(snap, task={}), "snapshot.task")
    assert env.step == step
    _refused(env, _copy(snap, task={"target": np.array([0.0, np.nan, 1.0])}), "snapshot.task.target")
    _refused(env, _copy(snap, task={"target": [0.0, 1.0, 2.0]}), "snapshot.task.target", SnapshotTypeError)


@pytest.mark.parametrize("case, field, error", [
    ("grippers={}", "snapshot.grippers", SnapshotError),
    ("rng=None", "snapshot.rng", SnapshotTypeError),
    ("elapsed_steps=float('nan')", "snapshot.elapsed_steps", SnapshotTypeError),
    ("elapsed_steps=-1", "snapshot.elapsed_steps", SnapshotError),
    ("model=None", "snapshot.model", SnapshotTypeError),
    ("diverged='no'", "snapshot.diverged", SnapshotTypeError),
    ("rng_seed='7'", "snapshot.rng_seed", SnapshotTypeError),
    ("last_obs=snap.last_obs[:47]", "snapshot.last_obs", SnapshotError),
    ("last_obs=None", "snapshot.last_obs", SnapshotTypeError),
])
def test_bad_top_level_fields_are_refused(lift, case, field, error):
    env, snap = lift
    name, expr = case.split("=", 1)
    _refused(env, _copy(snap, **{name: eval(expr)}), field, error)


def _set(snap, path, value):
    """A copy of ``snap`` with ``state.x`` / ``grippers.x`` set to ``value``."""
    out = _copy(snap)
    part, name = path.split(".")
    if part == "state":
        setattr(out.state, name, value)
    else:
        out.grippers[name] = value
    return out


def test_bad_arrays_are_refused(lift):
    env, snap = lift
    q = snap.state.particle_q
    nan_q = q.copy()
    nan_q[7, 2] = np.nan
    err = _refused(env, _set(snap, "state.particle_q", nan_q), "snapshot.state.particle_q")
    assert "(7, 2)" in str(err)
    _refused(env, _set(snap, "state.particle_q", q.ravel()), "snapshot.state.particle_q")
    _refused(env, _set(snap, "state.particle_q", q.astype(np.float32)), "snapshot.state.particle_q")
    _refused(env, _set(snap, "state.particle_qd", np.ma.masked_array(q)), "snapshot.state.particle_qd",
             SnapshotTypeError)
    _refused(env, _set(snap, "state.time", np.inf), "snapshot.state.time")
    pos = snap.grippers["position"].copy()
    pos[0, 0] = np.nan
    _refused(env, _set(snap, "grippers.position", pos), "snapshot.grippers.position")
    held = snap.grippers["held_by"].copy()
    held[0] = 1  # CornerLift has one gripper: index 0 only
    _refused(env, _set(snap, "grippers.held_by", held), "snapshot.grippers.held_by")
    _refused(env, _set(snap, "grippers.closed", np.zeros(1, dtype=bool)), "snapshot.grippers.held_by")


def test_a_foreign_object_is_a_typed_error(lift):
    env, _ = lift
    with pytest.raises(SnapshotTypeError, match="snapshot"):
        env.set_state({"state": None})


def test_a_valid_snapshot_still_restores_across_pickling_and_into_a_twin(lift):
    env, snap = lift
    twin = pickle.loads(pickle.dumps(env))
    assert twin.spec.id == ENV_ID
    twin.set_state(pickle.loads(pickle.dumps(snap)))
    a, b = twin.step(np.array([0.3, 0.1, 0.5, 1.0])), env.step(np.array([0.3, 0.1, 0.5, 1.0]))
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1:] == b[1:]


# ---------------------------------------------------------------------- property test
def _nan(a, i):
    a = np.array(a, dtype=float, copy=True)
    a.flat[i % a.size] = np.nan
    return a


MUTATIONS = {  # name -> (where, function of (value, i)); every one makes the snapshot invalid
    "nan": lambda a, i: _nan(a, i),
    "inf": lambda a, i: np.where(np.arange(a.size).reshape(a.shape) == i % a.size, np.inf, a.astype(float)),
    "flat": lambda a, i: a.ravel() if a.ndim > 1 else a[:-1],
    "extra_row": lambda a, i: np.concatenate([a, a[:1]]),
    "float32": lambda a, i: a.astype(np.float32 if a.dtype != np.float32 else np.float64),
    "int32": lambda a, i: a.astype(np.int32),
    "list": lambda a, i: a.tolist(),
    "masked": lambda a, i: np.ma.masked_array(a),
}
ARRAYS = ["state.particle_q", "state.particle_qd", "grippers.position", "grippers.velocity", "task.target",
          "last_obs"]
INT_ARRAYS = ["grippers.held_by", "grippers.slipped"]
SCALARS = {  # field -> bad values
    "format": [None, 0, SNAPSHOT_FORMAT + 1, "1", True],
    "env": ["RibbonDropEnv", None],
    "env_id": ["cloth_gym/CornerLift-v1", "CornerLiftEnv"],
    "material": ["thin_wool", None],
    "force_model": ["breen", None],
    "integrator": ["explicit", None],
    "observation_mode": ["keypoints", "rgb"],
    "model": [None, "model"],
    "rng": [None, np.random.RandomState(0), 3],
    "rng_seed": ["3", 2.5, -5],
    "elapsed_steps": [float("nan"), -1, 2.5, None, True],
    "diverged": [None, "False", 0],
    "grippers": [{}, None, "position"],
    "task": [{}, {"step": 5}, None],
}


def _mutated(snap, kind, where, i):
    if kind == "scalar":
        field, value = where
        return _copy(snap, **{field: value})
    out = _copy(snap)
    part, _, name = where.partition(".")
    get = {"state": lambda: getattr(out.state, name), "grippers": lambda: out.grippers[name],
           "task": lambda: out.task[name], "last_obs": lambda: out.last_obs}[part]
    a = get()
    if kind == "range":
        a = a.copy()
        a[i % a.size] = (-2, len(out.grippers["position"]) + i % 3)[i % 2]  # no such gripper
    else:
        a = MUTATIONS[kind](a, i)
    if part == "state":
        setattr(out.state, name, a)
    elif part == "grippers":
        out.grippers[name] = a
    elif part == "task":
        out.task[name] = a
    else:
        out = dataclasses.replace(out, last_obs=a)
    return out


_CASES = st.one_of(
    st.tuples(st.just("valid"), st.just(None)),
    st.tuples(st.sampled_from(sorted(MUTATIONS)), st.sampled_from(ARRAYS)),
    st.tuples(st.sampled_from(["range", "float32", "list", "flat"]), st.sampled_from(INT_ARRAYS)),
    st.tuples(st.just("scalar"), st.sampled_from([(f, v) for f, vs in SCALARS.items() for v in vs])),
)


def _snapshots():
    """Three snapshots of one CornerLift-v0 env: just reset, holding the corner, cloth asleep, each with
    the result of one step with a fixed action from it."""
    env = _env()
    env.reset(seed=5)
    expert = make_expert(env)
    out = []
    for n in (0, 12, 40):
        while env.elapsed_steps < n:
            env.step(expert.act() if n < 40 else np.array([0.0, 0.0, 0.0, -1.0]))
        out.append(env.get_state())
    return env, out


def test_mutated_snapshots_raise_or_replay_bit_for_bit():
    """≥ 2,000 examples, at least an eighth of them valid snapshots, each of which must restore to
    exactly the state it holds and then step exactly as the env it was taken from."""
    env, snaps = _snapshots()
    fresh = _env()  # restores go into another env of the same id, never reset
    counts = {"valid": 0, "refused": 0}

    @settings(max_examples=2000, deadline=None, database=None, derandomize=False,
              suppress_health_check=list(HealthCheck))
    @given(which=st.integers(0, 2), case=_CASES, i=st.integers(0, 10 ** 6),
           action=st.lists(st.floats(-1.5, 1.5, allow_nan=False), min_size=4, max_size=4))
    def prop(which, case, i, action):
        snap = snaps[which]
        kind, where = case
        if kind == "valid":
            fresh.set_state(snap)
            got = fresh.get_state()
            np.testing.assert_array_equal(got.state.particle_q, snap.state.particle_q)
            np.testing.assert_array_equal(got.grippers["held_by"], snap.grippers["held_by"])
            env.set_state(snap)
            a, b = fresh.step(np.array(action)), env.step(np.array(action))
            np.testing.assert_array_equal(a[0], b[0])
            assert a[1:] == b[1:]
            counts["valid"] += 1
            return
        with pytest.raises(ConfigError) as info:
            fresh.set_state(_mutated(snap, kind, where, i))
        assert isinstance(info.value, SnapshotError) and info.value.field.startswith("snapshot"), info.value
        counts["refused"] += 1

    prop()
    total = counts["valid"] + counts["refused"]
    assert total >= 2000 and counts["valid"] >= total / 8, counts  # one branch of four: about a fifth
