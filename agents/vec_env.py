"""Stable-Baselines3's ``VecEnv`` over a Gymnasium vector env (SB3 cannot take one directly).

:class:`GymnasiumVecEnv` hands a batched cloth_gym env
(:class:`cloth_gym.envs.vector.BatchedVectorEnv`, its sub-envs stepped in parallel threads) to
SB3's algorithms, ``VecNormalize`` and callbacks. It translates the two conventions:

* autoreset: the vector env runs in ``AutoresetMode.SAME_STEP``, as SB3 expects: a step that ends
  an episode returns the next episode's first observation, and the last one goes to
  ``info["terminal_observation"]``;
* info: Gymnasium's one dict of arrays (with ``"_key"`` masks) becomes SB3's list of one dict per
  sub-env, with ``"TimeLimit.truncated"`` (truncated and not terminated) on every step, as
  ``DummyVecEnv`` has it; the reset's info goes to ``reset_infos``;
* seeds: ``seed(s)`` seeds sub-env i with ``s + i`` at the next ``reset()``, as SB3's own vec envs do.

:class:`BatchedVecEnv` takes SB3's ``env_fns`` like ``DummyVecEnv``, so that SB3's
``make_vec_env(id, n_envs, vec_env_cls=BatchedVecEnv)`` and rl-baselines3-zoo build it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

__all__ = ["GymnasiumVecEnv", "BatchedVecEnv"]


def _unbatch_info(infos: dict, i: int) -> dict:
    """Sub-env i's entries of a Gymnasium vector info (nested dicts unbatched too)."""
    out = {}
    for key, value in infos.items():
        if key.startswith("_") or key in ("final_obs", "final_info"):  # SAME_STEP's, handled by step_wait
            continue
        if isinstance(value, dict):
            out[key] = _unbatch_info(value, i)
        elif infos.get("_" + key, np.ones(i + 1, dtype=bool))[i]:
            item = value[i]
            out[key] = item.item() if isinstance(item, np.generic) else item
    return out


class GymnasiumVecEnv(VecEnv):
    """SB3 ``VecEnv`` interface of a Gymnasium ``VectorEnv`` (``AutoresetMode.SAME_STEP``)."""

    def __init__(self, venv):
        from gymnasium.vector import AutoresetMode

        mode = venv.metadata.get("autoreset_mode")
        if mode != AutoresetMode.SAME_STEP:
            from cloth_gym.errors import ConfigError

            raise ConfigError("venv", f"must reset in AutoresetMode.SAME_STEP (SB3's convention), got {mode!r}")
        self.venv = venv
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self.metadata = venv.metadata
        self.render_mode = venv.render_mode
        self._actions = None

    def reset(self):
        seeds = list(self._seeds)
        # the batched env gives every sub-env the same reset options: the first sub-env's here
        opts = self._options[0] or None
        obs, infos = self.venv.reset(seed=seeds if any(s is not None for s in seeds) else None, options=opts)
        self.reset_infos = [_unbatch_info(infos, i) for i in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        obs, rewards, terms, truncs, infos = self.venv.step(self._actions)
        dones = np.logical_or(terms, truncs)
        out = []
        for i in range(self.num_envs):
            if dones[i]:
                info = _unbatch_info(infos["final_info"], i)
                info["terminal_observation"] = infos["final_obs"][i]
                info["TimeLimit.truncated"] = bool(truncs[i] and not terms[i])
                self.reset_infos[i] = _unbatch_info(infos, i)
            else:
                info = _unbatch_info(infos, i)
                info["TimeLimit.truncated"] = False  # on every step, as DummyVecEnv has it
            out.append(info)
        return obs, rewards.astype(np.float32), dones, out

    def close(self) -> None:
        self.venv.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        return list(self.venv.render())

    def _targets(self, indices) -> list:
        return [self.venv.envs[i] for i in self._get_indices(indices)]

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [env.get_wrapper_attr(attr_name) for env in self._targets(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        for env in self._targets(indices):
            setattr(env, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        return [env.get_wrapper_attr(method_name)(*method_args, **method_kwargs) for env in self._targets(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        from stable_baselines3.common import env_util

        return [env_util.is_wrapped(env, wrapper_class) for env in self._targets(indices)]


class BatchedVecEnv(GymnasiumVecEnv):
    """SB3's ``VecEnv`` over a :class:`~cloth_gym.envs.vector.BatchedVectorEnv` of ``env_fns``:
    a drop-in for ``DummyVecEnv`` (same constructor), so SB3's ``make_vec_env(...,
    vec_env_cls=BatchedVecEnv)`` and rl-baselines3-zoo (``ExperimentManager.default_vec_env_cls
    = BatchedVecEnv``) build it with their ``Monitor`` and wrappers around each sub-env; the
    sub-envs' physics then runs in ``threads`` threads (default: numba's thread count)."""

    def __init__(self, env_fns, threads: int | None = None):
        from cloth_gym.envs.vector import BatchedVectorEnv

        super().__init__(BatchedVectorEnv(list(env_fns), threads=threads, autoreset_mode="SameStep"))
