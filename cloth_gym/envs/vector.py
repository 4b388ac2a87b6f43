"""Batched vector env: N cloth envs stepped together, in parallel over cloths.

``gymnasium.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` returns a
:class:`BatchedVectorEnv` for every cloth_gym id. It holds N ordinary single envs (each made by
``gymnasium.make``, with its time limit) and steps them all in one call: the cloths' steps run on
several threads (the calling thread and a pool's), and the simulator's compiled kernels release
Python's global interpreter lock, so the cloths' physics runs on all cores while the envs' Python
(actions, rewards, observations) takes turns. Each cloth is stepped by exactly the code of a
single env, so a vector run is bit-identical to N single envs given the same seeds and actions,
for any number of threads.

It follows Gymnasium 1.x's vector API: batched spaces, per-sub-env seeds (``reset(seed=s)``
gives sub-env i the seed ``s + i``; a list gives each its own), vector ``info`` (each key an
array with a ``"_key"`` mask of the sub-envs that set it) and autoreset, by default
``AutoresetMode.NEXT_STEP`` (the step after a sub-env's episode ended resets it, ignoring its
action, and returns its first observation with reward 0). ``AutoresetMode.SAME_STEP`` (the reset
observation in the same step; the last one in ``info["final_obs"]``, the last info in
``info["final_info"]``) is what :class:`cloth_gym.agents.vec_env.GymnasiumVecEnv` uses to hand
the batch to Stable-Baselines3.

Importing this module imports neither numba nor the simulator (the registry names its factory).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from copy import deepcopy
from functools import partial
from queue import Empty, SimpleQueue
from typing import Any

import numpy as np
from gymnasium import Env
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space, concatenate, create_empty_array

from ..errors import ConfigError, ConfigTypeError
from ..validation import seed as check_seed

__all__ = ["BatchedVectorEnv", "batched_entry_point"]


def _default_threads() -> int:
    """numba's thread count (its own setting: ``NUMBA_NUM_THREADS``, or ``numba.set_num_threads``)."""
    import numba

    return int(numba.get_num_threads())


class BatchedVectorEnv(VectorEnv):
    """N cloth envs stepped in one call, their physics in parallel threads.

    env_fns: one callable per sub-env, each returning a new env (``lambda: gymnasium.make(id)``).
    threads: threads that step the sub-envs, the calling thread among them (default: numba's thread
    count, at most ``num_envs``; 1 steps the envs one after another in the calling thread).
    autoreset_mode: a ``gymnasium.vector.AutoresetMode`` (or its value): ``NEXT_STEP`` (default),
    ``SAME_STEP`` or ``DISABLED``.

    ``envs`` is the list of sub-envs (each a full Gymnasium env: ``envs[i].unwrapped`` has
    ``get_state``/``set_state``). ``render()`` returns a tuple of the sub-envs' frames;
    ``call(name, ...)``, ``get_attr(name)`` and ``set_attr(name, values)`` reach into them as
    ``SyncVectorEnv``'s do.
    """

    def __init__(self, env_fns: Sequence[Callable[[], Env]], threads: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP):
        if not isinstance(env_fns, Sequence) or len(env_fns) == 0:
            raise ConfigError("env_fns", "must be a non-empty sequence of callables returning envs")
        try:
            mode = AutoresetMode(autoreset_mode)
        except ValueError:
            raise ConfigError("autoreset_mode", f"must be one of {[m.value for m in AutoresetMode]}, "
                              f"got {autoreset_mode!r}") from None
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, (int, np.integer))):
            raise ConfigTypeError("threads", f"must be an integer ≥ 1 or None, got {threads!r}")
        if threads is not None and threads < 1:
            raise ConfigError("threads", f"must be ≥ 1 (or None: numba's thread count), got {threads}")
        self.envs = [fn() for fn in env_fns]
        if len({id(e.unwrapped) for e in self.envs}) != len(self.envs):
            raise ConfigError("env_fns", "returned the same env object twice: each call must make a new env")
        self.num_envs = len(self.envs)
        first = self.envs[0]
        for i, e in enumerate(self.envs[1:], 1):
            if e.observation_space != first.observation_space or e.action_space != first.action_space:
                raise ConfigError("env_fns", f"sub-env {i} has other spaces than sub-env 0: "
                                  f"{e.observation_space}, {e.action_space}")
        self.single_observation_space = first.observation_space
        self.single_action_space = first.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.metadata = {**first.metadata, "autoreset_mode": mode}
        self.render_mode = first.render_mode
        self.spec = first.spec
        self.threads = min(self.num_envs, _default_threads() if threads is None else int(threads))
        # sub-envs of one class that can tell in one call that every row of the actions passes (None else)
        kinds = {type(e.unwrapped) for e in self.envs}
        self._actions_pass = getattr(first.unwrapped, "_actions_pass", None) if len(kinds) == 1 else None
        self._pool = self._make_pool()
        self._obs = create_empty_array(self.single_observation_space, self.num_envs, fn=np.zeros)
        self._rewards = np.zeros(self.num_envs, dtype=np.float64)
        self._terminations = np.zeros(self.num_envs, dtype=np.bool_)
        self._truncations = np.zeros(self.num_envs, dtype=np.bool_)
        self._autoreset = np.zeros(self.num_envs, dtype=np.bool_)
        # wall seconds of each sub-env's last step: the next step hands the slowest out first
        self._step_seconds = np.zeros(self.num_envs, dtype=np.float64)
        self._step_cpu_seconds = np.zeros(self.num_envs, dtype=np.float64)  # the same steps' thread CPU time
        self._step_thread = np.zeros(self.num_envs, dtype=np.int64)  # which thread ran each (0: the caller)

    # ------------------------------------------------------------------ running the sub-envs
    def _map(self, fn: Callable[[int], Any], order: Sequence[int] | None = None) -> list:
        """``[fn(0), ..., fn(N-1)]``. With several threads the calling thread and the pool's
        ``threads - 1`` workers take the calls from one queue, in ``order`` (default 0, 1, ...); the
        result is indexed by sub-env all the same. Every call runs; the exception of the lowest
        sub-env that raised one is re-raised here."""
        if self._pool is None:
            self._step_thread[:] = 0
            return [fn(i) for i in range(self.num_envs)]
        todo: SimpleQueue = SimpleQueue()
        for i in (range(self.num_envs) if order is None else order):
            todo.put(int(i))
        results: list = [None] * self.num_envs
        errors: dict = {}

        def drain(thread: int) -> None:
            while True:
                try:
                    i = todo.get_nowait()
                except Empty:
                    return
                self._step_thread[i] = thread
                try:
                    results[i] = fn(i)
                except Exception as err:  # re-raised below, once every call has run
                    errors[i] = err

        helpers = [self._pool.submit(drain, k) for k in range(1, self.threads)]
        drain(0)  # the calling thread works too: no thread has to wake for the first calls
        for h in helpers:
            h.result()
        if errors:
            raise errors[min(errors)]
        return results

    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None):
        """Reset every sub-env. ``seed``: None, an int (sub-env i gets ``seed + i``) or one seed
        per sub-env. ``options`` go to every sub-env's ``reset``."""
        seeds = self._seeds(seed)
        results = self._map(lambda i: self.envs[i].reset(seed=seeds[i], options=options))
        infos: dict = {}
        for i, (_, info) in enumerate(results):
            infos = self._add_info(infos, info, i)
        self._obs = concatenate(self.single_observation_space, [o for o, _ in results], self._obs)
        self._autoreset[:] = False
        self._terminations[:] = False
        self._truncations[:] = False
        return self._copy_obs(), infos

    def _seeds(self, seed) -> list:
        """One seed per sub-env from ``reset``'s ``seed`` (ConfigError/ConfigTypeError naming it)."""
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
            return [check_seed("seed", seed) + i for i in range(self.num_envs)]
        if not isinstance(seed, (Sequence, np.ndarray)) or isinstance(seed, (str, bytes)):
            raise ConfigTypeError("seed", f"must be None, an int or {self.num_envs} seeds (one per sub-env), got "
                                  f"{seed!r} ({type(seed).__name__})")
        seeds = list(seed)
        if len(seeds) != self.num_envs:
            raise ConfigError("seed", f"must be None, an int or {self.num_envs} seeds (one per sub-env), "
                              f"got {len(seeds)}")
        return [check_seed(f"seed[{i}]", s) for i, s in enumerate(seeds)]

    def _check_actions(self, actions) -> list:
        """``actions`` as N rows (an array's rows, or a list's items), each checked as its sub-env
        checks an action, before any sub-env steps: a ConfigError/ConfigTypeError naming
        ``actions[i]`` for the first bad row, or ``actions`` for a batch of another length."""
        if np.ma.isMaskedArray(actions) and np.ma.getmaskarray(actions).any():
            raise ConfigError("actions", "has masked entries: give every sub-env's action in full")
        if self._actions_pass is not None and self._actions_pass(actions) and len(actions) == self.num_envs:
            return list(actions)  # every row would pass its sub-env's check: told in one call
        if isinstance(actions, (list, tuple)):  # rows checked one by one (a ragged list too)
            rows = list(actions)
        elif isinstance(actions, np.ndarray) and actions.ndim >= 1:
            rows = list(np.asarray(actions))
        else:
            raise ConfigTypeError("actions", f"must be an array of shape ({self.num_envs}, "
                                  f"{self.single_action_space.shape[0]}), got {actions!r}")
        if len(rows) != self.num_envs:
            raise ConfigError("actions", f"must hold one action per sub-env: shape ({self.num_envs}, ...), "
                              f"got {len(rows)} rows")
        for i, env in enumerate(self.envs):
            check = getattr(env.unwrapped, "_validate_action", None)
            if check is None:
                continue
            try:
                check(rows[i])
            except ConfigError as err:
                raise type(err)(f"actions[{i}]", err.message) from None
        return rows

    def __getstate__(self) -> dict:
        """Pickle and ``copy.deepcopy``: the sub-envs (each pickles mid-episode) and the batch's
        buffers; the thread pool is made anew on unpickling."""
        d = dict(self.__dict__)
        d["_pool"] = None
        return d

    def __setstate__(self, d: dict) -> None:
        self.__dict__.update(d)
        self._pool = self._make_pool()

    def _make_pool(self) -> ThreadPoolExecutor | None:
        """The ``threads - 1`` pool threads that step sub-envs beside the calling thread (None for one)."""
        return ThreadPoolExecutor(self.threads - 1, thread_name_prefix="cloth_gym") if self.threads > 1 else None

    def _step_one(self, i: int, action, mode: AutoresetMode):
        """Sub-env i's share of a vector step: (obs, reward, terminated, truncated, info, final)
        where final is (last obs, last info) of an episode that SAME_STEP reset here, else None."""
        start, start_cpu = time.perf_counter(), time.thread_time()
        try:
            return self._step_one_untimed(i, action, mode)
        finally:
            self._step_seconds[i] = time.perf_counter() - start
            self._step_cpu_seconds[i] = time.thread_time() - start_cpu

    def _step_one_untimed(self, i: int, action, mode: AutoresetMode):
        env = self.envs[i]
        if mode == AutoresetMode.NEXT_STEP and self._autoreset[i]:
            obs, info = env.reset()
            return obs, 0.0, False, False, info, None
        obs, reward, terminated, truncated, info = env.step(action)
        if mode == AutoresetMode.SAME_STEP and (terminated or truncated):
            final = (obs, info)
            obs, info = env.reset()
            return obs, reward, terminated, truncated, info, final
        return obs, reward, terminated, truncated, info, None

    def step(self, actions):
        """Step every sub-env with its row of ``actions``; returns batched (obs, rewards,
        terminations, truncations, infos)."""
        mode = self.metadata["autoreset_mode"]
        actions = self._check_actions(actions)  # all N before any sub-env steps
        # Longest first: the sub-envs whose last step took longest start first, so that the threads
        # finish together (a step's cost changes slowly along an episode). The order changes no result.
        order = np.argsort(-self._step_seconds, kind="stable")
        results = self._map(lambda i: self._step_one(i, actions[i], mode), order)
        batched = scalar_infos([r[4] for r in results])
        by_env = batched is None  # not all plain scalars under the same keys: Gymnasium's way, env by env
        infos: dict = {} if by_env else batched
        finals: dict = {}
        final_obs = np.full(self.num_envs, None, dtype=object)
        has_final = np.zeros(self.num_envs, dtype=np.bool_)
        for i, (obs, reward, term, trunc, info, final) in enumerate(results):
            self._rewards[i] = reward
            self._terminations[i] = term
            self._truncations[i] = trunc
            if by_env:
                infos = self._add_info(infos, info, i)
            if final is not None:
                final_obs[i] = final[0]
                has_final[i] = True
                finals = self._add_info(finals, final[1], i)
        if mode == AutoresetMode.SAME_STEP and has_final.any():
            infos["final_obs"], infos["_final_obs"] = final_obs, has_final
            infos["final_info"], infos["_final_info"] = finals, has_final
        self._obs = concatenate(self.single_observation_space, [r[0] for r in results], self._obs)
        self._autoreset = np.logical_or(self._terminations, self._truncations)
        return (self._copy_obs(), self._rewards.copy(), self._terminations.copy(), self._truncations.copy(),
                infos)

    @property
    def last_step_seconds(self) -> np.ndarray:
        """(N,) wall seconds each sub-env's last step took in its thread (a copy): their sum over
        ``threads`` times the vector step's wall time is the share of the threads kept busy."""
        return self._step_seconds.copy()

    @property
    def last_step_cpu_seconds(self) -> np.ndarray:
        """(N,) CPU seconds of its thread each sub-env's last step took (a copy): below
        :attr:`last_step_seconds` by the time the thread was not running (waiting for the
        interpreter lock, or for a core)."""
        return self._step_cpu_seconds.copy()

    @property
    def last_step_threads(self) -> np.ndarray:
        """(N,) which thread ran each sub-env's last step or reset (0: the calling thread, 1 to
        ``threads - 1``: the pool's), a copy: with each sub-env's cost, the load of each thread."""
        return self._step_thread.copy()

    def _copy_obs(self):
        return deepcopy(self._obs)  # an array, or a dict of arrays (a goal env)

    # ------------------------------------------------------------------ reaching into the sub-envs
    def render(self) -> tuple | None:
        """Each sub-env's ``render()`` (a tuple of frames)."""
        return tuple(env.render() for env in self.envs)

    def call(self, name: str, *args, **kwargs) -> tuple:
        """``envs[i].get_wrapper_attr(name)`` of every sub-env, called with the arguments when callable."""
        out = []
        for env in self.envs:
            attr = env.get_wrapper_attr(name)
            out.append(attr(*args, **kwargs) if callable(attr) else attr)
        return tuple(out)

    def get_attr(self, name: str) -> tuple:
        """The attribute ``name`` of every sub-env."""
        return tuple(env.get_wrapper_attr(name) for env in self.envs)

    def set_attr(self, name: str, values: Any | Sequence[Any]) -> None:
        """Set ``name`` on every sub-env: one value for all, or a list or tuple of one per sub-env."""
        if not isinstance(values, (list, tuple)):
            values = [values] * self.num_envs
        if len(values) != self.num_envs:
            raise ConfigError("values", f"must hold one value per sub-env ({self.num_envs}), got {len(values)}")
        for env, value in zip(self.envs, values):
            env.set_wrapper_attr(name, value)

    def close_extras(self, **kwargs) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        for env in self.envs:
            env.close()


def scalar_infos(infos: Sequence[dict]) -> dict | None:
    """The sub-envs' ``infos`` batched as ``VectorEnv._add_info`` batches them, one array per key
    (of the type of the values: ``int``, ``float``, ``bool`` or a NumPy integer, float or complex) followed by
    its mask ``_key``, all True, built in one call per key. None (batch them env by env) unless every
    info has the same keys, each with values of one such type in every info, none of them
    ``final_obs`` or another key's mask name."""
    keys = infos[0].keys()
    if any(info.keys() != keys for info in infos):
        return None
    out: dict = {}
    for key, value in infos[0].items():
        t = type(value)
        number = t in (int, float, bool) or (issubclass(t, np.number) and np.dtype(t).kind in "iufc")
        column = [info[key] for info in infos]
        if not number or key == "final_obs" or f"_{key}" in keys or any(type(v) is not t for v in column):
            return None
        out[key], out[f"_{key}"] = np.array(column, dtype=t), np.ones(len(infos), dtype=np.bool_)
    return out


def _make_batched(env_id: str, num_envs: int = 1, *, threads: int | None = None,
                  autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, **kwargs) -> BatchedVectorEnv:
    import gymnasium

    from ..validation import integer

    num_envs = integer("num_envs", num_envs, 1, 4096)
    # the env checker runs once per id (on sub-env 0), as gymnasium.make would for a single env
    fns = [partial(gymnasium.make, env_id, disable_env_checker=i > 0, **kwargs) for i in range(num_envs)]
    return BatchedVectorEnv(fns, threads=threads, autoreset_mode=autoreset_mode)


def batched_entry_point(env_id: str) -> Callable[..., BatchedVectorEnv]:
    """The ``vector_entry_point`` registered for ``env_id``: called by ``gymnasium.make_vec`` as
    ``f(num_envs=N, max_episode_steps=..., threads=None, autoreset_mode=..., **env_kwargs)``."""
    return partial(_make_batched, env_id)
