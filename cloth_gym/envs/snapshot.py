"""The snapshot of a cloth env's episode (:class:`EnvSnapshot`) and its check on restore.

:meth:`ClothEnv.set_state <cloth_gym.envs.base.ClothEnv.set_state>` checks a whole snapshot
(:func:`check_snapshot`) before it changes anything: its format version, that it was taken from
an env of the same id, material, force model, integrator and observation mode, and each field's
type, shape, dtype, range and finiteness. The first mismatch is a
:class:`~cloth_gym.errors.SnapshotError` (or :class:`~cloth_gym.errors.SnapshotTypeError`) naming
the field (``snapshot.state.particle_q``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces

from ..errors import SnapshotError, SnapshotTypeError
from ..sim.model import Model, SolverMemory, State

__all__ = ["EnvSnapshot", "SNAPSHOT_FORMAT", "check_snapshot", "env_id"]

#: the version of :class:`EnvSnapshot`'s layout; a snapshot of another version (or of none: taken by
#: a release before snapshots had one) is refused
SNAPSHOT_FORMAT = 1


@dataclass(frozen=True)
class EnvSnapshot:
    """Everything a cloth env's episode depends on, copied (:meth:`ClothEnv.get_state`).

    Restoring it (:meth:`ClothEnv.set_state`) and replaying the same actions is bit-identical to
    what followed when it was taken. It pickles, so it can be stored or sent to another process.
    It restores only into an env that matches it (:func:`check_snapshot`).

    Attributes
    ----------
    format
        The snapshot layout's version (:data:`SNAPSHOT_FORMAT` when taken).
    env, env_id
        The env's class name, and its Gymnasium id (``cloth_gym/CornerLift-v2``; the class name for
        an env made without ``gymnasium.make``).
    material, force_model, integrator, observation_mode
        The env's material name, force model (``"kes"``, ``"breen"``), integrator and observation
        mode when the snapshot was taken.
    model
        The episode's :class:`~cloth_gym.sim.model.Model` (immutable, shared; a randomised
        material makes one per episode).
    state
        The cloth: positions, velocities, time, step, obstacle offsets and the integrator's memory
        (:class:`~cloth_gym.sim.model.State`, a copy).
    grippers
        Each gripper's position, velocity, closed flag, the particles it holds, the slips so far.
    task
        The task's episode fields (:attr:`ClothEnv.episode_fields`, e.g. CornerLift's ``target``).
    rng, rng_seed
        The env's ``np_random`` generator, copied, and the seed it reports (``np_random_seed``).
    elapsed_steps
        Env steps since the last reset. A ``TimeLimit`` wrapper counts its own; restore it with
        ``env.set_wrapper_attr("_elapsed_steps", snapshot.elapsed_steps)``.
    diverged
        Whether the episode had diverged (then every step is a truncation).
    last_obs
        The last observation returned.
    """

    format: int
    env: str
    env_id: str
    material: str
    force_model: str
    integrator: str
    observation_mode: str
    model: Model
    state: State
    grippers: dict
    task: dict
    rng: np.random.Generator
    rng_seed: int | None
    elapsed_steps: int
    diverged: bool
    last_obs: np.ndarray | dict


def env_id(env) -> str:
    """The env's Gymnasium id (``env.spec.id``), or its class name when it has no spec."""
    spec = getattr(env, "spec", None)
    return spec.id if spec is not None else type(env).__name__


# ---------------------------------------------------------------------- field checks
def _array(field: str, a, shape: tuple, dtype, *, finite: bool = True, lo=None, hi=None) -> None:
    want = f"a numpy {np.dtype(dtype)} array of shape {shape}"
    if type(a) is not np.ndarray:  # not a list, not a masked array or another subclass
        raise SnapshotTypeError(field, f"must be {want}, got {type(a).__name__}")
    if a.shape != tuple(shape):
        raise SnapshotError(field, f"must be {want}, got shape {a.shape}")
    if a.dtype != np.dtype(dtype):
        raise SnapshotError(field, f"must be {want}, got dtype {a.dtype}")
    if finite and a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        bad = np.argwhere(~np.isfinite(a))[0]
        raise SnapshotError(field, f"must be finite, got {a[tuple(bad)]} at index {tuple(int(i) for i in bad)}")
    if a.size and lo is not None and (a.min() < lo or a.max() > hi):
        bad = np.argwhere((a < lo) | (a > hi))[0]
        raise SnapshotError(field, f"must hold values in [{lo}, {hi}], got {a[tuple(bad)]} at index "
                            f"{tuple(int(i) for i in bad)}")


def _optional_array(field: str, a, shape: tuple, dtype, **kw) -> None:
    if a is not None:
        _array(field, a, shape, dtype, **kw)


def _int(field: str, v, lo: int, hi: float = math.inf) -> None:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
        raise SnapshotTypeError(field, f"must be an integer, got {v!r} ({type(v).__name__})")
    if not lo <= v <= hi:
        raise SnapshotError(field, f"must be an integer in [{lo}, {hi}], got {v}")


def _real(field: str, v, lo: float) -> None:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise SnapshotTypeError(field, f"must be a real number, got {v!r} ({type(v).__name__})")
    if not (math.isfinite(v) and v >= lo):
        raise SnapshotError(field, f"must be a finite number ≥ {lo}, got {v!r}")


def _bool(field: str, v) -> None:
    if not isinstance(v, (bool, np.bool_)):
        raise SnapshotTypeError(field, f"must be a bool, got {v!r} ({type(v).__name__})")


def _same(field: str, got, want, what: str) -> None:
    if got != want:
        raise SnapshotError(field, f"was taken with {what} {got!r}, this env has {want!r}")


# ---------------------------------------------------------------------- the parts of a snapshot
def _check_format(snap) -> None:
    if not isinstance(snap, EnvSnapshot):
        raise SnapshotTypeError("snapshot", f"expected an EnvSnapshot (env.get_state()), got {type(snap).__name__}")
    fmt = getattr(snap, "format", None)
    if fmt is None:
        raise SnapshotError("snapshot.format", f"missing: the snapshot was taken by an earlier release of cloth_gym, "
                            f"whose snapshots this release cannot check; this release reads format "
                            f"{SNAPSHOT_FORMAT}: take the snapshot again with env.get_state()")
    if isinstance(fmt, bool) or not isinstance(fmt, int) or fmt != SNAPSHOT_FORMAT:
        raise SnapshotError("snapshot.format", f"is {fmt!r}; this release reads format {SNAPSHOT_FORMAT} only")
    for f in dataclasses.fields(EnvSnapshot):  # a pickle of another layout may lack some
        if not hasattr(snap, f.name):
            raise SnapshotError(f"snapshot.{f.name}", "missing")


def _check_identity(env, snap) -> None:
    if snap.env != type(env).__name__:
        raise SnapshotError("snapshot.env", f"was taken from a {snap.env}, not a {type(env).__name__}")
    _same("snapshot.env_id", snap.env_id, env_id(env), "env id")
    _same("snapshot.material", snap.material, env._model.material.name, "material")
    _same("snapshot.force_model", snap.force_model, env.force_options.model, "force model")
    _same("snapshot.integrator", snap.integrator, env.integrator_kind, "integrator")
    _same("snapshot.observation_mode", snap.observation_mode, env.observation_mode, "observation mode")


def _check_model(env, m) -> None:
    from .settings import _is_randomisation, material_choices

    nominal = env._model
    if not isinstance(m, Model):
        raise SnapshotTypeError("snapshot.model", f"must be a Model, got {type(m).__name__}")
    if m.particle_count != nominal.particle_count:
        raise SnapshotError("snapshot.model", f"has {m.particle_count} particles, this env's cloth "
                            f"{nominal.particle_count} (another sigma?)")
    if m.sigma != nominal.sigma or not np.array_equal(m.particle_q0, nominal.particle_q0):
        raise SnapshotError("snapshot.model", "is another lattice than this env's (another sigma or cloth size?)")
    if m.options != nominal.options:
        raise SnapshotError("snapshot.model.options", f"are not this env's force options: {m.options} vs "
                            f"{nominal.options}")
    choices = material_choices(env.material_spec)
    if choices is not None:
        names = sorted({c.name for c in choices})
        if m.material.name not in names:
            raise SnapshotError("snapshot.model.material", f"is {m.material.name!r}, not one of this env's "
                                f"materials {names}")
    elif m.material.name != nominal.material.name:
        _same("snapshot.model.material", m.material.name, nominal.material.name, "material")
    if not _is_randomisation(env.material_spec) and m.material != nominal.material:
        raise SnapshotError("snapshot.model.material", f"is another {m.material.name!r} than this env's "
                            f"(other coefficients)")


def _check_state(s, n: int, k: int, diverged: bool) -> None:
    if not isinstance(s, State):
        raise SnapshotTypeError("snapshot.state", f"must be a State, got {type(s).__name__}")
    fin = not diverged  # a diverged episode's state may hold NaN: it is never stepped again
    _array("snapshot.state.particle_q", s.particle_q, (n, 3), np.float64, finite=fin)
    _array("snapshot.state.particle_qd", s.particle_qd, (n, 3), np.float64, finite=fin)
    _real("snapshot.state.time", s.time, 0.0)
    _int("snapshot.state.step", s.step, 0)
    _optional_array("snapshot.state.obstacle_offset", s.obstacle_offset, (k, 3), np.float64)
    m = s.solver
    if not isinstance(m, SolverMemory):
        raise SnapshotTypeError("snapshot.state.solver", f"must be a SolverMemory, got {type(m).__name__}")
    for name in ("bdf2_x", "bdf2_v", "quiet_q", "warm_dv"):
        _optional_array(f"snapshot.state.solver.{name}", getattr(m, name), (n, 3), np.float64, finite=fin)
    _optional_array("snapshot.state.solver.contacts", m.contacts, (n,), np.int64, lo=-1, hi=k - 1)
    for name in ("bdf2_h", "warm_h"):
        _real(f"snapshot.state.solver.{name}", getattr(m, name), 0.0)
    for name in ("bdf2_step", "contacts_step", "quiet_step", "warm_step"):
        _int(f"snapshot.state.solver.{name}", getattr(m, name), -1)
    for name in ("quiet_slow", "quiet_sleepy", "asleep"):
        _bool(f"snapshot.state.solver.{name}", getattr(m, name))


def _check_grippers(g, count: int, n: int) -> None:
    from .grippers import Grippers

    if not isinstance(g, dict):
        raise SnapshotTypeError("snapshot.grippers", f"must be a dict, got {type(g).__name__}")
    if set(g) != set(Grippers.EPISODE_FIELDS):
        raise SnapshotError("snapshot.grippers", f"must have the keys {sorted(Grippers.EPISODE_FIELDS)}, got "
                            f"{sorted(map(str, g))}")
    _array("snapshot.grippers.position", g["position"], (count, 3), np.float64)
    _array("snapshot.grippers.velocity", g["velocity"], (count, 3), np.float64)
    _array("snapshot.grippers.closed", g["closed"], (count,), np.bool_)
    _array("snapshot.grippers.held_by", g["held_by"], (n,), np.int64, lo=-1, hi=count - 1)
    _array("snapshot.grippers.slipped", g["slipped"], (n,), np.int64, lo=-1, hi=count - 1)
    _int("snapshot.grippers.slips", g["slips"], 0)
    held = np.unique(g["held_by"][g["held_by"] >= 0])
    if held.size and not g["closed"][held].all():
        raise SnapshotError("snapshot.grippers.held_by", f"names gripper {int(held[~g['closed'][held]][0])} as "
                            f"holding particles, but it is open")


def _check_task(task, fields: dict) -> None:
    if not isinstance(task, dict):
        raise SnapshotTypeError("snapshot.task", f"must be a dict, got {type(task).__name__}")
    if set(task) != set(fields):
        raise SnapshotError("snapshot.task", f"must have exactly the keys {sorted(fields)}, got "
                            f"{sorted(map(str, task))}")
    for name, shape in fields.items():
        _array(f"snapshot.task.{name}", task[name], shape, np.float64)


def _check_obs(field: str, obs, space, finite: bool) -> None:
    if isinstance(space, spaces.Dict):
        if not isinstance(obs, dict) or set(obs) != set(space.spaces):
            raise SnapshotTypeError(field, f"must be a dict with the keys {sorted(space.spaces)}, got "
                                    f"{type(obs).__name__}")
        for key, sub in space.spaces.items():
            _check_obs(f"{field}.{key}", obs[key], sub, finite)
        return
    _array(field, obs, space.shape, space.dtype, finite=finite)


def check_snapshot(env, snap) -> None:
    """Raise a :class:`~cloth_gym.errors.SnapshotError` naming the first field of ``snap`` that
    does not fit ``env`` (see the module docstring); return None when it fits."""
    _check_format(snap)
    _check_identity(env, snap)
    _check_model(env, snap.model)
    _bool("snapshot.diverged", snap.diverged)
    n, k = env._model.particle_count, env._model.obstacle_arrays[0].shape[0]
    _check_state(snap.state, n, k, bool(snap.diverged))
    _check_grippers(snap.grippers, env.n_grippers, n)
    _check_task(snap.task, env.episode_fields)
    if not isinstance(snap.rng, np.random.Generator):
        raise SnapshotTypeError("snapshot.rng", f"must be a numpy random Generator, got {type(snap.rng).__name__}")
    if snap.rng_seed is not None:
        _int("snapshot.rng_seed", snap.rng_seed, -1)
    _int("snapshot.elapsed_steps", snap.elapsed_steps, 0)
    _check_obs("snapshot.last_obs", snap.last_obs, env.observation_space, env.observation_mode != "rgb")
