"""An env's settings: one checked object per env, versions as registry kwargs (cheap: no stepping)."""

from __future__ import annotations

import pickle

import gymnasium as gym
import pytest

import cloth_gym  # noqa: F401  (registers the ids)
from cloth_gym.envs import CORNER_LIFT_V1, CORNER_LIFT_V2, ENV_SPECS, RIBBON_DROP_V1, V1
from cloth_gym.envs.settings import OPTIONS, EnvSettings
from cloth_gym.errors import ConfigError, ConfigTypeError

#: what each versioned id's spec must set (the v0 ids: nothing, their classes' defaults)
VERSION_KWARGS = {
    "cloth_gym/CornerLift-v1": {"sigma": 1.0, "observation_dtype": "float32", "regrasp_slipped": False,
                                "sim_defaults": {"max_dt": 5e-3, "preconditioner": "band", "max_travel": 0.5}},
    "cloth_gym/CornerLift-v2": {"sigma": 1.0, "sim_defaults": {"max_dt": 1e-2, "preconditioner": "band",
                                                                "max_travel": 0.5}},
    "cloth_gym/CornerLiftGoal-v1": {"sigma": 1.0, "sim_defaults": {"max_dt": 5e-3, "preconditioner": "band",
                                                                    "max_travel": 0.5}},
    "cloth_gym/CornerLiftGoal-v2": {"sigma": 1.0, "sim_defaults": {"max_dt": 1e-2, "preconditioner": "band",
                                                                    "max_travel": 0.5}},
    "cloth_gym/DrapeOntoTable-v1": {"sigma": 1.0, "mass_lumping": "area", "damping_model": "strain-rate",
                                    "bounded_observations": True, "sim_defaults": {"max_travel": 0.5}},
    "cloth_gym/RibbonDrop-v1": {"sigma": 1.0, "target_rgb": (250, 150, 20),
                                "sim_defaults": {"max_dt": 5e-3, "strain_limit_percent": None, "max_travel": 0.5}},
}


@pytest.mark.parametrize("env_id", sorted(ENV_SPECS))
def test_the_spec_of_each_id_holds_its_versions_settings(env_id):
    kwargs = gym.spec(env_id).kwargs
    if env_id.endswith("-v0"):
        assert kwargs == {}
        return
    for k, v in VERSION_KWARGS[env_id].items():
        assert kwargs[k] == v, k
    assert set(kwargs) <= set(OPTIONS)
    # every v1 setting is in every later id's kwargs; v2 differs from v1 in the substep only
    assert {k: v for k, v in kwargs.items() if k != "sim_defaults"} == {k: v for k, v in V1.items()
                                                                          if k != "sim_defaults"}
    assert {**CORNER_LIFT_V1["sim_defaults"], "max_dt": 1e-2} == CORNER_LIFT_V2["sim_defaults"]


@pytest.mark.parametrize("env_id", ["cloth_gym/CornerLift-v2", "cloth_gym/RibbonDrop-v1"])
def test_an_env_made_from_an_id_has_the_settings_its_spec_lists(env_id):
    env = gym.make(env_id)
    u = env.unwrapped
    s = u.settings
    assert isinstance(s, EnvSettings) and dict(s.kwargs) == gym.spec(env_id).kwargs == env.spec.kwargs
    assert s.physics.sigma == 1.0 and s.physics.force_options.mass_lumping == "area"
    assert s.view.observation_dtype == "float32" and s.view.bounded_observations
    assert s.task.gripper.regrasp_slipped is False and s.physics.sim["max_travel"] == 0.5
    assert s.physics.sim_dt == (0.01 if "CornerLift" in env_id else 0.005) == u.sim_dt
    with pytest.raises(AttributeError):  # frozen
        s.physics.sigma = 2.0
    # pickling replays the kwargs: the copy has the same settings
    assert pickle.loads(pickle.dumps(u)).settings == s


def test_user_kwargs_override_the_versions():
    u = gym.make("cloth_gym/CornerLift-v2", sigma=2.0, sim_dt=0.005, integrator="implicit").unwrapped
    assert (u.sigma, u.sim_dt, u.sim["preconditioner"]) == (2.0, 0.005, "band")
    # the version's solver defaults are defaults: the explicit integrator and Breen's model still work
    assert gym.make("cloth_gym/CornerLift-v1", integrator="explicit").unwrapped.sim == {}
    breen = gym.make("cloth_gym/RibbonDrop-v1", model="breen").unwrapped
    assert (breen.sim_dt, breen.strain_limiter_percent) == (2.5e-3, None)
    # sim_defaults given by a user replace the version's key by key
    u = gym.make("cloth_gym/CornerLift-v0", sim_defaults={"max_dt": 0.025, "preconditioner": "lines"}).unwrapped
    assert (u.sim_dt, u.sim["preconditioner"], u.sim["tol"]) == (0.025, "lines", 1e-4)
    assert gym.make("cloth_gym/RibbonDrop-v0", **RIBBON_DROP_V1).unwrapped.settings.physics.sim == \
        gym.make("cloth_gym/RibbonDrop-v1").unwrapped.settings.physics.sim


@pytest.mark.parametrize("env_id", ["cloth_gym/CornerLift-v0", "cloth_gym/CornerLiftGoal-v2",
                                    "cloth_gym/DrapeOntoTable-v1"])
def test_an_unknown_kwarg_is_a_config_error_naming_the_valid_ones(env_id):
    with pytest.raises(ConfigError) as info:
        gym.make(env_id, sigmaa=1.0)
    assert isinstance(info.value, ConfigTypeError) and info.value.field == "sigmaa"
    for valid in OPTIONS:
        assert f"'{valid}'" in info.value.message


@pytest.mark.parametrize("kwargs, field", [
    (dict(sim_defaults={"max_dtt": 0.01}), "sim_defaults.max_dtt"),
    (dict(sim_defaults={"max_dt": -1.0}), "sim_defaults.max_dt"),
    (dict(sim_defaults=[0.01]), "sim_defaults"),
    (dict(regrasp_slipped="no"), "regrasp_slipped"),
    (dict(bounded_observations=1), "bounded_observations"),
])
def test_the_new_kwargs_are_checked_naming_the_field(kwargs, field):
    with pytest.raises(ConfigError) as info:
        gym.make("cloth_gym/CornerLift-v0", **kwargs)
    assert info.value.field == field
