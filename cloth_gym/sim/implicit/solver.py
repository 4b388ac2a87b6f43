"""The implicit integrator's Python side: :class:`ImplicitEuler` (settings, substeps, the
preconditioner's choice, what a call reads from and writes to ``State.solver``) over the compiled
step of :mod:`cloth_gym.sim.implicit.step`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...errors import ConfigError, SimulationDiverged
from ...validation import flag, integer, one_of, real
from ..bundles import DIVERGE_REASONS, PROFILE_SIZE, Guard, Status, Unlimited
from ..diagnostics import edge_strain, fastest
from ..model import Model, State
from ..obstacles import moved_obstacles, resting_contacts
from ..solver import SolverBase, check_dt, check_steps, check_strain_guard, effective_mass, make_world, strain_guard
from .bundles import Band, Carry, Multigrid, NewtonPasses, OneLevel, Precond, SolveOptions, newton_kind
from .levels import Hierarchy, Level, build_hierarchy
from .step import run_implicit

__all__ = ["ImplicitEuler", "ImplicitStepInfo"]

#: what a diverged implicit step can still change (it is the implicit integrator already)
IMPLICIT_HINT = ("reduce max_dt, bound the substeps by travel (max_travel, lattice spacings), converge the "
                 "Newton solve (newton_iters=10, newton_tol=0.1) or check the start state")
#: ... of a call that diverged again when retried with the Newton solve converged (retry_diverged)
RETRIED_HINT = ("the call diverged again when run with the Newton solve converged (retry_diverged): reduce "
                "max_dt, bound the substeps by travel (max_travel, lattice spacings) or check the start state")

_SMOOTH_DAMPING = 0.7  # ω of the damped line smoother (its spectrum reaches ~2.6 undamped)
#: max_travel="auto": lattice spacings a free particle may travel per substep where self-collision is on
AUTO_MAX_TRAVEL = 0.5
AUTO_MULTIGRID_PARTICLES = 1000  # preconditioner="auto": multigrid from this many particles, lines below
# ... except for small steps on mid-sized lattices, where lines need few enough iterations to win:
# "auto" keeps lines below AUTO_LINES_PARTICLES while the stiffness number h²·k/m stays below
# AUTO_LINES_STIFFNESS (k the stiffest edge's tangent at rest, m the lightest particle). Measured,
# CPU s per simulated s, 41×41 cotton tablecloth, t = 0.02–0.52 s, lines / multigrid: 1 ms (number
# 228) 10.5 / 13.8, 2 ms (913) 7.6 / 8.9, 3 ms (2055) 6.6 / 7.7, 5 ms (5700) 5.8 / 5.3, 10 ms 2.5 /
# 2.3; 81×81 at 1 ms (913): 90 / 73 (lines' iterations grow with the lattice's width).
AUTO_LINES_STIFFNESS = 3000.0
AUTO_LINES_PARTICLES = 4000
AUTO_BAND_WORK = 1.0e6  # preconditioner="auto": the band factor while 3N·(band width)² stays below this
#: retry_diverged: the Newton settings a diverged call is run again with (passes to 0.1 cm/s, a line
#: search on each correction, momentum-exact solves): docs/numerics.md, "Shaking a cloth"
RETRY_NEWTON = {"newton": NewtonPasses(10), "newton_tol": 0.1, "newton_tol_max": 0.0, "line_search": True,
                "momentum_exact": True}
#: refine_strain_rise: a refined call takes this many times the substeps. RibbonDrop-v3 pressed onto
#: the floor, 8 seeds, largest strain 1.39 % at 5 ms substeps, 0.76 % at 2.5 ms, 0.13 % at 1.25 ms
#: (docs/numerics.md, "Refining the calls where a strain jumps")
REFINE_FACTOR = 4


@dataclass(frozen=True)
class ImplicitStepInfo:
    """What one ``step`` did: substeps, substep length (s), CG iterations (max, mean), worst residual and
    linear solves per substep (mean: 1 for a single linearised pass, more with Newton corrections)."""

    substeps: int
    dt_sub: float
    cg_iterations_max: int
    cg_iterations_mean: float
    residual_max: float
    solves_mean: float = 1.0

    @classmethod
    def of(cls, stats: np.ndarray, h: float) -> "ImplicitStepInfo":
        """The info of a call's substeps of ``h`` s from their ``stats`` rows (CG iterations, relative
        residual, linear solves), summed in Python: the counts are whole numbers, so the means are
        numpy's to the bit, without numpy's per-call cost."""
        its, res, solves = zip(*stats.tolist())
        n = len(its)
        worst = math.nan if any(r != r for r in res) else max(res)  # NaN kept, as numpy's max
        return cls(n, h, int(max(its)), sum(its) / n, worst, sum(solves) / n)


class ImplicitEuler(SolverBase):
    """Backward Euler or BDF2, one linearised Newton step per (sub)step (more on request), PCG solve
    (:mod:`cloth_gym.sim.implicit`). What each setting trades, with measurements: the docs'
    solver core page (docs/solver_core.md), "The implicit integrator's settings".

    Parameters
    ----------
    max_dt
        s: ``step(dt)`` uses ``ceil(dt / max_dt)`` equal substeps. Stability does not limit it;
        accuracy and numerical damping do.
    tol
        CG relative residual tolerance ``|r|/|b|``.
    vtol, max_iter
        cm/s (0, the default: off): CG also stops once the residual bounds the mass-weighted RMS
        error of Δv by ``vtol`` (:func:`~cloth_gym.sim.implicit.cg.filtered_pcg`); ``max_iter`` caps its iterations.
    preconditioner
        ``"auto"`` (default; :meth:`preconditioner_for` says what it picks: band, lines or
        multigrid by lattice size and step), ``"band"``, ``"multigrid"``, ``"lines"``, ``"jacobi"``.
    max_speed, max_strain_percent
        divergence thresholds, cm/s and % edge strain (None: the model's guard).
    scheme
        ``"euler"`` (backward Euler, first order, strongly damping) or ``"bdf2"`` (second order,
        the same linear system with β = 2h/3; its history is kept in ``State.solver``, and a state
        without one for its current step and Δt starts with one backward-Euler step).
    newton_iters, newton_tol, newton_tol_max, line_search
        Newton passes per step at most (1: Baraff–Witkin's single linearised step), stopping once
        the nonlinear residual's mass-weighted RMS is within ``newton_tol`` (cm/s, > 0) and, with
        ``newton_tol_max`` (cm/s), every particle's correction within that. ``line_search``: each
        correction taken as α·δ, α halved from 1 until the residual falls enough.
    momentum_exact
        True (default): in free flight, each solve's Δv corrected to its exact momentum balance
        (:func:`~cloth_gym.sim.implicit.cg.exact_momentum`).
    strain_limit_percent, strain_iters
        None (default, off) or a strain (%, > 0): after each step, at most ``strain_iters``
        Gauss–Seidel sweeps pull lattice edges longer than ``(1 + limit/100)·L`` back and remove
        their separating velocity (:func:`~cloth_gym.sim.substep.limit_strain`).
    sleep_speed
        cm/s (0, the default: off): the cloth falls asleep (velocities zeroed; later calls only
        advance the time) after two quiet calls (no kinematic particle, wind or moving obstacle)
        that moved no particle faster than this on average.
    slow_dt, slow_speed
        s (0, the default: off) and cm/s (1.0): a :meth:`step` under quiet inputs that follows a
        quiet call in which no particle moved faster than ``slow_speed`` takes substeps of up to
        ``slow_dt`` instead of ``max_dt`` (:attr:`slow`); ``advance`` does not.
    warm_start, friction_resolve
        (True, True) each solve starts from the previous step's Δv; a step is solved again with
        raised friction dampers where particles slid slower than their dampers assumed.
    max_travel
        lattice spacings, None (off) or ``"auto"`` (default: :data:`AUTO_MAX_TRAVEL` where the
        model's self-collision is on): a call whose fastest free particle would move farther than
        this in one substep takes more, shorter substeps (fast impacts on the cloth itself).
    retry_diverged
        True (default): a call that diverges is run again from its start with :data:`RETRY_NEWTON`
        (:attr:`retried`), raising only if that diverges too; other calls are unchanged.
    couple_collisions
        False (default); True: the collision pass fed back into the solve (:func:`~.coupling.coupled_finish`).
    refine_strain_rise
        None (default, off) or percentage points (> 0): a call after which an edge's strain rose by
        more than this, or which diverged, is run again from its start in :data:`REFINE_FACTOR`
        times the substeps (:attr:`refined`); other calls are unchanged.
    """

    def __init__(self, max_dt: float = 5e-3, tol: float = 1e-4, max_iter: int = 200, vtol: float = 0.0,
                 preconditioner: str = "auto", max_speed: float = 1.0e5,
                 max_strain_percent: float | None = None, scheme: str = "euler", newton_iters: int = 1,
                 strain_limit_percent: float | None = None, strain_iters: int = 100, sleep_speed: float = 0.0,
                 slow_dt: float = 0.0, slow_speed: float = 1.0, warm_start: bool = True,
                 friction_resolve: bool = True, max_travel: float | str | None = "auto", newton_tol: float = 0.0,
                 momentum_exact: bool = True, newton_tol_max: float = 0.0, line_search: bool = False,
                 retry_diverged: bool = True, couple_collisions: bool = False,
                 refine_strain_rise: float | None = None):
        max_dt = real("max_dt", max_dt, 0.0, 10.0, lo_open=True, unit="s")
        tol = real("tol", tol, 0.0, 1.0, lo_open=True, hi_open=True)
        vtol = real("vtol", vtol, 0.0, 1e3, hi_open=True, unit="cm/s")
        max_iter = integer("max_iter", max_iter, 1, 100_000)
        max_speed = real("max_speed", max_speed, 0.0, 3e10, lo_open=True, unit="cm/s")
        max_strain_percent = check_strain_guard(max_strain_percent)
        newton_iters = integer("newton_iters", newton_iters, 1, 10)
        self.newton_tol = real("newton_tol", newton_tol, 0.0, 1e3, hi_open=True, unit="cm/s (0: every pass)")
        self.newton_tol_max = real("newton_tol_max", newton_tol_max, 0.0, 1e4, hi_open=True,
                                   unit="cm/s (0: no per-particle test)")
        if self.newton_tol_max > 0.0 and self.newton_tol == 0.0:
            raise ConfigError("newton_tol_max", "needs newton_tol > 0 (the passes' stopping test it adds to)")
        self.momentum_exact = flag("momentum_exact", momentum_exact)
        self.line_search = flag("line_search", line_search)
        self.retry_diverged = flag("retry_diverged", retry_diverged)
        self.couple_collisions = flag("couple_collisions", couple_collisions)
        self.retried = False  # was the last call run again after diverging?
        self.refine_strain_rise = None if refine_strain_rise is None else real(
            "refine_strain_rise", refine_strain_rise, 0.0, 100.0, lo_open=True, unit="percentage points (None: off)")
        self.refined = False  # was the last call run again with REFINE_FACTOR times the substeps?
        one_of("scheme", scheme, ("euler", "bdf2"))
        one_of("preconditioner", preconditioner, ("auto", "band", "multigrid", "lines", "jacobi"))
        if strain_limit_percent is not None:
            strain_limit_percent = real("strain_limit_percent", strain_limit_percent, 0.0,
                                        1e6 if max_strain_percent is None else max_strain_percent,
                                        lo_open=True, hi_open=True, unit="% (None: off; below max_strain_percent)")
        sleep_speed = real("sleep_speed", sleep_speed, 0.0, 1e3, hi_open=True, unit="cm/s (0: off)")
        slow_dt = real("slow_dt", slow_dt, 0.0, 1.0, unit="s (0: off)")
        slow_speed = real("slow_speed", slow_speed, 0.0, 1e3, hi_open=True, unit="cm/s")
        warm_start = flag("warm_start", warm_start)
        friction_resolve = flag("friction_resolve", friction_resolve)
        strain_iters = integer("strain_iters", strain_iters, 1, 1000)
        if max_travel is not None and not (isinstance(max_travel, str) and max_travel == "auto"):
            max_travel = float(real("max_travel", max_travel, 0.0, 100.0, lo_open=True,
                                    unit="lattice spacings (None: off; \"auto\")"))
        self.max_travel = max_travel
        self.strain_limit_percent = None if strain_limit_percent is None else float(strain_limit_percent)
        self.strain_iters = strain_iters
        self.max_dt = float(max_dt)
        self.tol = float(tol)
        self.vtol = float(vtol)
        self.max_iter = int(max_iter)
        self.preconditioner = preconditioner
        self.max_speed = float(max_speed)
        self.max_strain_percent = max_strain_percent
        self.scheme = scheme
        self.newton_iters = newton_iters
        self._no_history = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(1, dtype=np.int64))
        # derived from the model alone (its lattice levels and packed arrays), rebuilt for another model;
        # everything carried from call to call lives in the state (State.solver)
        self._levels: tuple[Model, Level, dict] | None = None
        self.last_stats = np.zeros((0, 2))
        self.sleep_speed = float(sleep_speed)
        self.slow_dt = float(slow_dt)
        self.slow_speed = float(slow_speed)
        self.slow = False  # did the last call take slow_dt substeps?
        self.warm_start = warm_start
        self.friction_resolve = friction_resolve
        self.asleep = False  # did the last call find the cloth asleep?

    # ------------------------------------------------------------------ substeps
    def substeps_for(self, model: Model, dt: float) -> int:
        """Number of equal substeps ``step`` uses for a step of ``dt`` seconds."""
        dt = check_dt("dt", dt)
        return max(1, check_steps("dt", math.ceil(dt / self.max_dt * (1 - 1e-12))))

    def _step_substeps(self, model: Model, state: State, dt: float, n: int, context) -> int:
        """``step``'s substeps: ``slow_dt`` ones for a slow cloth (:attr:`slow`), then more where
        ``max_travel`` asks for them."""
        quiet, last = context
        self.slow = self.slow_dt > self.max_dt and last and state.solver.quiet_slow
        if self.slow:
            n = max(1, int(math.ceil(dt / self.slow_dt * (1 - 1e-12))))
        travel = self.travel_limit(model)
        if travel is not None:
            n = max(n, self._travel_substeps(model, state, dt, travel))
        return n

    def travel_limit(self, model: Model) -> float | None:
        """Lattice spacings a free particle may travel in one substep of ``model`` (None: no limit):
        ``max_travel``, with ``"auto"`` resolved by the model's self-collision."""
        if self.max_travel == "auto":
            return AUTO_MAX_TRAVEL if model.collision.self_collision else None
        return self.max_travel

    def _travel_substeps(self, model: Model, state: State, dt: float, travel: float) -> int:
        """Substeps that keep the fastest free particle within ``travel`` lattice spacings per
        substep: its speed at the start of the call plus what gravity adds over ``dt``."""
        _, _, free_sq = fastest(state.particle_qd, model.particle_inv_mass)  # checked finite by SolverBase
        if free_sq < 0.0:  # no free particle
            return 1
        speed = math.sqrt(free_sq) + float(np.linalg.norm(model.gravity)) * dt
        return check_steps("dt", max(1, math.ceil(speed * dt / (travel * model.sigma))))

    # ------------------------------------------------------------------ preconditioner and levels
    def preconditioner_for(self, model: Model, dt: float | None = None) -> str:
        """The preconditioner used on ``model`` for substeps of ``dt`` s (default ``max_dt``):
        ``"auto"`` resolved by the lattice and the step — the band factor while its cost
        ``3N·(3w + 3)²`` stays below ``AUTO_BAND_WORK``, multigrid from
        ``AUTO_MULTIGRID_PARTICLES`` particles unless the step is small enough for lines
        (``AUTO_LINES_STIFFNESS``, ``AUTO_LINES_PARTICLES``), lines between."""
        return self._choose(Level(model), self.max_dt if dt is None else dt)[0]

    def _choose(self, level: Level, h: float) -> tuple[str, tuple[int, int] | None]:
        """:meth:`preconditioner_for` of a level's model at substep ``h``, with the band layout when
        it is the band."""
        if self.preconditioner not in ("auto", "band"):
            return self.preconditioner, None
        if self.preconditioner == "auto" and level.n >= AUTO_MULTIGRID_PARTICLES:
            m = level.model
            number = h * h * float(m.edge_stiffness.max()) / effective_mass(m)
            if level.n < AUTO_LINES_PARTICLES and number < AUTO_LINES_STIFFNESS:
                return "lines", None
            return "multigrid", None
        layout = level.band
        if self.preconditioner == "band" or 3 * level.n * (3 * layout[1] + 3) ** 2 <= AUTO_BAND_WORK:
            return "band", layout
        return "lines", None

    def _hierarchy(self, model: Model, h: float) -> Hierarchy:
        """The levels (and their scratch) for ``model`` at substep ``h``, built once per model and
        preconditioner (the model itself is the key: an id could be reused)."""
        if self._levels is None or self._levels[0] is not model:
            self._levels = (model, Level(model), {})
        fine, built = self._levels[1], self._levels[2]
        choice, band = self._choose(fine, h)
        if choice not in built:
            built[choice] = build_hierarchy(fine, choice == "multigrid", band)
        return built[choice]

    # ------------------------------------------------------------------ what the state carries
    def _contacts_of(self, model, state):
        """Per-particle obstacle touched in the last step (−1: none), from the state's memory when it
        was written at the state's current step; else the contacts the positions are in (a cloth
        laid on a table rests on it from its first step)."""
        mem = state.solver
        n = model.particle_count
        if mem.contacts is None or mem.contacts_step != state.step or mem.contacts.shape != (n,):
            mem.contacts = -np.ones(n, dtype=np.int64)
            types, params, _ = model.obstacle_arrays
            if types.shape[0]:
                off = state.obstacle_offset
                prm = params if off is None or off.shape != (types.shape[0], 3) else moved_obstacles(params, off)
                resting_contacts(state.particle_q, types, prm, float(model.contact_thickness), mem.contacts)
        return mem.contacts

    def _bdf2_history(self, model, state, h):
        """(x₋₁, v₋₁, ok) for BDF2, from the state's memory while it continues the step it was
        written at with the same h; otherwise fresh arrays with ok = 0 (a backward-Euler start)."""
        mem = state.solver
        n = model.particle_count
        if self.scheme != "bdf2":  # unused by backward Euler: one set of placeholders, not three arrays per call
            if self._no_history[0].shape[0] != n:
                self._no_history = (np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(1, dtype=np.int64))
            return self._no_history
        if (mem.bdf2_x is not None and mem.bdf2_step == state.step and mem.bdf2_h == h
                and mem.bdf2_x.shape == (n, 3)):
            return mem.bdf2_x, mem.bdf2_v, np.ones(1, dtype=np.int64)
        return np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(1, dtype=np.int64)

    def _warm_guess(self, model, state, h):
        """(Δv, ok) the first solve of this call starts from: the last step's velocity change from the
        state's memory (scaled to this call's h) when it was written at the current step."""
        mem = state.solver
        n = model.particle_count
        if (self.warm_start and mem.warm_dv is not None and mem.warm_step == state.step
                and mem.warm_dv.shape == (n, 3)):
            return mem.warm_dv * (h / mem.warm_h), np.ones(1, dtype=np.int64)
        return np.zeros((n, 3)), np.zeros(1, dtype=np.int64)

    def _quiet(self, control) -> bool:
        """Inputs that cannot wake a cloth at rest: no kinematic particle, no wind, no moving obstacle."""
        return control is None or not ((control.kinematic is not None and np.any(control.kinematic))
                                       or np.any(np.asarray(control.wind) != 0.0)
                                       or (control.obstacle_velocity is not None
                                           and np.any(np.asarray(control.obstacle_velocity) != 0.0)))

    def _call_context(self, model, state, control) -> tuple[bool, bool]:
        """(quiet, last): are the inputs quiet (when sleeping or slow substeps could use them), and
        does this call continue the quiet call recorded in the state's memory (no step since,
        positions untouched)."""
        quiet = (self.sleep_speed > 0.0 or self.slow_dt > 0.0) and self._quiet(control)
        mem = state.solver
        last = (quiet and mem.quiet_q is not None and mem.quiet_step == state.step
                and np.array_equal(mem.quiet_q, state.particle_q))
        return quiet, last

    # ------------------------------------------------------------------ the run
    def _run(self, model, state, control, n, h, context) -> ImplicitStepInfo:
        """``n`` substeps of ``h`` s (:meth:`_retrying`); with ``refine_strain_rise``, a call whose
        strain jumps by more than that, or that diverges, is run again from its start with
        :data:`REFINE_FACTOR` times the substeps."""
        self.refined = False
        if self.refine_strain_rise is None:
            return self._retrying(model, state, control, n, h, context)
        before = edge_strain(model, state)
        start = state.copy()
        try:
            info = self._retrying(model, state, control, n, h, context)
            if not np.any(edge_strain(model, state) - before > self.refine_strain_rise):
                return info
        except SimulationDiverged:
            pass
        state.restore(start)
        self.refined = True
        return self._retrying(model, state, control, n * REFINE_FACTOR, h / REFINE_FACTOR, context)

    def _retrying(self, model, state, control, n, h, context) -> ImplicitStepInfo:
        """``n`` substeps of ``h`` s (:meth:`_run_once`); with ``retry_diverged``, a run that diverges
        is run again from the call's start with :data:`RETRY_NEWTON`."""
        self.retried = False
        if not self._retries():
            return self._run_once(model, state, control, n, h, context, False)
        start = state.copy()
        try:
            return self._run_once(model, state, control, n, h, context, False)
        except SimulationDiverged:
            state.restore(start)
            self.retried = True
        try:
            return self._run_once(model, state, control, n, h, context, True)
        except SimulationDiverged as err:
            raise SimulationDiverged(err.step, err.time_s, err.particle, err.reason, err.value, RETRIED_HINT) from None

    def _retries(self) -> bool:
        """Does a diverged call get run again: ``retry_diverged``, and Newton's own settings less
        converged than :data:`RETRY_NEWTON`'s."""
        converged = (self.newton_iters >= RETRY_NEWTON["newton"].passes and self.line_search
                     and 0.0 < self.newton_tol <= RETRY_NEWTON["newton_tol"])
        return self.retry_diverged and not converged

    def _run_once(self, model, state, control, n, h, context, converge: bool) -> ImplicitStepInfo:
        """``n`` substeps of ``h`` s: the cloth's sleep (if asleep), the kernel's run over the state
        (its Newton passes those of :data:`RETRY_NEWTON` if ``converge``), what the state carries to
        the next call, and the divergence error if the run stopped."""
        quiet, last = context
        mem = state.solver
        self.asleep = False
        # the last call on this state was slow enough to sleep, and nothing moved the cloth since
        slow_before = last and mem.quiet_sleepy
        if slow_before and mem.asleep and not np.any(state.particle_qd):  # asleep, velocities untouched
            return self._sleep_through(state, n, h)
        mem.quiet_q = None
        x_start = state.particle_q.copy() if quiet else None
        hier = self._hierarchy(model, h)
        hx, hv, ok = self._bdf2_history(model, state, h)
        warm_dv, warm_ok = self._warm_guess(model, state, h)
        stats = np.zeros((n, 3))
        status, s, p, value = self._timed(
            run_implicit, n, h, state.particle_q, state.particle_qd,
            model.particle_inv_mass if control is None else control.inv_mass(model),
            np.zeros(3) if control is None else np.asarray(control.wind, dtype=float), stats,
            self._solve_options(hier, converge), self._guard(model), Carry(hx, hv, ok, warm_dv, warm_ok),
            model.force_data, make_world(model, state, control, self._contacts_of(model, state)), hier.levels_data,
            hier.work)
        status = Status(status)
        done = n if status == Status.OK else s + 1
        state.step += done
        state.time += done * h
        ok_run = status == Status.OK
        if ok_run and self.scheme == "bdf2" and ok[0] == 1:
            mem.bdf2_x, mem.bdf2_v, mem.bdf2_h, mem.bdf2_step = hx, hv, h, state.step
        else:
            mem.bdf2_x = mem.bdf2_v = None
        mem.contacts_step = state.step if ok_run else -1
        if ok_run and self.warm_start and warm_ok[0] == 1:
            mem.warm_dv, mem.warm_h, mem.warm_step = warm_dv, h, state.step
        else:
            mem.warm_dv = None
        self.last_stats = stats[:done]
        if quiet and ok_run:
            self._note_quiet(state, x_start, n * h, slow_before)
        if not ok_run:
            self._raise_diverged(state, status, p, value)
        return ImplicitStepInfo.of(stats, h)

    def _sleep_through(self, state: State, n: int, h: float) -> ImplicitStepInfo:
        """A call that finds the cloth asleep: only the time advances."""
        mem = state.solver
        contacts_valid = mem.contacts is not None and mem.contacts_step == state.step
        state.step += n
        state.time += n * h
        mem.quiet_step = state.step
        mem.quiet_slow, mem.quiet_sleepy, mem.asleep = False, True, True
        mem.bdf2_x = mem.bdf2_v = None
        if contacts_valid:
            mem.contacts_step = state.step
        self.last_stats = np.zeros((n, 3))
        self.asleep = True
        self._profile = (np.zeros(PROFILE_SIZE, dtype=np.int64), 0.0)
        return ImplicitStepInfo(n, h, 0, 0.0, 0.0, 0.0)

    def _solve_options(self, hier: Hierarchy, converge: bool = False) -> SolveOptions:
        """The kernel's settings; with ``converge``, Newton's those of :data:`RETRY_NEWTON`."""
        precond = Precond.JACOBI if self.preconditioner == "jacobi" else (hier.band_code or Precond.LINES)
        levels = hier.levels_data.n_levels
        family = Band(levels) if hier.band_code else (Multigrid(levels) if levels > 1 else OneLevel(levels))
        opts = SolveOptions(self.tol, self.vtol, self.max_iter, int(precond), _SMOOTH_DAMPING, self.scheme == "bdf2",
                            newton_kind(self.newton_iters), self.warm_start, self.friction_resolve, self.newton_tol,
                            self.momentum_exact, self.newton_tol_max, self.line_search, family,
                            self.couple_collisions)
        if converge:
            opts = opts._replace(**RETRY_NEWTON)
        return opts

    def _guard(self, model: Model) -> Guard:
        """The divergence thresholds and the strain limiter of a call on ``model``."""
        max_strain = strain_guard(model, self.max_strain_percent)
        if self.strain_limit_percent is not None and self.strain_limit_percent >= max_strain:
            raise ConfigError("strain_limit_percent", f"{self.strain_limit_percent:g} % must be below the strain guard "
                              f"{max_strain:g} % (max_strain_percent, or the model's: the limiter would never act "
                              f"before the step diverges)")
        if self.strain_limit_percent is None:
            return Unlimited(self.max_speed, max_strain, 0.0, self.strain_iters)
        return Guard(self.max_speed, max_strain, self.strain_limit_percent / 100.0, self.strain_iters)

    def _note_quiet(self, state: State, x_start: np.ndarray, duration: float, slow_before: bool) -> None:
        """After a quiet call of ``duration`` s: record it in the state's memory if no particle moved
        faster than ``slow_speed`` or ``sleep_speed`` on average, and put the cloth to sleep (its
        velocities zeroed) on the second such call in a row below ``sleep_speed``."""
        mem = state.solver
        d = state.particle_q - x_start
        d2max = float(np.einsum("ij,ij->i", d, d).max(initial=0.0))
        below_slow = self.slow_dt > 0.0 and d2max < (self.slow_speed * duration) ** 2
        below_sleep = d2max < (self.sleep_speed * duration) ** 2
        if below_sleep and slow_before:
            # the second slow call in a row: the cloth falls asleep, at rest
            state.particle_qd[:] = 0.0
        if below_slow or below_sleep:
            mem.quiet_q, mem.quiet_step = state.particle_q.copy(), state.step
            mem.quiet_slow, mem.quiet_sleepy = bool(below_slow), bool(below_sleep)
            mem.asleep = bool(below_sleep and slow_before)

    @staticmethod
    def _raise_diverged(state: State, status: Status, p: int, value: float):
        """:class:`~cloth_gym.errors.SimulationDiverged` for a run that stopped with ``status``; a
        matrix that was not SPD names the first non-finite particle if there is one."""
        if status == Status.NOT_SPD:
            bad = ~(np.isfinite(state.particle_q).all(axis=1) & np.isfinite(state.particle_qd).all(axis=1))
            if bad.any():
                raise SimulationDiverged(state.step, state.time, int(np.argmax(bad)), "non-finite", math.nan,
                                         IMPLICIT_HINT)
            raise SimulationDiverged(state.step, state.time, -1, DIVERGE_REASONS[status], math.nan)
        raise SimulationDiverged(state.step, state.time, p, DIVERGE_REASONS[status], value, IMPLICIT_HINT)
