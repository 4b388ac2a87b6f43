"""Gymnasium wrappers for training on cloth_gym's envs.

:class:`StartCurriculum` starts a share of the episodes from an easier starting
state, given by the task's ``reset(options=...)`` (a task's ``reset_options``:
for CornerLift, ``{"gripper_start": "corner"}`` puts the open gripper within
grasp radius of the corner to lift, ``{"gripper_start": "held"}`` starts with the
corner grasped and carried part of the way to the target). It is meant for *training* envs only: the
task it is evaluated on is the unwrapped one. ``scripts/train.py`` wraps its
training envs with the configs' ``env_wrapper`` (rl-baselines3-zoo's key) and
leaves the evaluation env bare; rl_zoo3 wraps its evaluation env too, so the
zoo's evaluation returns of such a config mix in the easier starts.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from .errors import ConfigError, ConfigTypeError
from .validation import real
from .validation import seed as check_seed

__all__ = ["StartCurriculum"]


class StartCurriculum(gym.Wrapper):
    """Reset with ``options`` in a share ``probability`` of the episodes.

    Parameters
    ----------
    env
        a cloth_gym env whose ``reset_options`` accept ``options``.
    probability
        share of the resets that use ``options``, in [0, 1].
    options
        the reset options of those episodes, e.g. ``{"gripper_start": "corner"}``, or a
        list of such dicts, one drawn uniformly for each curriculum episode.

    The choice is drawn from the wrapper's own generator, seeded from the reset
    seed, so a seeded run repeats and the env's own random stream is not
    touched. A reset called with explicit ``options`` passes them through
    unchanged. ``info["curriculum_start"]`` says whether the episode got
    ``options``.
    """

    def __init__(self, env: gym.Env, probability: float, options: dict | list):
        if not isinstance(env, gym.Env):
            raise ConfigTypeError("StartCurriculum.env", f"needs a cloth_gym env, got {type(env).__name__}")
        super().__init__(env)
        probability = real("StartCurriculum.probability", probability, 0.0, 1.0)
        choices = [options] if isinstance(options, dict) else options
        if not isinstance(choices, (list, tuple)) or not choices \
                or not all(isinstance(o, dict) and o for o in choices):
            raise ConfigTypeError("StartCurriculum.options", f"must be a non-empty dict of reset options or a "
                                  f"non-empty list of them, got {options!r}")
        check = getattr(getattr(env, "unwrapped", None), "check_reset_options", None)
        if check is None:
            raise ConfigTypeError("StartCurriculum.env", f"needs a cloth_gym env (reset options), got "
                                  f"{type(getattr(env, 'unwrapped', env)).__name__}")
        for i, o in enumerate(choices):  # checked now by the env's own rules, not at the first curriculum reset
            try:
                check(o)
            except ConfigError as err:
                field = err.field if isinstance(options, dict) else err.field.replace("options", f"options[{i}]", 1)
                raise ConfigError(f"StartCurriculum.{field}", err.message) from None
        self.probability = float(probability)
        self.choices = [dict(o) for o in choices]
        self._rng = np.random.default_rng()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if check_seed("seed", seed) is not None:
            self._rng = np.random.default_rng([int(seed), 0x5EED])
        curriculum = options is None and self._rng.random() < self.probability
        if curriculum:
            # a single choice draws nothing more: a one-dict curriculum repeats its earlier runs
            options = dict(self.choices[self._rng.integers(len(self.choices)) if len(self.choices) > 1 else 0])
        obs, info = self.env.reset(seed=seed, options=options)
        info["curriculum_start"] = bool(curriculum)
        return obs, info
