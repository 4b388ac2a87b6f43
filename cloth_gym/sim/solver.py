"""What every time integrator shares: :class:`SolverBase` and the checks, world and profile it uses.

An integrator (:class:`~cloth_gym.sim.integrators.SymplecticEuler`,
:class:`~cloth_gym.sim.implicit.ImplicitEuler`) is a :class:`SolverBase`: the base checks each
call's arguments (a :class:`~cloth_gym.sim.model.Model`, a :class:`~cloth_gym.sim.model.State` of
its particles, a :class:`~cloth_gym.sim.model.Control` or None, a step in
[``MIN_DT_SECONDS``, ``MAX_CALL_SECONDS``]), splits ``step(dt)`` and ``advance(duration, dt)`` into
equal substeps, times the call, and hands the substeps to the integrator's own :meth:`_run`. The
world of a call (obstacles where the state has them, their velocities, the contact record) is
built by :func:`make_world`; a call's phase profile is read by :func:`phase_profile`.
"""

from __future__ import annotations

import functools
import math
import time

import numpy as np

from ..errors import ConfigError, ConfigTypeError, InsideObstacle, SimulationDiverged
from ..validation import integer, real, vector
from ._numba import cycles, njit
from .bundles import N_PHASES, P_CG_PRECONDITION, P_CG_PRODUCT, PHASE_NAMES, PROFILE_SIZE, World
from .collision import MeshObstacle
from .diagnostics import fastest, first_non_finite
from .model import MAX_INPUT_SPEED, Control, Model, SolverMemory, State
from .obstacles import deepest_inside, moved_obstacles

__all__ = ["SolverBase", "check_dt", "check_advance", "check_call", "check_steps", "check_strain_guard",
           "strain_guard", "make_world", "effective_mass", "phase_profile", "cycles_per_second",
           "MIN_DT_SECONDS", "MAX_CALL_SECONDS", "MAX_STEPS_PER_CALL", "INSIDE_TOLERANCE_CM"]


class SolverBase:
    """A time integrator: ``step`` and ``advance`` over the integrator's own :meth:`_run`.

    A subclass sets :meth:`substeps_for` (the substeps of a step of ``dt`` seconds) and
    :meth:`_run` (``n`` substeps of ``h`` seconds on the state, in place; it stores its kernel's
    cycle counts with :meth:`_timed`), and may set :meth:`_call_context` (what ``_run`` needs to
    know of the call, computed once) and :meth:`_step_substeps` (``step``'s own substep rules on
    top of :meth:`substeps_for`, e.g. by the cloth's speed)."""

    _profile: tuple[np.ndarray, float] | None = None

    # ---------------------------------------------------------------- what a subclass sets
    def substeps_for(self, model: Model, dt: float) -> int:
        """Number of equal substeps ``step`` uses for a step of ``dt`` seconds."""
        raise NotImplementedError

    def _run(self, model: Model, state: State, control: Control | None, n: int, h: float, context):
        """``n`` substeps of ``h`` s on ``state`` in place; returns the step's info."""
        raise NotImplementedError

    def _call_context(self, model: Model, state: State, control: Control | None):
        """What :meth:`_run` needs to know of the call, read before it changes anything (default: None)."""
        return None

    def _step_substeps(self, model: Model, state: State, dt: float, n: int, context) -> int:
        """``step``'s substeps, given :meth:`substeps_for`'s ``n`` (default: ``n``)."""
        return n

    # ---------------------------------------------------------------- the API
    def step(self, model: Model, state: State, control: Control | None, dt: float):
        """Advance ``state`` in place by ``dt`` seconds, in equal substeps; returns the step's info."""
        check_call(model, state, control)
        self._check_speed(model, state)
        n = self.substeps_for(model, dt)
        context = self._call_context(model, state, control)
        n = self._step_substeps(model, state, dt, n, context)
        return self._run(model, state, control, n, dt / n, context)

    def advance(self, model: Model, state: State, control: Control | None, duration: float, dt: float) -> int:
        """Advance by ``duration`` seconds in steps of at most ``dt`` (each in :meth:`substeps_for`'s
        substeps); returns the number of substeps taken."""
        duration, dt = check_advance(duration, dt)
        check_call(model, state, control)
        self._check_speed(model, state)
        if duration == 0:
            return 0
        n_outer = max(1, int(math.ceil(duration / dt - 1e-9)))
        h_outer = duration / n_outer
        n_sub = self.substeps_for(model, h_outer)
        check_steps("dt", n_outer * n_sub)
        self._run(model, state, control, n_outer * n_sub, h_outer / n_sub, self._call_context(model, state, control))
        return n_outer * n_sub

    @property
    def last_profile(self) -> dict[str, float] | None:
        """Where the last ``step``/``advance`` call spent its time: seconds per
        :class:`~cloth_gym.sim.bundles.Phase`, plus ``other``, ``call`` and ``total``
        (:func:`phase_profile`). Read from the CPU's cycle counter around each phase, which costs a
        few nanoseconds per phase; None before a call."""
        return None if self._profile is None else phase_profile(*self._profile)

    @property
    def last_cg_profile(self) -> dict[str, float] | None:
        """The last call's PCG solves split by work: seconds in the operator's products
        (``product``: ``A·p`` and its constraint filter) and in the preconditioner's applies
        (``precondition``), summed over the call's solves (the first, the friction re-solve, Newton
        passes, the collision coupling's). Both are part of the phases those solves run in
        (:attr:`last_profile`); the rest of a solve is CG's dot products and vector updates (the
        band factorisation is a phase of its own). None before a call or without a cycle counter;
        zeros for an integrator without a linear solve."""
        return None if self._profile is None else cg_profile(self._profile[0])

    def _check_speed(self, model: Model, state: State) -> None:
        """A state handed over faster than the integrator's divergence threshold ``max_speed``
        (cm/s) has diverged already: :class:`SimulationDiverged` naming the fastest particle (a
        step could otherwise hide it: contact or an overflowing solve can zero such a velocity)."""
        limit = getattr(self, "max_speed", math.inf)
        p, sq, _ = fastest(state.particle_qd, model.particle_inv_mass)
        if p >= 0 and not sq <= limit * limit:
            raise SimulationDiverged(state.step, state.time, p, "speed", math.sqrt(sq),
                                     f"the state given to the integrator is already faster than max_speed = "
                                     f"{limit:g} cm/s at particle {p}: restore or reset it")

    def _timed(self, kernel, *args):
        """``kernel(*args, prof)`` with a fresh phase profile ``prof``, kept with the call's wall
        time for :attr:`last_profile`; returns what the kernel returns."""
        prof = np.zeros(PROFILE_SIZE, dtype=np.int64)
        t = time.perf_counter()
        out = kernel(*args, prof)
        self._profile = (prof, time.perf_counter() - t)
        return out


def effective_mass(model: Model) -> float:
    """The smallest mass per unit of edge width at a particle (g): min over particles and lattice
    directions of ``m_p / (½·Σ w_e)`` over the particle's edges e in that direction. A particle
    inside the cloth has two edges of width 1 per direction (its mass W·σ²); area lumping halves
    the mass and the edge widths on the outline together, so the stiffest mode per unit mass, and
    the stable step, stay those of the inside."""
    n = model.particle_count
    width = np.zeros((n, 2))  # Σ w_e per particle and direction
    for end in (0, 1):
        np.add.at(width, (model.edge_indices[:, end], model.edge_dir), model.edge_width)
    ratio = 0.5 * width.max(axis=1) / model.particle_mass
    return float(1.0 / ratio.max()) if ratio.max() > 0 else float(np.min(model.particle_mass))


def obstacle_motion(model: Model, state: State, control: Control | None):
    """(offset (K, 3) cm — the state's own array, advanced in place —, velocity (K, 3) cm/s) of the
    analytic obstacles for an integrator call."""
    k = model.obstacle_arrays[0].shape[0]
    vel = np.zeros((k, 3)) if control is None else control.obstacle_velocities(model)
    off = state.obstacle_offset
    if off is None or off.shape != (k, 3):
        off = np.zeros((k, 3))
        if np.any(vel != 0.0):
            state.obstacle_offset = off
    return off, vel


def make_world(model: Model, state: State, control: Control | None, touching: np.ndarray | None = None) -> World:
    """The :class:`~cloth_gym.sim.bundles.World` of one integrator call: the model's obstacles where
    ``state`` has them (its ``obstacle_offset``, advanced in place by the call), their velocities
    from ``control``, the contact record ``touching`` (a fresh one when None) and the collision
    pass's data."""
    offset, vel = obstacle_motion(model, state, control)
    ob = model.obstacle_data
    prm = moved_obstacles(ob.params, offset)
    if touching is None:
        touching = -np.ones(model.particle_count, dtype=np.int64)
    return World(ob, prm, offset, vel, touching, model.collision_arrays)


#: the range of a time step or duration an integrator call accepts, s: from a nanosecond (far below any
#: stable step of a cloth) to a day (no scene simulates longer in one call)
MIN_DT_SECONDS = 1e-9


MAX_CALL_SECONDS = 86400.0


#: the most (sub)steps one integrator call may take: a call asking for more is refused rather than
#: left running for hours
MAX_STEPS_PER_CALL = 10**6


def check_dt(field: str, dt) -> float:
    """A time step (s): a finite number in [MIN_DT_SECONDS, MAX_CALL_SECONDS]."""
    return real(field, dt, MIN_DT_SECONDS, MAX_CALL_SECONDS, unit="s")


def check_advance(duration, dt) -> tuple[float, float]:
    """``advance``'s arguments: a duration in [0, MAX_CALL_SECONDS] s and a step as :func:`check_dt`,
    at most MAX_STEPS_PER_CALL of them."""
    duration = real("duration", duration, 0.0, MAX_CALL_SECONDS, unit="s")
    dt = check_dt("dt", dt)
    check_steps("dt", duration / dt)
    return duration, dt


def check_strain_guard(max_strain_percent) -> float | None:
    """An integrator's ``max_strain_percent``: None (the model's guard) or a strain in (0, 1e6] %."""
    if max_strain_percent is None:
        return None
    return real("max_strain_percent", max_strain_percent, 0.0, 1e6, lo_open=True,
                unit="% (None: the model's strain guard)")


def strain_guard(model, max_strain_percent: float | None) -> float:
    """The strain (%) past which a step of ``model`` diverges: ``max_strain_percent``, else the
    model's :attr:`~cloth_gym.sim.model.Model.strain_guard_percent`; ``inf`` for none."""
    if max_strain_percent is not None:
        return max_strain_percent
    guard = model.strain_guard_percent
    return math.inf if guard is None else float(guard)


@njit
def _read_cycles():
    return cycles()


@functools.lru_cache(maxsize=1)
def cycles_per_second() -> float:
    """The rate of the cycle counter that the phase profile reads (ticks per second), measured once
    per process against ``time.perf_counter`` over 20 ms; 0 where the target has no counter."""
    _read_cycles()  # compile or load it first
    t0, c0 = time.perf_counter(), _read_cycles()
    while time.perf_counter() - t0 < 0.02:
        pass
    t1, c1 = time.perf_counter(), _read_cycles()
    return max(0.0, (c1 - c0) / (t1 - t0))


def phase_profile(prof: np.ndarray, wall_s: float) -> dict[str, float] | None:
    """Seconds per :class:`~cloth_gym.sim.bundles.Phase` of one integrator call from its kernel's
    cycle counts ``prof`` (the phases, then the whole loop, then :func:`cg_profile`'s counts), with
    ``"other"`` (the rest of the loop: copies, updates between the phases), ``"call"`` (``wall_s``
    less the loop: passing the arguments to the kernel, its allocations) and ``"total"``
    (``wall_s``, the call's wall time). None where the platform has no cycle counter."""
    rate = cycles_per_second()
    if rate <= 0.0:
        return None
    out = {name: float(prof[i]) / rate for i, name in enumerate(PHASE_NAMES)}
    loop = float(prof[N_PHASES]) / rate
    out["other"] = max(0.0, loop - sum(out.values()))
    out["call"] = max(0.0, wall_s - loop)
    out["total"] = float(wall_s)
    return out


def cg_profile(prof: np.ndarray) -> dict[str, float] | None:
    """Seconds of the PCG solves' products and preconditioner applies from a call's cycle counts
    ``prof`` (:data:`~cloth_gym.sim.bundles.PROFILE_SIZE`); None where the platform has no cycle
    counter."""
    rate = cycles_per_second()
    if rate <= 0.0:
        return None
    return {"product": float(prof[P_CG_PRODUCT]) / rate, "precondition": float(prof[P_CG_PRECONDITION]) / rate}


def check_steps(field: str, n: float) -> int:
    """``n`` (sub)steps for one call, refused (naming ``field``) above MAX_STEPS_PER_CALL."""
    if n > MAX_STEPS_PER_CALL:
        raise ConfigError(field, f"the call would take {n:.3g} steps, more than MAX_STEPS_PER_CALL = "
                          f"{MAX_STEPS_PER_CALL:.0e}: use a larger step or several calls")
    return int(n)


def check_call(model, state, control) -> None:
    """The arguments of an integrator's ``step``/``advance``: a :class:`Model`, a :class:`State` of its
    particles (float64 (N, 3) positions and velocities) and a :class:`Control` or None (a finite (3,)
    wind). A non-finite state is a :class:`SimulationDiverged` naming the particle
    (:func:`check_finite`)."""
    if not isinstance(model, Model):
        raise ConfigTypeError("model", f"expected a cloth_gym Model (build_cloth), got {type(model).__name__}")
    if not isinstance(state, State):
        raise ConfigTypeError("state", f"expected a cloth_gym State (model.state()), got {type(state).__name__}")
    n = model.particle_count
    for name in ("particle_q", "particle_qd"):
        a = getattr(state, name)
        if not isinstance(a, np.ndarray) or a.shape != (n, 3) or a.dtype != np.float64 or not a.flags.c_contiguous \
                or not a.flags.writeable:
            raise ConfigError(f"state.{name}", f"must be a writeable C-contiguous float64 array of shape ({n}, 3) "
                              f"(the model's particles), got {getattr(a, 'dtype', type(a).__name__)} "
                              f"{getattr(a, 'shape', '')}")
    real("state.time", state.time, -MAX_CALL_SECONDS * 1e6, MAX_CALL_SECONDS * 1e6, unit="s")
    integer("state.step", state.step, 0, 2**62)
    k = model.obstacle_arrays[0].shape[0]
    off = state.obstacle_offset
    if off is not None and not (isinstance(off, np.ndarray) and off.shape == (k, 3) and off.dtype == np.float64
                                and off.flags.writeable and np.all(np.isfinite(off))):
        raise ConfigError("state.obstacle_offset", f"must be None or a finite float64 array of shape ({k}, 3) cm, "
                          f"got {off!r}")
    if not isinstance(state.solver, SolverMemory):
        raise ConfigTypeError("state.solver", f"must be a SolverMemory, got {type(state.solver).__name__}")
    if control is not None:
        if not isinstance(control, Control):
            raise ConfigTypeError("control", f"expected a cloth_gym Control or None, got {type(control).__name__}")
        vector("Control.wind", control.wind, 3, unit="cm/s", limit=MAX_INPUT_SPEED)
        if control.obstacle_velocity is not None:  # None: no velocity (nothing to check)
            control.obstacle_velocities(model)
    check_finite(state)
    check_outside(model, state, model.particle_inv_mass if control is None else control.inv_mass(model))


def check_finite(state: State) -> None:
    """A state handed to an integrator with a NaN or infinite position or velocity is a
    :class:`~cloth_gym.errors.SimulationDiverged` naming that particle at once (one step later the
    forces would have spread it to its neighbours)."""
    p = first_non_finite(state.particle_q, state.particle_qd)
    if p >= 0:
        raise SimulationDiverged(state.step, state.time, p, "non-finite", math.nan,
                                 f"the state given to the integrator is already non-finite at particle {p}: "
                                 "restore or reset it")


#: round-off allowed beyond the contact thickness by :func:`check_outside`, cm (contact leaves particles
#: up to ~1e-15 cm inside a surface, which a thickness of 0 would otherwise refuse)
INSIDE_TOLERANCE_CM = 1e-9


def check_outside(model: Model, state: State, inv_mass: np.ndarray) -> None:
    """Refuse a start state with a free particle (``inv_mass`` > 0: neither pinned nor kinematic) deeper inside an
    analytic obstacle than the model's contact thickness: :class:`~cloth_gym.errors.InsideObstacle`
    naming the particle, the obstacle and the depth. Contact keeps simulated particles outside (at
    most round-off inside: :data:`INSIDE_TOLERANCE_CM` more is allowed), so only a state placed or
    edited by hand can fail this."""
    ob = model.obstacle_data
    if ob.types.shape[0] == 0:
        return
    offset = state.obstacle_offset if state.obstacle_offset is not None else np.zeros((ob.types.shape[0], 3))
    p, k, depth = deepest_inside(state.particle_q, inv_mass, ob.types, moved_obstacles(ob.params, offset))
    if p >= 0 and depth > model.contact_thickness + INSIDE_TOLERANCE_CM:
        kind = [o for o in model.obstacles if not isinstance(o, MeshObstacle)][k]
        raise InsideObstacle(p, k, depth, model.contact_thickness, type(kind).__name__)
