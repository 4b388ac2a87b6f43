"""Evaluate a policy on a cloth_gym env: a trained run, the scripted expert, or random actions.

:func:`evaluate_policy_source` runs ``n_episodes`` episodes with seeds
``seed, seed + 1, ...`` (so every policy sees the same starting states) and
reports the success rate (``info["is_success"]`` at the end of an episode),
the return (mean ± std), episode lengths and divergences, optionally writing a
GIF of the first episode.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

__all__ = ["Policy", "load_policy", "evaluate_policy_source", "run_episode"]


class Policy:
    """``act(obs) → action`` for one env; ``reset(env)`` at the start of each episode."""

    name = "policy"

    def reset(self, env) -> None:
        pass

    def act(self, obs) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError


class RandomPolicy(Policy):
    name = "random"

    def reset(self, env):
        self.space = env.action_space

    def act(self, obs):
        return self.space.sample()


class ExpertPolicy(Policy):
    name = "expert"

    def reset(self, env):
        from .experts import make_expert

        self.expert = make_expert(env)

    def act(self, obs):
        return self.expert.act()


class TrainedPolicy(Policy):
    """A saved SB3 model with its VecNormalize statistics (if it was trained with them)."""

    def __init__(self, run_dir, deterministic: bool = True):
        from .training import load_run

        self.model, self.entry, self.env_id, self.env_kwargs, self.norm = load_run(run_dir)
        self.deterministic = deterministic
        self.name = str(run_dir)

    def act(self, obs):
        if self.norm is not None:
            obs = self.norm.normalize_obs(obs)
        action, _ = self.model.predict(obs, deterministic=self.deterministic)
        return action


def load_policy(source: str) -> Policy:
    """``"expert"``, ``"random"`` or a run directory written by :func:`cloth_gym.agents.training.train`."""
    if source == "expert":
        return ExpertPolicy()
    if source == "random":
        return RandomPolicy()
    if not (Path(source) / "model.zip").exists():
        from cloth_gym.errors import ConfigError

        raise ConfigError("policy", f"expected 'expert', 'random' or a run directory with model.zip, got {source!r}")
    return TrainedPolicy(source)


def run_episode(env, policy: Policy, seed: int, frames: list | None = None) -> dict:
    """One episode from ``env.reset(seed=seed)``; appends rendered frames to ``frames`` if given."""
    obs, info = env.reset(seed=seed)
    env.action_space.seed(seed)
    policy.reset(env)
    total, steps = 0.0, 0
    if frames is not None:
        frames.append(env.render())
    while True:
        obs, r, term, trunc, info = env.step(policy.act(obs))
        total += float(r)
        steps += 1
        if frames is not None:
            frames.append(env.render())
        if term or trunc:
            break
    return {"return": total, "length": steps, "success": bool(info.get("is_success", False)),
            "diverged": bool(info.get("diverged", False))}


def evaluate_policy_source(source: str, env_id: str | None = None, n_episodes: int = 10, seed: int = 0,
                           env_kwargs: dict | None = None, gif: str | Path | None = None,
                           out_json: str | Path | None = None) -> dict:
    """Evaluate ``source`` (see :func:`load_policy`) on ``env_id`` (a trained run's own env and
    kwargs by default). Returns the summary dict (also written to ``out_json``)."""
    import gymnasium as gym

    import cloth_gym  # noqa: F401  (registers the ids)
    from cloth_gym.errors import ConfigError

    policy = load_policy(source)
    if isinstance(policy, TrainedPolicy):
        env_id = env_id or policy.env_id
        env_kwargs = {**policy.env_kwargs, **(env_kwargs or {})}
    if env_id is None:
        raise ConfigError("env", "an env id is needed for the expert and random policies")
    kwargs = dict(env_kwargs or {})
    if gif is not None:
        kwargs["render_mode"] = "rgb_array"
    env = gym.make(env_id, **kwargs)
    episodes = []
    frames: list = []
    t0 = time.perf_counter()
    for k in range(n_episodes):
        episodes.append(run_episode(env, policy, seed + k, frames if (gif is not None and k == 0) else None))
    wall = time.perf_counter() - t0
    env.close()
    rets = np.array([e["return"] for e in episodes])
    summary = {
        "policy": policy.name, "env_id": env_id, "env_kwargs": kwargs, "episodes": n_episodes, "seed": seed,
        "success_rate": float(np.mean([e["success"] for e in episodes])),
        "return_mean": float(rets.mean()), "return_std": float(rets.std()),
        "length_mean": float(np.mean([e["length"] for e in episodes])),
        "diverged": int(sum(e["diverged"] for e in episodes)), "wall_s": wall, "per_episode": episodes,
    }
    if gif is not None:
        from cloth_gym.render import save_gif

        summary["gif"] = str(save_gif(gif, frames, fps=env.metadata.get("render_fps", 20)))
    if out_json is not None:
        Path(out_json).parent.mkdir(parents=True, exist_ok=True)
        Path(out_json).write_text(json.dumps(summary, indent=2))
    return summary
