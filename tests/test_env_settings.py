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
    "cloth_gym/DrapeOntoTable-v2": {"sigma": 1.0, "mass_lumping": "area", "damping_model": "strain-rate",
                                    "bounded_observations": True,
                                    "sim_defaults": {"max_travel": 0.5, "retry_diverged": True}},
    "cloth_gym/RibbonDrop-v1": {"sigma": 1.0, "target_rgb": (250, 150, 20),
                                "sim_defaults": {"max_dt": 5e-3, "strain_limit_percent": None, "max_travel": 0.5}},
    "cloth_gym/RibbonDrop-v2": {"sigma": 1.0, "target_rgb": (250, 150, 20), "start_tilt_deg": 0.5,
                                "sim_defaults": {"max_dt": 5e-3, "strain_limit_percent": None, "max_travel": 0.5,
                                                 "scheme": "bdf2", "newton_iters": 10, "newton_tol": 0.1,
                                                 "momentum_exact": True}},
    "cloth_gym/RibbonDrop-v3": {"sigma": 1.0, "target_rgb": (250, 150, 20), "start_tilt_deg": 0.5,
                                "sim_defaults": {"max_dt": 5e-3, "strain_limit_percent": None, "max_travel": 0.5,
                                                 "scheme": "bdf2", "newton_iters": 10, "newton_tol": 0.1,
                                                 "momentum_exact": True, "couple_collisions": True}},
    "cloth_gym/RibbonDrop-v4": {"sigma": 1.0, "target_rgb": (250, 150, 20), "start_tilt_deg": 0.5,
                                "sim_defaults": {"max_dt": 5e-3, "strain_limit_percent": None, "max_travel": 0.5,
                                                 "scheme": "bdf2", "newton_iters": 10, "newton_tol": 0.1,
                                                 "momentum_exact": True, "couple_collisions": True,
                                                 "refine_strain_rise": 0.3}},
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
    # every v1 setting is in every later id's kwargs; CornerLift-v2 differs from v1 in the substep only,
    # RibbonDrop-v2 to -v4 in their solver and their start's tilt
    assert {k: v for k, v in kwargs.items() if k not in ("sim_defaults", "start_tilt_deg")} == \
        {k: v for k, v in V1.items() if k != "sim_defaults"}
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


def test_start_tilt_is_ribbondrops_and_keeps_the_other_draws():
    """RibbonDrop-v2's start is v1's rotated out of the ribbon's plane by 0.5° about the held end
    (the free end 40 cm below moves 40·sin 0.5° = 0.35 cm along the ribbon's normal, x), drawn
    after v1's draws: the same seed gives v1's target and, but for the tilt, v1's start. Other
    envs refuse a tilt."""
    import math

    import numpy as np

    from cloth_gym.envs.ribbon_drop import RibbonDropEnv

    v1, v2 = gym.make("cloth_gym/RibbonDrop-v1").unwrapped, gym.make("cloth_gym/RibbonDrop-v2").unwrapped
    sides = set()
    for seed in range(6):
        v1.reset(seed=seed)
        v2.reset(seed=seed)
        np.testing.assert_array_equal(v1.target_center, v2.target_center)
        q1, q2 = v1.physics.state.particle_q, v2.physics.state.particle_q
        held = RibbonDropEnv.held_end(v2, v2.physics.model)
        np.testing.assert_allclose(q2[held], q1[held], atol=1e-12)
        depth = q1[held, 2].mean() - q1[:, 2]  # cm below the held end
        shift = q2[:, 0] - q1[:, 0]
        side = np.sign(shift[np.argmax(depth)])
        sides.add(side)
        np.testing.assert_allclose(np.abs(shift), depth * math.sin(math.radians(0.5)), atol=1e-9)
        np.testing.assert_allclose(q2[:, 2] - q1[:, 2], -depth * (math.cos(math.radians(0.5)) - 1), atol=1e-9)
        # a rigid rotation: every edge keeps its length
        e = v2.physics.model.edge_indices
        np.testing.assert_allclose(np.linalg.norm(q2[e[:, 0]] - q2[e[:, 1]], axis=1),
                                   np.linalg.norm(q1[e[:, 0]] - q1[e[:, 1]], axis=1), atol=1e-12)
    assert sides == {-1.0, 1.0}
    with pytest.raises(ConfigError, match="start_tilt_deg"):
        gym.make("cloth_gym/CornerLift-v2", start_tilt_deg=1.0)
    with pytest.raises(ConfigError, match="start_tilt_deg"):
        gym.make("cloth_gym/RibbonDrop-v2", start_tilt_deg=30.0)
