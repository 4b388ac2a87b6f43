"""Hyperparameter sweeps on Ray Tune, each trial a normal training run.

A sweep starts from a training config (:func:`~cloth_gym.agents.config.load_train_config`),
samples hyperparameters from a search space, and trains each sample with
:func:`~cloth_gym.agents.training.train` into its own run directory. Every evaluation
(``EvalCallback``'s mean return and success rate) is reported to Tune, so that the ASHA
scheduler can stop the trials that lag behind at the same number of env steps.

The search space is data, a YAML file mapping a config key to one distribution::

    learning_rate: {loguniform: [1.0e-4, 3.0e-3]}
    gamma: {choice: [0.95, 0.98, 0.99]}
    tau: {uniform: [0.005, 0.05]}
    batch_size: {choice: [128, 256, 512]}
    policy_kwargs.net_arch: {choice: [[128, 128], [256, 256]]}

Keys are those of a training config, or ``env_kwargs.<name>`` / ``policy_kwargs.<name>`` for
one entry of those mappings. Distributions: ``uniform: [lo, hi]``, ``loguniform: [lo, hi]``
(0 < lo), ``randint: [lo, hi]`` (integers lo ≤ x < hi), ``choice: [a, b, ...]`` and
``grid: [a, b, ...]`` (every value, each ``num_samples`` times, as Tune's ``grid_search``).
Every key and each distribution's extreme values are checked against the config before Ray
starts, so a typo fails at once with the valid keys named.

Where it runs: without an address, a Ray is started on this machine with ``cpus`` CPUs and
stopped after; with ``address`` (``ray://host:10001`` or ``auto``), the trials go to that
cluster, whose nodes must have cloth_gym installed and must reach ``out_dir`` (a shared
file system, or a ``storage`` URI Tune can write, such as ``s3://bucket/path``).

Outputs, in ``out_dir``: ``sweep.json`` (every trial's parameters, last evaluation, env steps,
status and run directory; the best trial), ``best.yaml`` (the best trial's config as a zoo
file, ready for ``scripts/train.py --conf``), and ``tune/`` (Tune's experiment, with each
trial's run directory under ``<trial>/run``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import yaml
from stable_baselines3.common.callbacks import BaseCallback

from cloth_gym.errors import ClothGymError, ConfigError, ConfigTypeError
from cloth_gym.materials import configs_dir
from cloth_gym.validation import integer, is_file, read_yaml, real

from .config import TrainConfig, require_ray, with_overrides
from .training import train

__all__ = ["SearchSpace", "SweepResult", "load_search_space", "sweep", "DISTRIBUTIONS", "METRICS", "SCHEDULERS",
           "SWEEP_CONFIG_DIR"]

#: the distributions a search space may use
DISTRIBUTIONS = ("uniform", "loguniform", "randint", "choice", "grid")
#: what a sweep maximises: the last evaluation's success rate or its mean return
METRICS = ("success_rate", "mean_return")
#: "asha" stops trials that lag at the same env steps (Tune's ASHAScheduler); "fifo" runs all to the end
SCHEDULERS = ("asha", "fifo")


#: the shipped search spaces (``configs/sweep/<algo>.yaml``)
SWEEP_CONFIG_DIR = configs_dir() / "sweep"


@dataclass(frozen=True)
class SearchSpace:
    """Hyperparameter distributions: ``((key, distribution, args), ...)``, validated.

    ``args`` is ``(lo, hi)`` for ``uniform``, ``loguniform`` and ``randint``, the tuple of values
    for ``choice`` and ``grid``."""

    params: tuple

    def to_tune(self) -> dict:
        """Tune's ``param_space``."""
        from ray import tune

        make = {"uniform": lambda a: tune.uniform(*a), "loguniform": lambda a: tune.loguniform(*a),
                "randint": lambda a: tune.randint(*a), "choice": lambda a: tune.choice(list(a)),
                "grid": lambda a: tune.grid_search(list(a))}
        return {key: make[dist](args) for key, dist, args in self.params}

    def extremes(self) -> list[dict]:
        """One override per key and telling value a trial can draw: each bound, each choice, and for
        the continuous distributions one value inside (an integer key's error shows there):
        what :func:`sweep` validates before it starts."""
        out = []
        for key, dist, args in self.params:
            lo, hi = (float(v) for v in args[:2]) if dist in ("uniform", "loguniform") else (0.0, 0.0)
            if dist == "uniform":
                out += [{key: lo}, {key: hi}, {key: lo + (hi - lo) / math.e}]
            elif dist == "loguniform":
                out += [{key: lo}, {key: hi}, {key: lo * (hi / lo) ** (1 / math.e)}]
            elif dist == "randint":
                out += [{key: int(args[0])}, {key: int(args[1]) - 1}]
            else:
                out += [{key: v} for v in args]
        return out


def parse_search_space(data, source: str = "space") -> SearchSpace:
    """A :class:`SearchSpace` from a mapping ``{key: {distribution: args}}`` (as in the YAML)."""
    if not isinstance(data, dict) or not data:
        raise ConfigTypeError(source, f"must map config keys to distributions, got {data!r}")
    params = []
    for key, spec in data.items():
        field = f"{source}.{key}"
        if not isinstance(key, str):
            raise ConfigTypeError(source, f"keys must be config keys (strings), got {key!r}")
        if not isinstance(spec, dict) or len(spec) != 1:
            raise ConfigTypeError(field, f"must be one {{distribution: args}} with distribution in "
                                  f"{list(DISTRIBUTIONS)}, got {spec!r}")
        (dist, args), = spec.items()
        if dist not in DISTRIBUTIONS:
            raise ConfigError(field, f"unknown distribution {dist!r}; one of {list(DISTRIBUTIONS)}")
        if not isinstance(args, list) or not args:
            raise ConfigTypeError(f"{field}.{dist}", f"must be a non-empty list, got {args!r}")
        if dist in ("uniform", "loguniform", "randint"):
            if len(args) != 2:
                raise ConfigError(f"{field}.{dist}", f"must be [lo, hi], got {args!r}")
            for v in args:
                if dist == "randint":
                    integer(f"{field}.{dist}", v, -2**63, 2**63 - 1)
                else:
                    real(f"{field}.{dist}", v)
            lo, hi = args
            if not lo < hi:
                raise ConfigError(f"{field}.{dist}", f"needs lo < hi, got {args!r}")
            if dist == "loguniform" and lo <= 0:
                raise ConfigError(f"{field}.{dist}", f"needs 0 < lo, got {args!r}")
        params.append((key, dist, tuple(args)))
    return SearchSpace(tuple(params))


def load_search_space(path: str | Path) -> SearchSpace:
    """The search space of a YAML file (see the module docstring)."""
    if not is_file(path):
        raise ConfigError("space", f"no such search-space file: {path}")
    return parse_search_space(read_yaml(path, "space"), "space")


@dataclass(frozen=True)
class SweepResult:
    """out_dir: where ``sweep.json`` and ``best.yaml`` are. trials: one dict per trial
    (``params``, ``success_rate``, ``mean_return``, ``env_steps``, ``status``, ``run_dir``),
    best first. best_config: the best trial's :class:`TrainConfig`."""

    out_dir: Path
    trials: list
    best_config: TrainConfig


class _TuneReport(BaseCallback):
    """After each evaluation, reports env steps, mean return and success rate to Tune (the
    ``callback_after_eval`` of SB3's ``EvalCallback``, whose results are its ``parent``'s)."""

    def _on_step(self) -> bool:
        from ray import tune

        ev = self.parent
        successes = ev.evaluations_successes[-1] if ev.evaluations_successes else []
        tune.report({"env_steps": int(self.num_timesteps), "mean_return": float(ev.last_mean_reward),
                     "success_rate": float(sum(successes) / len(successes)) if successes else 0.0})
        return True


def _trial(params: dict, *, cfg: TrainConfig, seed: int, eval_freq: int, n_eval_episodes: int) -> None:
    from ray import tune

    run_dir = Path(tune.get_context().get_trial_dir()) / "run"
    train(with_overrides(cfg, params), run_dir, seed=seed, eval_freq=eval_freq, n_eval_episodes=n_eval_episodes,
          after_eval=_TuneReport(), command=f"sweep trial {json.dumps(params, default=str)}")


def sweep(cfg: TrainConfig, space: SearchSpace, out_dir: str | Path, *, num_samples: int = 8, seed: int = 0,
          eval_freq: int = 5000, n_eval_episodes: int = 10, metric: str = "success_rate",
          scheduler: str = "asha", cpus: int = 2, cpus_per_trial: int = 1, address: str | None = None,
          storage: str | None = None, verbose: int = 0) -> SweepResult:
    """Train ``num_samples`` samples of ``space`` applied to ``cfg`` on Ray Tune and keep the best.

    Every trial trains with the same ``seed`` and evaluates every ``eval_freq`` env steps on
    ``n_eval_episodes`` episodes (the evaluation envs' seeds as in :func:`train`); ``metric``
    (one of :data:`METRICS`) of the last evaluation ranks them, the mean return breaking ties.
    scheduler: one of :data:`SCHEDULERS`; ASHA may stop a trial at any evaluation after the
    first quarter of ``n_timesteps``. cpus: the local Ray's CPUs (ignored with ``address``);
    cpus_per_trial: CPUs each trial reserves, so ``cpus // cpus_per_trial`` trials run at once.
    storage: where Tune keeps the experiment (default ``out_dir/tune``; on a cluster a path all
    nodes share, or a URI). Returns the :class:`SweepResult`; raises :class:`ClothGymError`
    when no trial finished an evaluation."""
    if metric not in METRICS:
        raise ConfigError("metric", f"must be one of {list(METRICS)}, got {metric!r}")
    if scheduler not in SCHEDULERS:
        raise ConfigError("scheduler", f"must be one of {list(SCHEDULERS)}, got {scheduler!r}")
    for name, v in (("num_samples", num_samples), ("eval_freq", eval_freq), ("n_eval_episodes", n_eval_episodes),
                    ("cpus", cpus), ("cpus_per_trial", cpus_per_trial)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ConfigError(name, f"must be an integer >= 1, got {v!r}")
    if eval_freq > cfg.n_timesteps:
        raise ConfigError("eval_freq", f"must be at most n_timesteps ({cfg.n_timesteps}) for any trial to "
                          f"report, got {eval_freq}")
    for override in space.extremes():  # a bad key or value fails here, not in a Ray worker
        with_overrides(cfg, override)

    ray = require_ray("sweep")
    from ray import tune
    from ray.tune.schedulers import ASHAScheduler, FIFOScheduler

    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    sched = FIFOScheduler() if scheduler == "fifo" else ASHAScheduler(
        time_attr="env_steps", max_t=cfg.n_timesteps, grace_period=max(eval_freq, cfg.n_timesteps // 4),
        reduction_factor=3)
    started = not ray.is_initialized()
    if started:
        kw = {} if address else {"num_cpus": cpus}
        ray.init(address=address, include_dashboard=False, log_to_driver=verbose > 0, **kw)
    try:
        trainable = tune.with_resources(
            tune.with_parameters(_trial, cfg=cfg, seed=seed, eval_freq=eval_freq, n_eval_episodes=n_eval_episodes),
            {"cpu": cpus_per_trial})
        tuner = tune.Tuner(
            trainable, param_space=space.to_tune(),
            tune_config=tune.TuneConfig(num_samples=num_samples, metric=metric, mode="max", scheduler=sched,
                                        trial_dirname_creator=lambda trial: f"trial_{trial.trial_id}"),
            run_config=tune.RunConfig(name="tune", storage_path=storage or str(out_dir), verbose=verbose))
        grid = tuner.fit()
    finally:
        if started:
            ray.shutdown()

    trials = []
    for res in grid:
        m = res.metrics or {}
        trials.append({"params": {k: res.config[k] for k, _, _ in space.params},
                       "success_rate": m.get("success_rate"), "mean_return": m.get("mean_return"),
                       "env_steps": m.get("env_steps"), "status": "error" if res.error else "done",
                       "error": str(res.error).splitlines()[0] if res.error else None,
                       "run_dir": str(Path(res.path) / "run")})
    done = [t for t in trials if t["success_rate"] is not None]
    if not done:
        errors = sorted({t["error"] for t in trials if t["error"]})
        raise ClothGymError(f"sweep: no trial finished an evaluation (errors: {errors})")
    other = "mean_return" if metric == "success_rate" else "success_rate"
    trials.sort(key=lambda t: (t["success_rate"] is not None, t[metric] or 0.0, t[other] or 0.0), reverse=True)
    best = with_overrides(cfg, trials[0]["params"])
    (out_dir / "best.yaml").write_text(yaml.safe_dump({cfg.env_id: best.to_zoo_dict()}, sort_keys=False))
    (out_dir / "sweep.json").write_text(json.dumps(
        {"algo": cfg.algo, "env_id": cfg.env_id, "metric": metric, "scheduler": scheduler, "seed": seed,
         "num_samples": num_samples, "eval_freq": eval_freq, "n_eval_episodes": n_eval_episodes,
         "base_config": cfg.to_zoo_dict(), "space": {k: {d: list(a)} for k, d, a in space.params},
         "best": trials[0], "trials": trials}, indent=2, default=str))
    return SweepResult(out_dir, trials, best)
