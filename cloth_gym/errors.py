"""Typed errors of cloth_gym.

Every error that bad input or a failing simulation can raise derives from
:class:`ClothGymError`, so callers can catch the whole family at once, and each
also derives from the builtin it refines (``ValueError`` for bad values,
``ArithmeticError`` for numerical failures), so generic handlers keep working.
"""

from __future__ import annotations


class ClothGymError(Exception):
    """Base class of every error raised by cloth_gym."""


class ConfigError(ClothGymError, ValueError):
    """A configuration value is missing, unknown, or out of its allowed range.

    The message names the field (dotted path, e.g. ``stretch.warp.c1``), the
    value given and the allowed range or the allowed keys.

    ``ConfigError(field, message)`` is the usual form. A single argument
    ``"field: message"`` is split at its first ``": "`` (libraries such as
    Gymnasium re-raise an error as ``type(err)(text)``, and the field must
    survive that).
    """

    def __init__(self, field: str, message: str | None = None):
        if message is None:
            field, sep, message = str(field).partition(": ")
            if not sep:  # no field given
                field, message = "", field
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}" if field else message)

    def __reduce__(self):  # picklable (vector-env workers send errors across processes)
        return _rebuild, (type(self), (self.field, self.message), self.__dict__)


def _rebuild(cls, args, state):
    """Unpickle an error made with ``cls(*args)``, its attributes restored."""
    err = cls(*args)
    err.__dict__.update(state)
    return err


class ConfigTypeError(ConfigError, TypeError):
    """A configuration value has the wrong type (a string for a number, an unknown keyword
    argument, a ragged action): a :class:`ConfigError` that ``except TypeError`` catches too."""


class MaterialError(ConfigError):
    """A fabric description is invalid (negative mass, unknown key, NaN, ...).

    ``file`` is the YAML file it came from, when there is one (the message names it too).
    """

    file: str | None = None


class MaterialTypeError(MaterialError, TypeError):
    """A fabric description of the wrong type (``load_material(123)``, a list for a curve)."""


class SnapshotError(ConfigError):
    """An env snapshot that does not fit the env it is restored into (``ClothEnv.set_state``): another
    format version, env id, material, force model, integrator or observation mode, or a field of
    the wrong shape, dtype, range or a non-finite number. ``field`` names the first mismatch
    (``snapshot.state.particle_q``, ``snapshot.task.target``)."""


class SnapshotTypeError(SnapshotError, ConfigTypeError):
    """A snapshot, or a field of one, of the wrong type (not an ``EnvSnapshot``, a list for an array)."""


class SizeError(ConfigError):
    """A lattice with more particles than the size guard allows (``build_cloth(max_particles=)``).

    ``particles`` is the count the lattice would have and ``memory_bytes`` an estimate of what
    simulating it would take.
    """

    def __init__(self, field: str, message: str | None = None, particles: int = 0, memory_bytes: float = 0.0):
        super().__init__(field, message)
        self.particles = int(particles)
        self.memory_bytes = float(memory_bytes)



class StabilityError(ClothGymError, ValueError):
    """A time step exceeds the explicit integrator's estimated stability limit."""

    def __init__(self, dt: float, limit: float, message: str):
        self.dt = float(dt)
        self.limit = float(limit)
        super().__init__(message)

    def __reduce__(self):
        return type(self), (self.dt, self.limit, self.args[0])


class InsideObstacle(ClothGymError, ValueError):
    """A particle starts an integrator call deeper inside an obstacle than the contact thickness.

    Contact keeps every free particle outside the obstacles once simulated; a start state with one
    deep inside (a cloth placed through a table) has no outside to be pushed to that the simulator
    could know, so it is refused.

    Attributes
    ----------
    particle
        Index of the deepest particle.
    obstacle
        Index of the obstacle in the model's analytic obstacles (``Plane``, ``Box``, ``Sphere``,
        ``Cylinder``, in the order given to ``build_cloth``).
    depth_cm
        How deep inside it the particle is, cm.
    thickness_cm
        The model's contact thickness, cm.
    """

    def __init__(self, particle: int, obstacle: int, depth_cm: float, thickness_cm: float, kind: str = "obstacle"):
        self.particle = int(particle)
        self.obstacle = int(obstacle)
        self.depth_cm = float(depth_cm)
        self.thickness_cm = float(thickness_cm)
        self.kind = kind
        super().__init__(f"state.particle_q: particle {self.particle} starts {self.depth_cm:.4g} cm inside obstacle "
                         f"{self.obstacle} ({kind}), more than the contact thickness {self.thickness_cm:g} cm; "
                         f"start the cloth outside the obstacles")

    def __reduce__(self):
        return type(self), (self.particle, self.obstacle, self.depth_cm, self.thickness_cm, self.kind)


class SimulationDiverged(ClothGymError, ArithmeticError):
    """The state became non-finite or exploded.

    Attributes
    ----------
    step
        Index of the (sub)step at which the failure was detected, counted from
        the start of the integrator call that detected it, plus any offset the
        caller passed (the simulator counts steps over its whole life).
    time_s
        Simulated time (s) at the end of that step.
    particle
        Index of the first offending particle; −1 when no particle is at fault by itself
        (reason ``"not-spd"``).
    reason
        ``"non-finite"``, ``"speed"`` (speed above the explosion threshold),
        ``"strain"`` (an edge stretched past the explosion threshold) or ``"not-spd"`` (the
        implicit solver's matrix is not positive definite while every particle is finite).
    value
        The offending value (speed in cm/s, strain in percent, or NaN).
    hint
        What the user can still change, from the integrator that raised it (None: a generic hint).
    """

    def __init__(self, step: int, time_s: float, particle: int, reason: str, value: float, hint: str | None = None):
        self.step = int(step)
        self.time_s = float(time_s)
        self.particle = int(particle)
        self.reason = reason
        self.value = float(value)
        self.hint = hint
        what = (f"particle {self.particle} {reason} (value {self.value:.6g})" if self.particle >= 0 else
                "the implicit solver's matrix is not positive definite" if reason == "not-spd" else reason)
        if hint is None:
            hint = ("check the start state (a cloth starting inside an obstacle?) or reduce dt" if reason == "not-spd"
                    else "reduce dt or use more substeps")
        super().__init__(f"simulation diverged at step {self.step} (t = {self.time_s:.6g} s): {what}; {hint}")

    def __reduce__(self):
        return type(self), (self.step, self.time_s, self.particle, self.reason, self.value, self.hint)


class ResetNeeded(ClothGymError, RuntimeError):
    """An env stepped before its first ``reset()``."""


class RemoteEnvError(ClothGymError, RuntimeError):
    """A sub-env living in another process (a Ray actor of
    :class:`cloth_gym.agents.ray_vec_env.RayVecEnv`) died, failed or did not answer in time.

    Attributes
    ----------
    actor
        Index of the actor.
    sub_envs
        The indices (in the vector env) of the sub-envs it held; their episodes are lost.
    """

    def __init__(self, actor: int, sub_envs, message: str):
        self.actor = int(actor)
        self.sub_envs = [int(i) for i in sub_envs]
        super().__init__(message)

    def __reduce__(self):
        return type(self), (self.actor, self.sub_envs, self.args[0])
