"""Temporally extended exploration of the grip: SB3 action noise that holds a gripper's grip
action at +1 or −1 for a stretch of steps.

SAC explores by sampling each step's action independently. On cloth_gym's grip actions
(``> 0`` closes, ``≤ 0`` opens, one value per step) that almost never *holds* a grasp for
more than a step or two once the policy's grip mean leans to one side: a policy that hovers
with the gripper open (grip about −0.9, σ about 0.5 before the tanh) closes on roughly one
step in a thousand, and the critic never sees what keeping the corner would be worth
(``docs/baselines.md``, CornerLift). :class:`GripHoldNoise` is ez-greedy exploration
(Dabney, Ostrovski & Barreto, "Temporally-Extended ε-Greedy Exploration", ICLR 2021) on the
grip components only: on each step that is not already in a stretch, with probability
``probability`` a stretch starts, of a sign drawn with equal odds and a length drawn from a
geometric distribution of mean ``mean_steps``; during it the noise is ±2 on every grip
component, which SB3 clips to a grip of ±1, and 0 on the displacements. Outside stretches
the noise is zero: the policy's own stochastic actions are used unchanged.

SB3's off-policy algorithms add the noise to the action they execute and store that action in
the replay buffer, so the critic learns from what was done; evaluation
(``deterministic=True``, :class:`~stable_baselines3.common.callbacks.EvalCallback`,
``scripts/evaluate.py``) never adds it. A stretch ends at an episode's end
(SB3 calls :meth:`reset`). A training config turns it on with the callback
:class:`cloth_gym.agents.callbacks.GripExploration` (rl-baselines3-zoo's ``callback`` key).
"""

from __future__ import annotations

import math

import numpy as np
from stable_baselines3.common.noise import ActionNoise

from cloth_gym.errors import ConfigError

__all__ = ["GripHoldNoise"]


class GripHoldNoise(ActionNoise):
    """Hold the grip action at ±1 for geometric stretches (ez-greedy on the grip).

    Parameters
    ----------
    n_actions
        size of the action (4 per gripper: dx, dy, dz, grip).
    probability
        chance per step, outside a stretch, that one starts, in (0, 1].
    mean_steps
        mean stretch length in env steps, ≥ 1 (geometric: P(len = k) = (1 − q)^(k−1) q,
        q = 1 / mean_steps).
    seed
        seed of the noise's own generator (:class:`~cloth_gym.agents.callbacks.GripExploration` gives it the
        algorithm's seed).
    n_envs
        vectorised envs, each with its own stretch.
    """

    def __init__(self, n_actions: int, probability: float, mean_steps: float, seed: int | None = None,
                 n_envs: int = 1):
        super().__init__()
        if isinstance(n_actions, bool) or not isinstance(n_actions, (int, np.integer)) or n_actions < 4 \
                or n_actions % 4:
            raise ConfigError("GripHoldNoise.n_actions", f"must be a multiple of 4 (dx, dy, dz, grip per "
                              f"gripper), got {n_actions!r}")
        for name, v, lo, hi, lo_open in (("probability", probability, 0.0, 1.0, True),
                                         ("mean_steps", mean_steps, 1.0, 1e6, False)):
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v <= hi \
                and (v > lo if lo_open else v >= lo)
            if not ok:
                bracket = "(" if lo_open else "["
                raise ConfigError(f"GripHoldNoise.{name}", f"must be a number in {bracket}{lo}, {hi}], got {v!r}")
        self.n_actions = int(n_actions)
        self.probability = float(probability)
        self.mean_steps = float(mean_steps)
        self.n_envs = int(n_envs)
        self._rng = np.random.default_rng(seed)
        self._left = np.zeros(self.n_envs, dtype=np.int64)   # steps left in the current stretch
        self._sign = np.zeros(self.n_envs)

    def __call__(self) -> np.ndarray:
        out = np.zeros((self.n_envs, self.n_actions))
        for i in range(self.n_envs):
            if self._left[i] == 0 and self._rng.random() < self.probability:
                self._left[i] = self._rng.geometric(1.0 / self.mean_steps)
                self._sign[i] = 1.0 if self._rng.random() < 0.5 else -1.0
            if self._left[i] > 0:
                out[i, 3::4] = 2.0 * self._sign[i]
                self._left[i] -= 1
        return out[0] if self.n_envs == 1 else out

    def reset(self, indices=None) -> None:
        """End the stretch of the given envs (all by default): an episode ended."""
        self._left[slice(None) if indices is None else np.asarray(indices)] = 0

    def __repr__(self) -> str:
        return f"GripHoldNoise(probability={self.probability}, mean_steps={self.mean_steps})"
