"""Stable-Baselines3's ``VecEnv`` with its sub-envs in Ray actors, on this machine or a cluster.

:class:`RayVecEnv` takes SB3's ``env_fns`` like ``DummyVecEnv`` and puts them, ``envs_per_actor``
at a time, into Ray actors: each actor holds a :class:`~cloth_gym.agents.vec_env.BatchedVecEnv`
of its envs (their physics in ``threads_per_actor`` threads) and reserves that many CPUs, so Ray
places the actors on whichever nodes have them. A step sends each actor its slice of the actions
at once and gathers the answers; observations, rewards, dones and infos come back in sub-env
order, bit-identical to ``DummyVecEnv`` over the same ``env_fns`` (every sub-env is an ordinary
env, seeded as SB3 seeds them)::

    from stable_baselines3.common.env_util import make_vec_env
    venv = make_vec_env("cloth_gym/CornerLift-v2", n_envs=8, vec_env_cls=RayVecEnv,
                        vec_env_kwargs={"envs_per_actor": 4})            # a local Ray: 2 actors
    venv = make_vec_env(..., vec_env_kwargs={"address": "ray://head:10001"})   # a running cluster

``scripts/train.py --vec-env ray --n-envs N [--envs-per-actor k] [--ray-address ADDR]`` trains
on it; rl-baselines3-zoo does with ``ExperimentManager.default_vec_env_cls = RayVecEnv`` set
before ``rl_zoo3.train.train()`` (``docs/scaling.md``).

Failures never hang: an actor that dies (its process killed, its node lost) or raises is a
:class:`cloth_gym.RemoteEnvError` naming the actor and the sub-envs it held, as soon as Ray
reports it; an actor that does not answer within ``timeout_s`` is one too. The vec env is not
usable after such an error (its lost episodes cannot be resumed): close it and make a new one.
Without ``address``, a Ray started here is shut down by :meth:`RayVecEnv.close`.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from cloth_gym.errors import ConfigError, ConfigTypeError, RemoteEnvError

from .config import require_ray

__all__ = ["RayVecEnv"]


class _EnvActor:
    """The actor's side: a BatchedVecEnv of its env_fns, driven through SB3's VecEnv calls."""

    def __init__(self, env_fns, threads: int):
        from cloth_gym.agents.vec_env import BatchedVecEnv

        self.venv = BatchedVecEnv(env_fns, threads=threads)

    def spaces(self):
        v = self.venv
        return v.observation_space, v.action_space, dict(v.metadata), v.render_mode

    def pid(self) -> int:
        return os.getpid()

    def cpu_seconds(self) -> float:
        return time.process_time()

    def reset(self, seeds, options):
        self.venv._seeds, self.venv._options = list(seeds), list(options)
        obs = self.venv.reset()
        return obs, self.venv.reset_infos

    def step(self, actions):
        return self.venv.step(actions)

    def call(self, method: str, *args, **kwargs):
        return getattr(self.venv, method)(*args, **kwargs)


def _positive_int(field: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ConfigTypeError(field, f"must be an integer ≥ 1, got {value!r}")
    if value < 1:
        raise ConfigError(field, f"must be ≥ 1, got {value}")
    return int(value)


class RayVecEnv(VecEnv):
    """SB3 ``VecEnv`` over ``env_fns`` held ``envs_per_actor`` per Ray actor (see the module docstring).

    env_fns: callables making the sub-envs (as for ``DummyVecEnv``), pickled to the actors.
    envs_per_actor: sub-envs per actor (the last actor may hold fewer). address: a Ray cluster
    (``"ray://host:10001"``, ``"auto"``); None: the Ray already initialised in this process, or a
    local one started here. threads_per_actor: each actor's physics threads and reserved CPUs.
    timeout_s: the longest wait for an actor's answer before :class:`~cloth_gym.RemoteEnvError`."""

    def __init__(self, env_fns, envs_per_actor: int = 1, address: str | None = None, threads_per_actor: int = 1,
                 timeout_s: float = 300.0):
        ray = require_ray("vec_env")
        env_fns = list(env_fns)
        if not env_fns:
            raise ConfigError("env_fns", "must be a non-empty sequence of callables returning envs")
        k = _positive_int("envs_per_actor", envs_per_actor)
        threads = _positive_int("threads_per_actor", threads_per_actor)
        if not (isinstance(timeout_s, (int, float)) and not isinstance(timeout_s, bool) and timeout_s > 0):
            raise ConfigError("timeout_s", f"must be a number of seconds > 0, got {timeout_s!r}")
        self.timeout_s = float(timeout_s)
        #: the sub-env indices each actor holds
        self.groups = [list(range(s, min(s + k, len(env_fns)))) for s in range(0, len(env_fns), k)]
        need = len(self.groups) * threads
        self._started_ray = not ray.is_initialized()
        if self._started_ray:
            local = {} if address else {"num_cpus": max(os.cpu_count() or 1, need)}  # oversubscribed, never stuck
            ray.init(address=address, include_dashboard=False, log_to_driver=False, **local)
        have = ray.cluster_resources().get("CPU", 0.0)
        if have < need:
            self._shutdown()
            raise ConfigError("envs_per_actor", f"{len(self.groups)} actors × {threads} threads need {need} CPUs; "
                              f"the Ray cluster has {have:g}: give more envs per actor or fewer envs")
        actor_cls = ray.remote(_EnvActor)
        self._actors = [actor_cls.options(num_cpus=threads).remote([env_fns[i] for i in g], threads)
                        for g in self.groups]
        obs_space, act_space, metadata, render_mode = self._gather([a.spaces.remote() for a in self._actors])[0]
        super().__init__(len(env_fns), obs_space, act_space)
        self.metadata = metadata
        self.render_mode = render_mode
        self._refs = None

    # ------------------------------------------------------------------ the Ray calls
    def _gather(self, refs, actors: Sequence[int] | None = None) -> list:
        """``ray.get`` of one reference per actor (``actors``: which, default all in order),
        each failure a RemoteEnvError naming the actor."""
        import ray
        from ray.exceptions import GetTimeoutError, RayActorError, RayTaskError

        actors = list(range(len(refs))) if actors is None else list(actors)
        out = []
        for j, ref in zip(actors, refs):
            try:
                out.append(ray.get(ref, timeout=self.timeout_s))
            except RayActorError as err:
                raise RemoteEnvError(j, self.groups[j], f"Ray actor {j} (sub-envs {self.groups[j]}) died: "
                                     f"{str(err).splitlines()[0]}; its episodes are lost: close this vec env "
                                     f"and make a new one") from None
            except GetTimeoutError:
                raise RemoteEnvError(j, self.groups[j], f"Ray actor {j} (sub-envs {self.groups[j]}) did not answer "
                                     f"within timeout_s = {self.timeout_s:g} s") from None
            except RayTaskError as err:
                cause = err.cause if getattr(err, "cause", None) is not None else err
                raise RemoteEnvError(j, self.groups[j], f"Ray actor {j} (sub-envs {self.groups[j]}) raised "
                                     f"{type(cause).__name__}: {cause}") from cause
        return out

    def _route(self, indices) -> list[tuple[int, list[int], list[int]]]:
        """``(actor, its local indices, positions in indices)`` for each actor holding some of ``indices``."""
        where = {}
        for pos, i in enumerate(self._get_indices(indices)):
            j, local = divmod(i, len(self.groups[0]))
            actor = where.setdefault(j, (j, [], []))
            actor[1].append(local)
            actor[2].append(pos)
        return list(where.values())

    def _call(self, method: str, *args, indices=None, **kwargs) -> list:
        routes = self._route(indices)
        results = self._gather([self._actors[j].call.remote(method, *args, indices=local, **kwargs)
                                for j, local, _ in routes], [j for j, _, _ in routes])
        out: list = [None] * sum(len(p) for _, _, p in routes)
        for (_, _, positions), values in zip(routes, results):
            for p, v in zip(positions, values):
                out[p] = v
        return out

    # ------------------------------------------------------------------ SB3's VecEnv
    def reset(self):
        seeds, options = list(self._seeds), list(self._options)
        results = self._gather([a.reset.remote([seeds[i] for i in g], [options[i] for i in g])
                                for a, g in zip(self._actors, self.groups)])
        self.reset_infos = [info for _, infos in results for info in infos]
        self._reset_seeds()
        self._reset_options()
        return _concat([obs for obs, _ in results])

    def step_async(self, actions: np.ndarray) -> None:
        actions = np.asarray(actions)
        self._refs = [a.step.remote(actions[g[0]:g[-1] + 1]) for a, g in zip(self._actors, self.groups)]

    def step_wait(self):
        refs, self._refs = self._refs, None
        results = self._gather(refs)
        obs = _concat([r[0] for r in results])
        rewards = np.concatenate([r[1] for r in results])
        dones = np.concatenate([r[2] for r in results])
        infos = [info for r in results for info in r[3]]
        return obs, rewards, dones, infos

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [img for imgs in self._gather([a.call.remote("get_images") for a in self._actors]) for img in imgs]

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return self._call("get_attr", attr_name, indices=indices)

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        self._call("set_attr", attr_name, value, indices=indices)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        return self._call("env_method", method_name, *method_args, indices=indices, **method_kwargs)

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return self._call("env_is_wrapped", wrapper_class, indices=indices)

    def actor_pids(self) -> list[int]:
        """The process id of each actor (on its node)."""
        return self._gather([a.pid.remote() for a in self._actors])

    def actor_cpu_seconds(self) -> list[float]:
        """The CPU seconds each actor's process has used so far (user and system, all its threads)."""
        return self._gather([a.cpu_seconds.remote() for a in self._actors])

    def close(self) -> None:
        import ray

        for a in getattr(self, "_actors", []):
            try:
                ray.get(a.call.remote("close"), timeout=10)
            except Exception:  # noqa: BLE001  (a dead actor has nothing left to close)
                pass
            ray.kill(a)
        self._actors = []
        self._shutdown()

    def _shutdown(self) -> None:
        import ray

        if self._started_ray and ray.is_initialized():
            ray.shutdown()
        self._started_ray = False


def _concat(parts):
    if isinstance(parts[0], dict):
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return np.concatenate(parts)
