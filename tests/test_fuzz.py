"""Property-based tests (Hypothesis): any input to a public entry point either works or raises a
cloth_gym error — never another exception type, a hang, or a NaN in an observation.

The profile is derandomised (the same examples on every run, so CI is deterministic) and small
enough for a few minutes; ``HYPOTHESIS_PROFILE=deep`` runs many more examples with fresh draws.
"""

import copy
import math
import os
import warnings

import gymnasium as gym
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import cloth_gym  # noqa: F401  (registers the ids)
from cloth_gym.errors import ClothGymError, ConfigError, MaterialError
from cloth_gym.materials import Material, fit_kes_curve, materials_dir
from cloth_gym.sim import Disc, ForceOptions, Rectangle, Ribbon, build_cloth
from cloth_gym.sim.implicit import ImplicitEuler
from cloth_gym.sim.integrators import SymplecticEuler
from cloth_gym.sim.obstacles import Box, Cylinder, Plane, Sphere

settings.register_profile("ci", derandomize=True, max_examples=100, deadline=None, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                                 HealthCheck.function_scoped_fixture])
settings.register_profile("deep", max_examples=2000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                                 HealthCheck.function_scoped_fixture])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

CORNER = "cloth_gym/CornerLift-v0"

# anything a user might pass where a value is expected
junk = st.one_of(
    st.none(), st.booleans(), st.integers(-10**12, 10**12), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8), st.binary(max_size=4), st.complex_numbers(max_magnitude=1e3),
    st.lists(st.floats(-1e3, 1e3), max_size=4), st.dictionaries(st.text(max_size=4), st.integers(), max_size=2),
)
yaml_junk = junk.filter(lambda v: not isinstance(v, complex))  # what a YAML file can hold
numbers = st.one_of(st.floats(-1e6, 1e6), st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 10**6))


def works_or_cloth_gym_error(fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, or None when it raised a cloth_gym error; anything else fails the test."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # KES fit warnings and Gymnasium's checker are not failures
            return fn(*args, **kwargs)
    except ClothGymError:
        return None


# ----------------------------------------------------------------------------- materials
def _shipped():
    return yaml.safe_load((materials_dir() / "thick_cotton.yaml").read_text())


def _paths(d, prefix=()):
    for k, v in d.items():
        yield prefix + (k,)
        if isinstance(v, dict):
            yield from _paths(v, prefix + (k,))


PATHS = list(_paths(_shipped()))


@st.composite
def mutated_materials(draw):
    """The shipped YAML's contents with a few leaves replaced, removed or added."""
    data = _shipped()
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(PATHS))
        node = data
        for k in path[:-1]:
            node = node.get(k) if isinstance(node, dict) else None
        if not isinstance(node, dict):
            continue
        action = draw(st.sampled_from(["replace", "number", "delete", "add"]))
        if action == "replace":
            node[path[-1]] = draw(junk)
        elif action == "number":
            node[path[-1]] = draw(numbers)
        elif action == "delete":
            node.pop(path[-1], None)
        else:
            node[draw(st.text(max_size=6))] = draw(junk)
    return data


@given(mutated_materials())
def test_any_material_mapping_loads_or_raises_a_material_error(data):
    m = works_or_cloth_gym_error(Material.from_dict, data)
    if m is not None:  # what loads is physically valid
        assert m.areal_density > 0 and 0 < m.compression_factor <= 1 and 0 <= m.friction <= 10
        for kind in (m.stretch, m.bending, m.shear):
            for c in (kind.warp, kind.weft):
                assert all(math.isfinite(v) and v >= 0 for v in c.as_array())


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=8),
       st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=8),
       st.sampled_from([("c1", "c2"), ("c0", "c1", "c2"), ("c0",), ()]))
def test_raw_kes_samples_fit_or_raise_a_material_error(x, y, terms):
    curve = works_or_cloth_gym_error(fit_kes_curve, x, y, terms=terms)
    if curve is not None:
        assert all(math.isfinite(v) and v >= 0 for v in curve.as_array())


@given(st.one_of(junk, st.sampled_from(["thick_cotton", "thin_wool", "no_such_fabric", "x.yaml", ""])))
def test_any_material_spec_loads_or_raises(spec):
    works_or_cloth_gym_error(cloth_gym.load_material, spec)


# ----------------------------------------------------------------------------- shapes and the builder
sizes = st.one_of(st.sampled_from([1.0, 2.0, 4.0, 10.0, 7.5]), numbers, junk)
spacings = st.one_of(st.sampled_from([0.5, 1.0, 2.0, 2.5]), st.floats(0.05, 60.0), junk)


@given(st.sampled_from([Rectangle, Ribbon, Disc]), sizes, sizes, spacings)
def test_any_shape_builds_or_raises_and_a_built_lattice_is_whole(kind, a, b, sigma):
    shape = works_or_cloth_gym_error(lambda: kind(a) if kind is Disc else kind(a, b))
    if shape is None:
        return
    model = works_or_cloth_gym_error(build_cloth, shape, sigma=sigma, max_particles=5000)
    if model is not None:
        n = model.particle_count
        assert n == shape.particle_count(model.sigma)
        assert np.isclose(model.particle_mass.sum(), model.material.areal_density * shape.area_cm2)  # area lumping
        assert np.all(np.isfinite(model.particle_q0))


@given(st.sampled_from(["point", "normal", "center", "half_extents", "radius", "height", "friction"]), junk)
def test_any_obstacle_argument_is_checked_when_made(name, value):
    makers = {
        "point": lambda v: Plane(point=v), "normal": lambda v: Plane(normal=v),
        "center": lambda v: Sphere(v, 1.0), "half_extents": lambda v: Box((0, 0, 0), v),
        "radius": lambda v: Sphere((0, 0, 0), v), "height": lambda v: Cylinder((0, 0, 0), 1.0, v),
        "friction": lambda v: Box((0, 0, 0), (1, 1, 1), friction=v),
    }
    ob = works_or_cloth_gym_error(makers[name], value)
    if ob is not None:
        t, p, mu = ob.pack()
        assert np.all(np.isfinite(p))


# ----------------------------------------------------------------------------- integrators
INTEGRATOR_KWARGS = ["max_dt", "tol", "max_iter", "vtol", "max_speed", "max_strain_percent", "newton_iters",
                     "scheme", "preconditioner", "strain_limit_percent", "sleep_speed", "slow_dt", "warm_start"]


@given(st.dictionaries(st.sampled_from(INTEGRATOR_KWARGS), st.one_of(junk, numbers), max_size=3))
def test_any_implicit_option_is_accepted_or_refused(kwargs):
    integ = works_or_cloth_gym_error(ImplicitEuler, **kwargs)
    if integ is not None:
        assert math.isfinite(integ.max_speed) and integ.max_dt > 0
        assert integ.max_strain_percent is None or math.isfinite(integ.max_strain_percent)


@pytest.fixture(scope="module")
def tiny():
    return build_cloth(Rectangle(2.0, 2.0), sigma=1.0, options=ForceOptions(air=False))


@given(st.sampled_from(["implicit", "explicit"]), st.one_of(numbers, junk), st.one_of(numbers, junk))
def test_advance_with_any_duration_and_step_works_or_refuses(tiny, kind, duration, dt):
    integ = ImplicitEuler() if kind == "implicit" else SymplecticEuler(on_unstable="substep")
    if isinstance(duration, (int, float)) and not isinstance(duration, bool) and isinstance(dt, (int, float)) \
            and not isinstance(dt, bool) and math.isfinite(duration) and math.isfinite(dt) and dt > 0:
        duration = min(abs(duration), 0.05, 200 * dt)  # keep a valid call short
    state = tiny.state()
    works_or_cloth_gym_error(integ.advance, tiny, state, None, duration, dt)
    assert np.all(np.isfinite(state.particle_q))


# ----------------------------------------------------------------------------- env kwargs
ENV_VALUES = {
    "material": st.one_of(st.sampled_from(["thick_cotton", "thin_wool", "silk"]), mutated_materials(),
                          st.fixed_dictionaries({}, optional={"friction": st.tuples(numbers, numbers),
                                                              "stretch_scale": st.tuples(numbers, numbers)}),
                          junk),
    "model": st.one_of(st.sampled_from(["kes", "breen"]), junk),
    "integrator": st.sampled_from(["implicit", "explicit", "rk4"]),
    "sigma": st.one_of(st.sampled_from([1.0, 2.0, 4.0, 5.0, 3.0]), junk),
    "control_dt": st.one_of(st.sampled_from([0.05, 0.02, 0.1]), numbers),
    "sim_dt": st.one_of(st.sampled_from([0.01, 0.005, 0.025]), numbers),
    "observation_mode": st.one_of(st.sampled_from(["state", "keypoints", "rgb"]), junk),
    "reward_weights": st.one_of(st.none(), st.dictionaries(st.sampled_from(["reach", "grasp", "success", "x"]),
                                                           numbers, max_size=2), junk),
    "image_size": st.one_of(st.sampled_from([16, 32]), junk),
    "max_step_cm": st.one_of(st.sampled_from([1.0, 2.0]), numbers),
    "strain_limiter_percent": st.one_of(st.none(), st.sampled_from([0.0, 1.0, 5.0]), numbers),
    "solver_tol": st.one_of(st.none(), numbers),
    "sleep_speed": st.one_of(st.none(), numbers),
    # strings only: gymnasium.make itself fails on a non-string render_mode (AttributeError) before the
    # env sees it; the env's own check is exercised in test_validation
    "render_mode": st.sampled_from([None, "rgb_array", "window"]),
    "bogus": junk,
}


def _check_obs(env, obs):
    assert obs.shape == env.observation_space.shape and obs.dtype == env.observation_space.dtype
    assert np.all(np.isfinite(obs)), "NaN or inf in an observation"


@settings(max_examples=60)
@given(st.dictionaries(st.sampled_from(sorted(ENV_VALUES)), st.none(), max_size=3).flatmap(
    lambda keys: st.fixed_dictionaries({k: ENV_VALUES[k] for k in keys})), st.integers(0, 2**32))
def test_any_env_kwargs_make_a_working_env_or_raise(kwargs, seed):
    env = works_or_cloth_gym_error(gym.make, CORNER, **kwargs)
    if env is None:
        return
    obs, info = env.reset(seed=seed)
    _check_obs(env, obs)
    for _ in range(2):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        _check_obs(env, obs)
        assert math.isfinite(reward) and isinstance(info["diverged"], bool)
    env.close()


# ----------------------------------------------------------------------------- actions and resets
@pytest.fixture(scope="module")
def corner_env():
    env = gym.make(CORNER)
    env.reset(seed=0)
    return env


real_dtypes = st.sampled_from([np.float64, np.float32, np.float16, np.int8, np.int64, np.uint8, np.bool_])
any_dtypes = st.one_of(real_dtypes, st.sampled_from([np.complex128, np.str_, np.bytes_, object,
                                                     "datetime64[s]", "timedelta64[s]"]))
actions = st.one_of(
    hnp.arrays(real_dtypes, st.sampled_from([(4,), (1, 4), (2, 2), (3,), (5,), (0,), ()])),
    hnp.arrays(any_dtypes, st.sampled_from([(4,), (2,)]), elements=None),
    st.lists(st.one_of(numbers, junk), min_size=0, max_size=5),
    junk,
)


@given(actions)
def test_any_action_steps_or_raises_and_never_gives_nan(corner_env, action):
    out = works_or_cloth_gym_error(corner_env.step, action)
    if out is None:
        return
    obs, reward, terminated, truncated, info = out
    if info["diverged"]:  # an extreme action may diverge: a truncated episode with the last finite obs
        assert truncated
        corner_env.reset(seed=0)
    _check_obs(corner_env, obs)


@given(st.one_of(st.none(), st.integers(-5, 2**70), junk),
       st.one_of(st.none(), st.dictionaries(st.sampled_from(["gripper_start", "target", 3]),
                                            st.one_of(st.sampled_from(["random", "corner", "held"]), junk),
                                            max_size=2), junk))
def test_any_seed_and_reset_options_reset_or_raise(corner_env, seed, options):
    out = works_or_cloth_gym_error(corner_env.reset, seed=seed, options=options)
    if out is not None:
        _check_obs(corner_env, out[0])


@given(st.one_of(numbers, junk), st.one_of(
    st.sampled_from([{"gripper_start": "corner"}, [{"gripper_start": "held"}, {"gripper_start": "corner"}]]),
    st.dictionaries(st.sampled_from(["gripper_start", "x"]), st.one_of(st.sampled_from(["corner", "up"]), junk),
                    max_size=2), st.lists(junk, max_size=2), junk),
       st.one_of(st.none(), st.integers(0, 10), junk))
def test_any_curriculum_wraps_or_raises(corner_env, probability, options, seed):
    from cloth_gym.wrappers import StartCurriculum

    wrapped = works_or_cloth_gym_error(StartCurriculum, corner_env, probability, options)
    if wrapped is not None:
        out = works_or_cloth_gym_error(wrapped.reset, seed=seed)
        if out is not None:
            _check_obs(corner_env, out[0])


# ----------------------------------------------------------------------------- training configs
def _train_config():
    from cloth_gym.agents.config import CONFIG_DIR

    return yaml.safe_load((CONFIG_DIR / "sac.yaml").read_text())


@st.composite
def mutated_train_configs(draw):
    data = _train_config()
    entry = data.setdefault("default", {})
    keys = ["n_timesteps", "n_envs", "normalize", "policy", "policy_kwargs", "learning_rate", "gamma",
            "batch_size", "env_wrapper", "callback", "env_kwargs", "buffer_size", "tau", "bogus"]
    for _ in range(draw(st.integers(1, 3))):
        entry[draw(st.sampled_from(keys))] = draw(st.one_of(yaml_junk, numbers, st.sampled_from(
            ["lin_1e-3", "lin_x", "MlpPolicy", "cloth_gym.wrappers.StartCurriculum", {"net_arch": [8]},
             {"activation_fn": ["relu"]}, [{"cloth_gym.agents.callbacks.GripExploration": {"probability": 2}}]])))
    return data


@given(st.one_of(mutated_train_configs().map(yaml.safe_dump), st.text(max_size=40)))
def test_any_training_config_file_loads_or_raises_a_config_error(tmp_path_factory, text):
    from cloth_gym.agents.config import load_train_config

    path = tmp_path_factory.mktemp("conf") / "sac.yaml"
    path.write_text(text)
    cfg = works_or_cloth_gym_error(load_train_config, "sac", CORNER, path)
    if cfg is not None:
        assert cfg.n_timesteps >= 1 and 1 <= cfg.n_envs <= 256


def test_fuzzing_catches_what_it_should():
    """The harness itself: a non-cloth_gym exception is not swallowed."""
    def refuse():
        raise ConfigError("x", "y")

    with pytest.raises(ZeroDivisionError):
        works_or_cloth_gym_error(lambda: 1 / 0)
    assert works_or_cloth_gym_error(refuse) is None
    assert isinstance(copy.deepcopy(MaterialError("a", "b")), MaterialError)
