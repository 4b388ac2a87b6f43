"""SB3 callbacks that the training configs name under rl-baselines3-zoo's ``callback`` key.

What SAC needs beyond its constructor arguments on cloth_gym's tasks is given as callbacks, so
that every shipped config stays in the zoo's format and trains through the zoo too, from any
directory (the baselines ship inside the package as ``cloth_gym.agents``)::

    cloth_gym/CornerLift-v0:
      ...
      callback:
        - cloth_gym.agents.callbacks.GripExploration: {probability: 0.01, mean_steps: 20}

    python -m rl_zoo3.train --algo sac --env cloth_gym/CornerLift-v0 --gym-packages cloth_gym \\
        -conf configs/train/sac_curriculum.yaml

Both act once, when training starts (``on_training_start``, after SB3 has reset the envs and
before the first env step), and only on the off-policy algorithms (SAC, TQC): anything else is a
:class:`~cloth_gym.errors.ConfigError`, at ``load_train_config`` for ``scripts/train.py`` and at the
start of training under the zoo.

* :class:`GripExploration` makes :class:`cloth_gym.agents.exploration.GripHoldNoise` the algorithm's action
  noise (ez-greedy on the grip).
* :class:`ExpertDemos` puts scripted-expert episodes (:mod:`cloth_gym.agents.experts`) into the replay buffer
  and optionally takes gradient steps on them (SACfD style): :func:`add_expert_demos`.

Seeds: both derive theirs from the algorithm's seed (``model.seed``, 0 when unseeded): the noise
uses it as is, the demonstrations use episodes ``seed + DEMO_SEED_OFFSET + k`` (evaluation uses
10000+, the tests 1000+).
"""

from __future__ import annotations

import time

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from cloth_gym.errors import ConfigError

from .exploration import GripHoldNoise

__all__ = ["GripExploration", "ExpertDemos"]

DEMO_SEED_OFFSET = 20_000


def _require_off_policy(callback: BaseCallback, what: str) -> None:
    if not isinstance(callback.model, OffPolicyAlgorithm):
        raise ConfigError(f"callback.{type(callback).__name__}", f"{what}: only for off-policy algorithms "
                          f"(SAC, TQC), not {type(callback.model).__name__}")


class GripExploration(BaseCallback):
    """Make :class:`~cloth_gym.agents.exploration.GripHoldNoise` (``probability``, ``mean_steps``; ranges
    there) the action noise of the off-policy algorithm being trained.

    The noise is made once, at the first training start (size of the action, ``model.n_envs``
    stretches, seeded with ``model.seed``), and set again at every later start: SB3 would
    otherwise wrap it in a ``VectorizedActionNoise`` of copies that share one generator."""

    off_policy_only = True

    def __init__(self, probability: float, mean_steps: float, verbose: int = 0):
        super().__init__(verbose)
        try:  # the noise's own checks, now rather than when training starts
            GripHoldNoise(4, probability, mean_steps)
        except ConfigError as err:
            raise ConfigError(f"GripExploration.{err.field.rsplit('.', 1)[-1]}", err.message) from None
        self.probability = float(probability)
        self.mean_steps = float(mean_steps)
        self.noise: GripHoldNoise | None = None

    def _on_training_start(self) -> None:
        _require_off_policy(self, "grip exploration is action noise")
        if self.noise is None:
            self.noise = GripHoldNoise(self.model.action_space.shape[0], self.probability, self.mean_steps,
                                       seed=self.model.seed, n_envs=self.model.n_envs)
        self.model.action_noise = self.noise

    def _on_step(self) -> bool:
        return True


class ExpertDemos(BaseCallback):
    """Put ``episodes`` scripted-expert episodes of the training env's task into the replay buffer
    when training first starts, take ``pretrain_steps`` gradient steps on the buffer, then
    ``bc_steps`` steps of behaviour cloning (:func:`behaviour_clone`: the actor's deterministic
    action regressed onto the demonstrations', so that learning starts from the expert's motion).
    With ``bc_every`` = k > 0, one more behaviour-cloning step on the demonstrations every k env
    steps (counted over all the vector env's envs: 8 envs and k = 1 take 8 per vector step) while
    training keeps the actor near them where the critic knows no better (SAC's own actor updates,
    unanchored, undo the cloning within 10k env steps on RibbonDrop-v2).
    ``bc_alpha`` = α > 0 weighs each cloning step after those at the start by mean|Q(s, π(s))| / α,
    as TD3+BC (Fujimoto & Gu 2021) weighs its cloning term against the critic's: the actor's
    optimiser (Adam) is shared with SAC's actor updates, whose gradients scale with Q, so an
    unweighted cloning step moves the actor far less than a critic-driven one.

    episodes: ≥ 1 (up to 10,000). pretrain_steps, bc_steps: ≥ 0 (up to 10⁷); bc_every ≥ 0 (0: never);
    bc_alpha ≥ 0 (up to 10⁶; 0: unweighted);
    the batch size is the algorithm's. The demonstrations run on a fresh env made from the training env's id and
    keyword arguments (``spec``), so on the task's plain start whatever wrappers the training envs
    have. The buffer should be larger than the demonstrations plus the run, or they are
    overwritten. ``stats`` (after training starts): :func:`add_expert_demos`'s dict plus
    ``pretrain_steps``, ``bc_steps`` (and ``bc_loss``, the last batch's) and ``with_pretrain_wall_s``."""

    off_policy_only = True

    def __init__(self, episodes: int, pretrain_steps: int = 0, bc_steps: int = 0, bc_every: int = 0,
                 bc_alpha: float = 0.0, verbose: int = 0):
        super().__init__(verbose)
        for name, v, lo, hi in (("episodes", episodes, 1, 10_000), ("pretrain_steps", pretrain_steps, 0, 10**7),
                                ("bc_steps", bc_steps, 0, 10**7), ("bc_every", bc_every, 0, 10**7)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
                raise ConfigError(f"ExpertDemos.{name}", f"must be an integer in [{lo}, {hi}], got {v!r}")
        self.episodes = int(episodes)
        self.pretrain_steps = int(pretrain_steps)
        self.bc_steps = int(bc_steps)
        self.bc_every = int(bc_every)
        if isinstance(bc_alpha, bool) or not isinstance(bc_alpha, (int, float, np.integer, np.floating)) \
                or not 0.0 <= float(bc_alpha) <= 1e6:
            raise ConfigError("ExpertDemos.bc_alpha", f"must be a number in [0, 1e6], got {bc_alpha!r}")
        self.bc_alpha = float(bc_alpha)
        self.demo_rows = 0  # the replay buffer's rows holding the demonstrations
        self.stats: dict | None = None

    def _on_training_start(self) -> None:
        _require_off_policy(self, "demonstrations go into the replay buffer")
        if self.stats is not None:  # a later learn() call: the buffer has them already
            return
        t0 = time.perf_counter()
        spec = self.training_env.get_attr("spec", [0])[0]
        seed = (self.model.seed or 0) + DEMO_SEED_OFFSET
        stats = add_expert_demos(self.model, spec.id, spec.kwargs, self.episodes, seed)
        self.demo_rows = self.model.replay_buffer.pos
        if self.pretrain_steps:
            self.model.train(gradient_steps=self.pretrain_steps, batch_size=self.model.batch_size)
        if self.bc_steps:
            stats["bc_loss"] = behaviour_clone(self.model, self.bc_steps, self.demo_rows)
        stats["pretrain_steps"] = self.pretrain_steps
        stats["bc_steps"] = self.bc_steps
        stats["bc_every"], stats["bc_alpha"] = self.bc_every, self.bc_alpha
        stats["with_pretrain_wall_s"] = time.perf_counter() - t0
        self.stats = stats

    def _on_step(self) -> bool:
        if self.bc_every:  # one cloning step per multiple of bc_every the last vector step passed
            n, k = self.num_timesteps, self.bc_every
            due = n // k - (n - self.training_env.num_envs) // k
            if due:
                behaviour_clone(self.model, due, self.demo_rows, self.bc_alpha)
        return True


def behaviour_clone(model, steps: int, rows: int, alpha: float = 0.0) -> float:
    """``steps`` steps of the actor's own optimiser on the mean squared difference between its
    deterministic action and the replay buffer's (both scaled to [−1, 1]), on batches of the
    algorithm's size drawn from the buffer's first ``rows`` rows (the demonstrations) with numpy's
    global generator (SB3 seeds it). SAC, TQC: any actor called as ``actor(obs, deterministic=True)``.
    With ``alpha`` > 0 the loss is weighted by the batch's mean|Q(s, π(s))| / ``alpha`` (the
    critic's output, every critic and quantile averaged; no gradient through the weight).
    Returns the last batch's unweighted loss."""
    import torch as th
    import torch.nn.functional as F

    actor = model.actor
    actor.set_training_mode(True)
    loss = th.zeros(())
    for _ in range(steps):
        rows_drawn = np.random.randint(0, rows, size=model.batch_size)
        batch = model.replay_buffer._get_samples(rows_drawn, env=model._vec_normalize_env)
        pi = actor(batch.observations, deterministic=True)
        loss = F.mse_loss(pi, batch.actions)
        weight = 1.0
        if alpha > 0.0:
            with th.no_grad():
                q = model.critic(batch.observations, pi)
                q = th.cat(q, dim=1) if isinstance(q, tuple) else q
                weight = float(q.abs().mean()) / alpha
        actor.optimizer.zero_grad()
        (weight * loss).backward()
        actor.optimizer.step()
    actor.set_training_mode(False)
    return float(loss.detach())


def add_expert_demos(model, env_id: str, env_kwargs: dict, n_episodes: int, seed: int) -> dict:
    """Run the scripted expert (:func:`cloth_gym.agents.experts.make_expert`) for ``n_episodes`` episodes of
    ``gym.make(env_id, **env_kwargs)`` (seeds ``seed, seed + 1, ...``) and add every transition to
    ``model.replay_buffer``.

    The transitions are stored as SB3's off-policy collection stores them: the observation before
    VecNormalize (the buffer normalises when it samples), the action scaled to [−1, 1], the env's
    reward, ``done = terminated or truncated``, and ``info["TimeLimit.truncated"]`` set on a
    truncation that is not a termination, so that the time limit does not cut the bootstrap
    (``handle_timeout_termination``). ``next_obs`` of the last step is the episode's real final
    observation. With ``n_envs`` > 1 the buffer takes ``n_envs`` transitions per row; a remainder
    of fewer than ``n_envs`` transitions is left out. Returns ``{"episodes", "transitions",
    "env_steps", "success_rate", "return_mean", "wall_s"}``."""
    import gymnasium as gym

    import cloth_gym  # noqa: F401  (registers the ids)

    from .experts import make_expert

    buf = model.replay_buffer
    n = buf.n_envs
    env = gym.make(env_id, **env_kwargs)
    low, high = env.action_space.low, env.action_space.high
    t0 = time.perf_counter()
    rows: list[tuple] = []
    returns, successes, steps = [], [], 0
    for k in range(n_episodes):
        obs, info = env.reset(seed=seed + k)
        expert = make_expert(env)
        total = 0.0
        while True:
            a = np.clip(np.asarray(expert.act(), dtype=np.float32), low, high)  # float32, as SB3 steps
            next_obs, r, term, trunc, info = env.step(a)
            steps += 1
            total += float(r)
            done = bool(term or trunc)
            rows.append((obs, next_obs, model.policy.scale_action(a), float(r), done,
                         {"TimeLimit.truncated": bool(trunc and not term)}))
            obs = next_obs
            if done:
                break
        returns.append(total)
        successes.append(bool(info.get("is_success", False)))
    env.close()
    added = 0
    for i in range(0, len(rows) - n + 1, n):
        chunk = rows[i:i + n]
        buf.add(np.stack([c[0] for c in chunk]), np.stack([c[1] for c in chunk]),
                np.stack([c[2] for c in chunk]), np.array([c[3] for c in chunk], dtype=np.float32),
                np.array([c[4] for c in chunk], dtype=np.float32), [c[5] for c in chunk])
        added += n
    return {"episodes": n_episodes, "transitions": added, "env_steps": steps,
            "success_rate": float(np.mean(successes)) if successes else 0.0,
            "return_mean": float(np.mean(returns)) if returns else 0.0, "wall_s": time.perf_counter() - t0}
