"""Learning while the envs step: an off-policy learner's gradient steps run during the next env step.

An off-policy algorithm of Stable-Baselines3 alternates: step the envs, store the transitions,
take gradient steps, step the envs again. On a cloth env both halves are heavy (CornerLift-v1:
about 20 ms of simulation and 10–13 ms of SAC update per env step on one core), and in that
loop one of them always waits for the other. :func:`overlapped` makes the two run at once:

* :class:`OverlappedVecEnv` steps the envs on a background thread: ``step_async`` starts the step
  and returns; ``step_wait`` first runs ``while_stepping`` on the calling thread, then waits for
  the step. The simulator's compiled kernels release Python's interpreter lock, so the physics and
  the learner's tensor arithmetic use separate cores.
* :class:`OverlappedTraining` (a mixin before the algorithm's class) defers the gradient steps that
  ``learn()`` asks for after a collection and takes them in the next ``step_wait``, while the envs
  step with the actions already chosen.

What changes for learning: each action is chosen by the policy as it was before the latest
collection's gradient steps (one update behind, with ``train_freq: 1``); the number of gradient
steps, their batches' source (the replay buffer as it stood after the previous collection) and
everything else are those of the plain algorithm. Gradient steps taken outside the collection loop
(``ExpertDemos``' pretraining, at the start of training) run at once, as before. The runs are
deterministic: the envs draw from their own generators, the learner from torch's and numpy's.
What it gains, measured: ``docs/baselines.md``, "Learning while the envs step".
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

__all__ = ["OverlappedVecEnv", "OverlappedTraining", "overlapped", "find_overlapped"]


class OverlappedVecEnv(VecEnvWrapper):
    """A ``VecEnv`` whose steps run on a background thread (one step at a time).

    ``while_stepping``: a callable with no arguments, or None; ``step_wait`` runs it on the
    calling thread while the step runs. ``reset``, ``close`` and everything else run on the
    calling thread, after any step in progress has finished."""

    def __init__(self, venv: VecEnv):
        super().__init__(venv)
        self.while_stepping = None
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="cloth_gym-envs")
        self._pending = None

    def step_async(self, actions) -> None:
        self._finish()
        self._pending = self._pool.submit(self.venv.step, actions)

    def step_wait(self):
        if self.while_stepping is not None:
            self.while_stepping()
        return self._finish()

    def _finish(self):
        """The result of the step in progress (None if there is none)."""
        pending, self._pending = self._pending, None
        return None if pending is None else pending.result()

    def reset(self):
        self._finish()
        return self.venv.reset()

    def close(self) -> None:
        self._finish()
        self._pool.shutdown(wait=True)
        self.venv.close()


def find_overlapped(env) -> OverlappedVecEnv | None:
    """The :class:`OverlappedVecEnv` in ``env``'s chain of ``VecEnvWrapper``\\ s (``VecNormalize``
    around it, say), or None."""
    while env is not None:
        if isinstance(env, OverlappedVecEnv):
            return env
        env = getattr(env, "venv", None)
    return None


class OverlappedTraining:
    """Mixin for an SB3 off-policy algorithm (``class OverlappedSAC(OverlappedTraining, SAC)``):
    the gradient steps that ``learn()`` asks for after each collection are taken during the next
    env step, where the algorithm's env contains an :class:`OverlappedVecEnv` (module docstring).
    ``learn()`` takes the steps still owed before it returns, so a finished model has had every
    gradient step of the plain algorithm."""

    _owed_steps: int = 0
    _owed_batch_size: int = 0
    _deferring: bool = False

    def collect_rollouts(self, *args, **kwargs):
        # from the first collection on, learn()'s own train() calls are deferred; gradient steps
        # asked for before it (a callback's pretraining in on_training_start) run at once
        self._deferring = find_overlapped(self.env) is not None
        return super().collect_rollouts(*args, **kwargs)

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        if not self._deferring:
            super().train(gradient_steps=gradient_steps, batch_size=batch_size)
            return
        self._owed_steps += gradient_steps
        self._owed_batch_size = batch_size

    def _take_owed_steps(self) -> None:
        steps, self._owed_steps = self._owed_steps, 0
        if steps:
            super().train(gradient_steps=steps, batch_size=self._owed_batch_size)

    def learn(self, *args, **kwargs):
        venv = find_overlapped(self.env)
        if venv is not None:
            venv.while_stepping = self._take_owed_steps
        try:
            out = super().learn(*args, **kwargs)
            self._deferring = False
            self._take_owed_steps()
        finally:
            self._deferring = False
            if venv is not None:
                venv.while_stepping = None
        return out

    def _excluded_save_params(self) -> list[str]:
        return super()._excluded_save_params() + ["_owed_steps", "_owed_batch_size", "_deferring"]


def overlapped(algo_cls: type) -> type:
    """``algo_cls`` with :class:`OverlappedTraining` mixed in (an off-policy SB3 class: SAC, TQC)."""
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

    if not issubclass(algo_cls, OffPolicyAlgorithm):
        from cloth_gym.errors import ConfigError

        raise ConfigError("overlap", f"needs an off-policy algorithm (sac, tqc), got {algo_cls.__name__}")
    return type(f"Overlapped{algo_cls.__name__}", (OverlappedTraining, algo_cls), {})
