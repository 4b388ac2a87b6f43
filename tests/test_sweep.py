"""Hyperparameter sweeps: search spaces are validated data; a 2-trial sweep on a local Ray trains
two normal runs and reports their evaluations faithfully."""

import json

import numpy as np
import pytest
import yaml

from cloth_gym import ConfigError
from cloth_gym.agents.config import CONFIG_DIR, load_train_config, with_overrides
from cloth_gym.agents.sweep import SWEEP_CONFIG_DIR, load_search_space, parse_search_space, sweep


def test_shipped_spaces_load_and_fit_their_configs():
    for algo, conf in (("sac", "sac_curriculum.yaml"), ("ppo", "ppo.yaml")):
        space = load_search_space(SWEEP_CONFIG_DIR / f"{algo}.yaml")
        cfg = load_train_config(algo, "cloth_gym/CornerLift-v1", CONFIG_DIR / conf)
        for override in space.extremes():
            with_overrides(cfg, override)


def test_extremes_are_the_bounds_and_every_choice():
    space = parse_search_space({"learning_rate": {"loguniform": [1e-4, 1e-3]}, "batch_size": {"randint": [64, 70]},
                                "gamma": {"choice": [0.9, 0.99]}})
    ex = space.extremes()
    assert ex[:2] == [{"learning_rate": 1e-4}, {"learning_rate": 1e-3}]
    assert 1e-4 < ex[2]["learning_rate"] < 1e-3
    assert ex[3:] == [{"batch_size": 64}, {"batch_size": 69}, {"gamma": 0.9}, {"gamma": 0.99}]


@pytest.mark.parametrize("data, field", [
    ({"learning_rate": {"normal": [0, 1]}}, "space.learning_rate"),
    ({"learning_rate": {"loguniform": [0.0, 1e-3]}}, "space.learning_rate.loguniform"),
    ({"tau": {"uniform": [0.05, 0.01]}}, "space.tau.uniform"),
    ({"tau": {"uniform": [0.01]}}, "space.tau.uniform"),
    ({"batch_size": {"randint": [64.5, 128]}}, "space.batch_size.randint"),
    ({"gamma": {"choice": []}}, "space.gamma.choice"),
    ({"gamma": 0.99}, "space.gamma"),
    ({}, "space"),
])
def test_bad_search_spaces_name_the_field(data, field):
    with pytest.raises(ConfigError) as err:
        parse_search_space(data)
    assert err.value.field == field


def test_dotted_overrides_set_one_entry_and_keep_the_rest():
    cfg = load_train_config("sac", "cloth_gym/CornerLift-v0", CONFIG_DIR / "sac_curriculum.yaml")
    new = with_overrides(cfg, {"policy_kwargs.net_arch": [64, 64], "env_kwargs.sigma": 4.0, "gamma": 0.9})
    assert new.policy_kwargs == {**cfg.policy_kwargs, "net_arch": [64, 64]}
    assert new.env_kwargs == {**cfg.env_kwargs, "sigma": 4.0}
    assert new.algo_kwargs["gamma"] == 0.9 and new.env_wrapper == cfg.env_wrapper and new.callback == cfg.callback
    with pytest.raises(ConfigError, match="learning_rat"):
        with_overrides(cfg, {"learning_rat": 1e-3})
    with pytest.raises(ConfigError) as err:
        with_overrides(cfg, {"algo_kwargs.gamma": 0.9})
    assert err.value.field == "override.algo_kwargs.gamma"


def test_a_bad_key_fails_before_ray_starts(tmp_path):
    cfg = load_train_config("sac", "cloth_gym/CornerLift-v0")
    space = parse_search_space({"batch_size": {"uniform": [64, 256]}})  # floats for an integer key
    with pytest.raises(ConfigError, match="batch_size"):
        sweep(cfg, space, tmp_path, num_samples=1)
    assert not (tmp_path / "tune").exists()


@pytest.mark.slow
def test_two_trial_sweep_on_a_local_ray(tmp_path):
    cfg = load_train_config("sac", "cloth_gym/CornerLift-v0",
                            overrides={"n_timesteps": 120, "learning_starts": 40, "batch_size": 32})
    space = parse_search_space({"learning_rate": {"grid": [3e-4, 1e-3]}, "tau": {"uniform": [0.01, 0.02]}})
    res = sweep(cfg, space, tmp_path / "sweep", num_samples=1, seed=5, eval_freq=60, n_eval_episodes=2,
                scheduler="fifo", cpus=2)
    assert sorted(t["params"]["learning_rate"] for t in res.trials) == [3e-4, 1e-3]
    for t in res.trials:
        assert t["status"] == "done" and 0.01 <= t["params"]["tau"] <= 0.02
        run = yaml.safe_load(open(f"{t['run_dir']}/config.yaml"))[cfg.env_id]
        assert run["learning_rate"] == t["params"]["learning_rate"] and run["tau"] == t["params"]["tau"]
        ev = np.load(f"{t['run_dir']}/eval/evaluations.npz")
        assert list(ev["timesteps"]) == [60, 120] and t["env_steps"] == 120
        # what Tune ranked is what the run's own evaluation recorded last
        assert t["mean_return"] == pytest.approx(ev["results"][-1].mean())
        assert t["success_rate"] == pytest.approx(ev["successes"][-1].mean())
    report = json.loads((tmp_path / "sweep" / "sweep.json").read_text())
    assert report["best"] == res.trials[0] and len(report["trials"]) == 2
    key = [(t["success_rate"], t["mean_return"]) for t in res.trials]
    assert key == sorted(key, reverse=True)
    best = load_train_config("sac", cfg.env_id, tmp_path / "sweep" / "best.yaml")
    assert best == res.best_config and best.algo_kwargs["learning_rate"] == res.trials[0]["params"]["learning_rate"]


def test_without_ray_a_config_error_names_the_option_and_the_cluster_extra(monkeypatch):
    """Ray comes with the cluster extra only: asking for it without Ray installed is a ConfigError
    naming the option that asked and the extra to install, not a bare ModuleNotFoundError."""
    import sys

    from cloth_gym.agents.config import require_ray

    assert require_ray("sweep").__name__ == "ray"
    monkeypatch.setitem(sys.modules, "ray", None)  # an install without Ray: `import ray` raises
    with pytest.raises(ConfigError, match=r"^sweep: needs Ray.*cloth_gym\[cluster\]"):
        require_ray("sweep")
