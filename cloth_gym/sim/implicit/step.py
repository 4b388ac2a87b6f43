"""The implicit step as a list of named stages (see :mod:`cloth_gym.sim.implicit`).

Each (sub)step of ``h`` seconds, in order (:func:`run_implicit`):

1. :func:`evaluate_forces` — every force at the start of the step;
2. :func:`prepare` — lumped mass (with absolute damping and air drag's linearisation) and the
   obstacle contacts' constraints and friction dampers;
3. :func:`assemble` — the stiffness blocks of H and the preconditioner's set-up;
4. :func:`right_hand_side` — ``h·(f − h·H·v)`` (BDF2: with its history terms);
5. :func:`first_solve` — PCG for the velocity change Δv (warm-started), its momentum balance made
   exact in free flight (:func:`exact_momentum`);
6. :func:`friction_resolve` — the solve again where friction's dampers were too weak;
7. :func:`newton_passes` — further Newton passes (``SolveOptions.n_newton`` > 1) until the next
   correction is within ``SolveOptions.newton_tol``;
8. :func:`update` — ``v += Δv``, ``x += h·v``;
9. :func:`~cloth_gym.sim.substep.finish_substep` — obstacles, strain limiter, collision pass and
   the divergence check, shared with the explicit integrator; with ``SolveOptions.couple_collisions``
   :func:`coupled_finish`, where each collision pass is followed by the step's solve again with the
   particles the pass moved held where it put them (:func:`couple_collision_response`,
   :func:`coupled_newton`), until a pass moves nothing.

Every stage adds its time to its :class:`~cloth_gym.sim.bundles.Phase` of the profile; the
band preconditioner's lazy factorisation is counted under FACTOR wherever it happens.

The stages, and the loop over steps, are inlined into :func:`run_implicit` (``inline="always"``:
numba types them into their caller's IR) rather than compiled as kernels of their own: numba
optimises each kernel's module again with every callee linked into it, so each layer of separate
kernels would pay again for the layers below it (docs/cli.md, "Where the first run's CPU goes").
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from numba.extending import overload

from .._numba import NJIT_FLAGS, cycles, njit, runtime
from ..bundles import (N_PHASES, P_ASSEMBLY, P_COLLISION, P_FACTOR, P_FORCES, P_FRICTION, P_NEWTON, P_PREPARE,
                       P_RHS, P_SOLVE, NoCollisionPass, Status)
from ..collision_kernels import COLLISION_PASS_BITS, run_collision_pass
from ..forces import (AIR, DAMPING, STRAIN_DAMPING, air_linearisation, eval_forces, eval_forces_at,
                      eval_strain_damping, lumped_mass)
from ..obstacles import signed_distance
from ..substep import closing_stage, finish_substep, needs_previous_positions, obstacle_stage
from .bundles import BAND_WARP, CGWork, Matrix
from .cg import filtered_pcg, free_mass, residual_norm2
from .contact import FRICTION_PASSES, contact_constraints, filter_vec, friction_force, refine_friction
from .matrix import apply_H, implicit_rhs, matvec_A
from . import precondition as pc
from .multigrid import level_matrix


class StepWork(NamedTuple):
    """What the stages of one run share: per-particle scratch, overwritten every step, and views
    of the level-0 parts of :class:`~cloth_gym.sim.implicit.bundles.Work`. Arrays are (N, 3) in the
    units of what they hold unless said otherwise."""

    f: np.ndarray  # forces, dyne
    normals: np.ndarray  # particle normals (air drag)
    drag: np.ndarray  # (N,) air drag's linearisation, g/s
    rhs: np.ndarray  # the right-hand side, g·cm/s
    dv: np.ndarray  # the velocity change Δv, cm/s
    cg: CGWork  # PCG's vectors
    cfric: np.ndarray  # (N,) friction dampers, g/s
    fmax: np.ndarray  # (N,) the largest friction force each contact may exert, dyne
    con: np.ndarray  # (N,) int8 constrained directions per particle (contact)
    cn: np.ndarray  # contact normals
    x_prev: np.ndarray  # positions at the start of the step (collision pass), cm
    dxh: np.ndarray  # BDF2: ⅓(x − x₋₁), cm
    tmp: np.ndarray  # scratch: BDF2's history product, Newton's filtered residual
    xk: np.ndarray  # Newton: the current estimate's positions, cm
    vk: np.ndarray  # ... and velocities, cm/s
    dv_k: np.ndarray  # Newton: the estimate a correction is added to, cm/s
    delta: np.ndarray  # Newton's line search: the correction, cm/s
    ffric: np.ndarray  # friction at the Newton estimate, dyne
    hist_v_old: np.ndarray  # BDF2: v₋₁ of this step (the carry already holds this step's v)
    md_before: np.ndarray  # (N,) the lumped mass before the friction re-solve raised it, g
    stale: np.ndarray  # (1,) int64: the band factor is to be rebuilt before its next use (1), not SPD (2)
    free: np.ndarray  # (N,) bool: free particles (Work.free, level 0)
    md: np.ndarray  # (N,) the lumped mass with damping and drag, g (Work.mdiag, level 0)
    H: Matrix  # level 0's stiffness
    bslot: np.ndarray  # (N,) each particle's slot in the band's line order
    x_pass: np.ndarray  # positions before the collision pass (couple_collisions), cm
    con_saved: np.ndarray  # (N,) int8: the contact constraints while the coupling holds particles
    v_start: np.ndarray  # velocities at the start of the step (couple_collisions), cm/s


@njit
def step_work(inv_mass, opts, lv, ws) -> StepWork:
    """The :class:`StepWork` of a run on ``N = inv_mass.shape[0]`` particles (free: ``inv_mass`` > 0)."""
    n = inv_mass.shape[0]
    fr = ws.free[0:n]
    for q in range(n):
        fr[q] = inv_mass[q] > 0.0
    bslot = lv.lw_slot[0:n] if opts.precond == BAND_WARP else lv.lf_slot[0:n]
    cg = CGWork(np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)))
    return StepWork(np.empty((n, 3)), np.empty((n, 3)), np.zeros(n), np.empty((n, 3)), np.empty((n, 3)), cg,
                    np.zeros(n), np.zeros(n), np.zeros(n, dtype=np.int8), np.zeros((n, 3)), np.empty((n, 3)),
                    np.zeros((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)),
                    np.empty((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.empty(n), np.zeros(1, dtype=np.int64), fr,
                    ws.mdiag[0:n], level_matrix(0, lv, ws), bslot,
                    np.empty((n, 3) if opts.couple_collisions else (0, 3)), np.zeros(n, dtype=np.int8),
                    np.empty((n, 3) if opts.couple_collisions else (0, 3)))


@njit
def run_implicit(n_steps, h, x, v, inv_mass, wind, stats, opts, guard, carry, fd, world, lv, ws, prof):
    """``n_steps`` backward-Euler (or BDF2) steps of ``h`` s (see :mod:`cloth_gym.sim.implicit`).

    ``x``, ``v`` (N, 3): positions (cm) and velocities (cm/s), advanced in place; ``inv_mass`` (N,)
    1/g, 0 for pinned and kinematic particles; ``wind`` (3,) cm/s. ``stats`` (n_steps, 3) gets (CG
    iterations, relative residual, linear solves: 1 + Newton corrections) per step. ``opts``: :class:`SolveOptions`; ``guard``:
    :class:`~cloth_gym.sim.bundles.Guard`; ``carry``: :class:`Carry` (with ``opts.bdf2`` the steps
    are BDF2 once its history is set; the first step is backward Euler, which sets it); ``fd``:
    :class:`~cloth_gym.sim.bundles.ForceData`; ``world``: :class:`~cloth_gym.sim.bundles.World`;
    ``lv``, ``ws``: :class:`Levels` and their :class:`Work`.

    ``prof`` (N_PHASES + 1,) int64: the phase profile, cycle counts per
    :class:`~cloth_gym.sim.bundles.Phase` and of the whole call, added to.

    Returns (status, step, particle, value): a :class:`~cloth_gym.sim.bundles.Status` code
    (NOT_SPD: the coarsest-level or band matrix was not positive definite), the step it happened
    at, and the particle and value it concerns."""
    start = cycles()
    out = _implicit_steps(n_steps, h, x, v, inv_mass, wind, stats, opts, guard, carry, fd, world, lv, ws, prof)
    prof[N_PHASES] += cycles() - start
    return out


@njit(inline="always")
def _implicit_steps(n_steps, h, x, v, inv_mass, wind, stats, opts, guard, carry, fd, world, lv, ws, prof):
    """The body of :func:`run_implicit`: the stages of the module docstring, step after step."""
    sw = step_work(inv_mass, opts, lv, ws)
    contacts = world.obstacles.types.shape[0] > 0
    keep_prev = needs_previous_positions(world)
    vt_pairs = np.zeros((0, 2), dtype=np.int64)  # self-collision pair lists, kept across steps
    ee_pairs = np.zeros((0, 2), dtype=np.int64)
    ref_x = np.full((x.shape[0] if (world.collision.flags & COLLISION_PASS_BITS) != 0 else 0, 3), np.inf)
    for s in range(n_steps):
        # BDF2 once its history is set: the same system with β = 2h/3 in place of h
        use2 = opts.bdf2 and carry.ok[0] == 1
        heff = 2.0 * h / 3.0 if use2 else h
        evaluate_forces(x, v, wind, fd, sw, prof)
        prepare(x, v, wind, heff, fd, world, contacts, sw, prof)
        if not assemble(x, heff, opts, fd, lv, ws, sw, prof):
            return Status.NOT_SPD, s, -1, math.nan
        right_hand_side(x, v, heff, use2, opts, fd, carry, sw, prof)
        it, rel = first_solve(heff, opts, carry, lv, ws, sw, prof)
        ok, it2, rel = friction_resolve(x, v, heff, opts, fd, world, contacts, lv, ws, sw, prof, rel)
        if not ok:
            return Status.NOT_SPD, s, -1, math.nan
        ok, it3, rel, passes = newton_passes(x, v, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, prof,
                                             rel)
        if not ok or sw.stale[0] == 2:  # a coarse or the band matrix was not SPD (non-finite state)
            return Status.NOT_SPD, s, -1, math.nan
        stats[s, 0] = it + it2 + it3
        stats[s, 1] = rel
        stats[s, 2] = 1 + passes
        if opts.warm_start:
            carry.dv[:] = sw.dv
            carry.dv_ok[0] = 1
        if keep_prev:
            sw.x_prev[:] = x
        coupled = opts.couple_collisions and (world.collision.flags & COLLISION_PASS_BITS) != 0
        if coupled:
            sw.v_start[:] = v
        update(x, v, heff, use2, sw)
        if coupled:
            status, pp, value, vt_pairs, ee_pairs, itc = coupled_finish(x, v, inv_mass, wind, heff, use2, opts, fd,
                                                                        world, contacts, guard, lv, ws, sw, vt_pairs,
                                                                        ee_pairs, ref_x, prof)
            stats[s, 0] += itc
        else:
            status, pp, value, vt_pairs, ee_pairs = finish_substep(x, v, sw.x_prev, inv_mass, heff, fd, world,
                                                                   guard, vt_pairs, ee_pairs, ref_x, prof)
        if status != Status.OK:
            return status, s, pp, value
    return Status.OK, n_steps, -1, 0.0


@njit(inline="always")
def evaluate_forces(x, v, wind, fd, sw, prof):
    """Every force at ``(x, v)`` into ``sw.f`` (dyne) but strain-rate damping: the assembled matrix
    is H + C/β, whose product −β²(H + C/β)·v in the right-hand side applies it (and C's implicit
    part)."""
    t0 = cycles()
    eval_forces_at(x, v, wind, fd, sw.normals, sw.f, runtime(False))
    prof[P_FORCES] += cycles() - t0


@njit(inline="always")
def prepare(x, v, wind, heff, fd, world, contacts, sw, prof):
    """The lumped mass ``sw.md`` (g: mass, absolute damping and air drag's linearisation, each
    times its share of ``heff``) and the obstacle contacts' constraints (``sw.con``, ``sw.cn``)
    and friction dampers (``sw.cfric``)."""
    t0 = cycles()
    if (fd.flags & AIR) != 0:
        air_linearisation(x, v, fd.tris, wind, fd.c_air, fd.area, sw.normals, sw.drag)
    lumped_mass(fd.mass, fd.damping_rate, (fd.flags & DAMPING) != 0, sw.drag, heff, sw.md)
    if contacts:
        contact_constraints(x, v, sw.f, world, fd.mass, heff, sw.cn, sw.con, sw.cfric, sw.md, sw.free, sw.fmax)
    prof[P_PREPARE] += cycles() - t0


@njit(inline="always")
def assemble(x, heff, opts, fd, lv, ws, sw, prof):
    """The stiffness blocks of H + C/β on every level and the preconditioner's set-up (the band
    factor is marked stale and built on first use). False if a coarse matrix is not SPD."""
    t0 = cycles()
    sw.stale[0] = 1
    ok = pc.setup(opts.family, x, heff * heff, opts.precond, fd, lv, ws, sw.con, sw.cn, runtime(True))
    prof[P_ASSEMBLY] += cycles() - t0
    return ok


@njit(inline="always")
def right_hand_side(x, v, heff, use2, opts, fd, carry, sw, prof):
    """``sw.rhs``: backward Euler's ``β·f − β²·(H + C/β)·v``; BDF2 (β = 2h/3) adds
    ``⅓M(v − v₋₁) − β·(H·dxh − C·dxh/β)`` with ``dxh = ⅓(x − x₋₁)``, the update
    ``x₊₁ = x + dxh + β·v₊₁``. Then this step's (x, v) become BDF2's history in ``carry``."""
    t0 = cycles()
    n = x.shape[0]
    fr = sw.free
    implicit_rhs(sw.f, v, heff, sw.H, fr, sw.rhs)
    if use2:
        for q in range(n):
            for i in range(3):
                sw.dxh[q, i] = (x[q, i] - carry.x[q, i]) / 3.0
        apply_H(sw.dxh, sw.H, sw.tmp)  # (H + C/β)·dxh; the history term takes H·dxh alone
        if (fd.flags & STRAIN_DAMPING) != 0:
            sw.dv_k[:] = 0.0
            eval_strain_damping(x, sw.dxh, fd, sw.dv_k)  # −C·dxh
            for q in range(n):
                for i in range(3):
                    sw.tmp[q, i] += sw.dv_k[q, i] / heff
        for q in range(n):
            if fr[q]:
                for i in range(3):
                    sw.rhs[q, i] += fd.mass[q] * (v[q, i] - carry.v[q, i]) / 3.0 - heff * sw.tmp[q, i]
        sw.hist_v_old[:] = carry.v
    if opts.bdf2:
        carry.x[:] = x
        carry.v[:] = v
        carry.ok[0] = 1
    prof[P_RHS] += cycles() - t0


@njit(inline="always")
def first_solve(heff, opts, carry, lv, ws, sw, prof):
    """PCG for Δv (``sw.dv``), from the last step's Δv when warm-started. Returns (iterations,
    relative residual)."""
    t0 = cycles()
    warm = opts.warm_start and carry.dv_ok[0] == 1
    if warm:
        sw.dv[:] = carry.dv
    factored = prof[P_FACTOR]
    it, rel = filtered_pcg(warm, sw.rhs, sw.dv, sw.cg, opts, heff * heff, sw.free, sw.con, sw.cn, sw.md, lv, ws,
                           sw.stale, sw.bslot, prof)
    if opts.momentum_exact:
        exact_momentum(sw.rhs, sw.dv, sw.md, sw.free, sw.con)
    prof[P_SOLVE] += cycles() - t0 - (prof[P_FACTOR] - factored)
    return it, rel


@njit
def exact_momentum(rhs, dv, md, free, con):
    """In free flight (every particle free, no obstacle constraint), add to Δv the uniform velocity
    that makes the solve's momentum balance exact, ``Σ m̃_q Δv_q = Σ b_q`` (g·cm/s): the internal
    forces' matrix H + C/β annihilates a uniform velocity, so the exact solution of
    ``(M̃ + β²H)Δv = b`` satisfies it, and an inexact CG iterate is off by its residual's sum. Only
    the momentum (the centre of mass's motion) changes, by that residual; the cloth's shape does
    not. With a pinned, held or touching particle, momentum is not conserved and nothing is done."""
    n = dv.shape[0]
    for q in range(n):
        if not free[q] or con[q] != 0:
            return
    msum = 0.0
    for q in range(n):
        msum += md[q]
    if msum <= 0.0:
        return
    for i in range(3):
        gap = 0.0
        for q in range(n):
            gap += rhs[q, i] - md[q] * dv[q, i]
        c = gap / msum
        if not math.isfinite(c):  # a non-finite state: leave it where it is, for the check to name
            return
        for q in range(n):
            dv[q, i] += c


@njit(inline="always")
def friction_resolve(x, v, heff, opts, fd, world, contacts, lv, ws, sw, prof, rel):
    """Up to FRICTION_PASSES re-solves, from the first solve's Δv, with the friction dampers raised
    where the first solve left a particle sliding more slowly than its damper assumed
    (:func:`~cloth_gym.sim.implicit.contact.refine_friction`). Returns (ok, iterations, relative
    residual); ok is False if a refreshed coarse matrix is not SPD."""
    if not (contacts and opts.friction_resolve):
        return True, 0, rel
    t0 = cycles()
    factored = prof[P_FACTOR]
    it = 0
    h2 = heff * heff
    resolve_warm = runtime(True)
    for _ in range(FRICTION_PASSES):
        sw.md_before[:] = sw.md
        if not refine_friction(v, sw.dv, sw.con, sw.cn, sw.cfric, sw.fmax, world.touching, world.vel, heff, sw.md,
                               sw.rhs):
            break
        if not pc.refresh(opts.family, x, h2, opts.precond, fd, lv, ws, sw.con, sw.cn, sw.md, sw.md_before, sw.stale):
            return False, it, rel
        it2, rel = filtered_pcg(resolve_warm, sw.rhs, sw.dv, sw.cg, opts, h2, sw.free, sw.con, sw.cn, sw.md, lv, ws,
                                sw.stale, sw.bslot, prof)
        it += it2
    prof[P_FRICTION] += cycles() - t0 - (prof[P_FACTOR] - factored)
    return True, it, rel


@njit(inline="always")
def newton_passes(x, v, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, prof, rel):
    """Newton passes 2 … ``opts.n_newton``: the residual ``−g(Δv) = β·f(x_k, v_k) − M·Δv`` (plus
    ⅓M(v − v₋₁) for BDF2, and friction at v_k) at the current estimate ``(x_k, v_k)``, filtered as
    the solve sees it (:func:`newton_residual`). Converged, and no further pass, once the
    correction δ that would follow has a mass-weighted RMS ``√(Σ m̃_q|δ_q|² / Σ m̃_q)`` within
    ``opts.newton_tol`` (cm/s), and with ``opts.newton_tol_max`` every ``|δ_q|`` within that:
    known before solving when the residual's ``Σ|g_q|²/m̃_q`` is small enough (A ≥ M̃ bounds δ by
    it: a quiet or rigidly carried cloth stops before its second assembly), else after the
    correction is solved (H assembled at the estimate, solved from 0) and added. With
    ``opts.line_search`` a correction that is not yet small is taken as ``α·δ``, α halved from 1
    (at most LINE_SEARCH_HALVINGS times) until the residual's ``Σ|g_q|²/m̃_q`` falls by the
    factor ``1 − α/2`` (:func:`line_search`). Returns (ok, iterations, relative residual of the
    last solve, correction solves taken)."""
    if opts.n_newton <= 1:
        return True, 0, rel, 0
    t0 = cycles()
    factored = prof[P_FACTOR]
    n = x.shape[0]
    fr = sw.free
    h2 = heff * heff
    it = 0
    passes = 0  # correction solves taken
    from_zero = not runtime(True)
    floor2 = opts.newton_tol * opts.newton_tol * free_mass(sw.md, fr) if opts.newton_tol > 0.0 else 0.0
    # the per-particle test: Σ|g|²/m̃ ≤ min m̃ · tol_max² bounds every |δ_q| by tol_max before solving
    max2 = opts.newton_tol_max * opts.newton_tol_max
    floor2_max = max2 * min_free_mass(sw.md, fr) if max2 > 0.0 else math.inf
    phi, ready = 0.0, False  # the residual at sw.dv, and whether sw.rhs and sw.tmp hold it
    for _ in range(1, opts.n_newton):
        if not ready:
            phi = newton_residual(x, v, sw.dv, wind, heff, use2, fd, world, contacts, sw)
        ready = False
        if floor2 > 0.0 and phi <= min(floor2, floor2_max):
            break
        sw.stale[0] = 1  # the band factor, if used, is rebuilt on demand
        if not pc.setup(opts.family, sw.xk, h2, opts.precond, fd, lv, ws, sw.con, sw.cn, runtime(True)):
            return False, it, rel, passes
        sw.dv_k[:] = sw.dv
        it2, rel = filtered_pcg(from_zero, sw.rhs, sw.dv, sw.cg, opts, h2, fr, sw.con, sw.cn, sw.md, lv, ws,
                                sw.stale, sw.bslot, prof)
        if opts.momentum_exact:
            exact_momentum(sw.rhs, sw.dv, sw.md, fr, sw.con)
        it += it2
        passes += 1
        small = below_floor_velocity(sw.dv, sw.md, floor2)  # the correction itself within newton_tol
        if small and max2 > 0.0:
            small = largest_square(sw.dv) <= max2
        if small or not opts.line_search:
            for q in range(n):
                for i in range(3):
                    sw.dv[q, i] += sw.dv_k[q, i]
            if small:
                break
        else:
            phi = line_search(x, v, wind, heff, use2, fd, world, contacts, sw, phi)
            ready = True
    prof[P_NEWTON] += cycles() - t0 - (prof[P_FACTOR] - factored)
    return True, it, rel, passes


#: the line search's largest number of step halvings (α ≥ 1/16)
LINE_SEARCH_HALVINGS = 4


@njit(inline="always")
def line_search(x, v, wind, heff, use2, fd, world, contacts, sw, phi0):
    """Backtracking on the Newton correction: ``sw.dv`` holds δ and ``sw.dv_k`` the estimate it
    corrects; leaves ``sw.dv = dv_k + α·δ`` for the first α = 1, ½, … whose residual
    ``φ(α) = Σ|g_q|²/m̃_q`` is at most ``(1 − α/2)·phi0`` (Armijo's test on ½‖g‖², slope −2φ₀ along
    a Newton direction, with constant ¼), or the smallest α tried, and returns its φ. Its residual
    is left in ``sw.rhs`` for the next pass."""
    n = x.shape[0]
    sw.delta[:] = sw.dv
    alpha = 1.0
    phi = phi0
    for k in range(LINE_SEARCH_HALVINGS + 1):
        for q in range(n):
            for i in range(3):
                sw.dv[q, i] = sw.dv_k[q, i] + alpha * sw.delta[q, i]
        phi = newton_residual(x, v, sw.dv, wind, heff, use2, fd, world, contacts, sw)
        if phi <= (1.0 - 0.5 * alpha) * phi0 or k == LINE_SEARCH_HALVINGS:
            break
        alpha *= 0.5
    return phi


@njit
def newton_residual(x, v, dv, wind, heff, use2, fd, world, contacts, sw):
    """The Newton residual at the estimate ``Δv = dv``: the estimate ``(x_k, v_k)`` into ``sw.xk``,
    ``sw.vk``, ``−g(Δv) = β·(f + f_friction)(x_k, v_k) − M·Δv`` (BDF2: plus ⅓M(v − v₋₁)) into
    ``sw.rhs`` (0 at pinned particles), the same filtered as the solve sees it (constraint reactions
    out) into ``sw.tmp``; returns the filtered residual's ``Σ|g_q|²/m̃_q``."""
    n = x.shape[0]
    fr = sw.free
    for q in range(n):
        for i in range(3):
            sw.vk[q, i] = v[q, i] + (dv[q, i] if fr[q] else 0.0)
            sw.xk[q, i] = x[q, i] + (sw.dxh[q, i] if use2 else 0.0) + heff * sw.vk[q, i]
    eval_forces(sw.xk, sw.vk, wind, fd, sw.normals, sw.f)
    if contacts:
        friction_force(sw.vk, sw.con, sw.cn, sw.cfric, world.touching, world.vel, sw.ffric)
    for q in range(n):
        for i in range(3):
            if fr[q]:
                sw.rhs[q, i] = heff * (sw.f[q, i] + sw.ffric[q, i]) - fd.mass[q] * dv[q, i]
                if use2:
                    sw.rhs[q, i] += fd.mass[q] * (v[q, i] - sw.hist_v_old[q, i]) / 3.0
            else:
                sw.rhs[q, i] = 0.0
    sw.tmp[:] = sw.rhs
    filter_vec(sw.tmp, fr, sw.con, sw.cn)
    return residual_norm2(sw.tmp, sw.md)


#: the most collision passes each followed by the coupling in one substep (then one last pass)
COUPLING_ROUNDS = 4
#: (cm²) a particle the collision pass moved farther than √ of this is held by the coupling
HELD_SHIFT2 = 1.0e-12


@njit(inline="always")
def coupled_finish(x, v, inv_mass, wind, heff, use2, opts, fd, world, contacts, guard, lv, ws, sw, vt_pairs,
                   ee_pairs, ref_x, prof):
    """:func:`~cloth_gym.sim.substep.finish_substep` with the collision response coupled to the
    elastic solve: obstacles and limiter, the rounds of :func:`coupling_rounds`, then the put-back
    and the divergence check. Returns finish_substep's five values and the coupling's PCG
    iterations. Newton's and the band factor's time stay counted under NEWTON and FACTOR only."""
    t0 = cycles()
    obstacle_stage(x, v, sw.x_prev, inv_mass, heff, fd, world, guard)
    t1 = cycles()
    counted = prof[P_NEWTON] + prof[P_FACTOR]
    vt_pairs, ee_pairs, it = coupling_rounds(world.collision, x, v, inv_mass, wind, heff, use2, opts, fd, world,
                                             contacts, lv, ws, sw, vt_pairs, ee_pairs, ref_x, prof)
    status, p, value = closing_stage(x, v, inv_mass, fd, world, guard, t0, t1, cycles(), prof)
    prof[P_COLLISION] -= prof[P_NEWTON] + prof[P_FACTOR] - counted
    return status, p, value, vt_pairs, ee_pairs, it


def coupling_rounds(cd, x, v, inv_mass, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, vt_pairs,
                    ee_pairs, ref_x, prof):
    """At most COUPLING_ROUNDS rounds of the collision pass, :func:`hold_on_obstacles`,
    :func:`couple_collision_response` and :func:`coupled_newton` (in free flight the momentum the
    round added taken back: :func:`keep_momentum`), until a pass moves nothing (else one last
    pass). Returns the pass's pair lists and the PCG iterations. For ``cd`` a
    :class:`~cloth_gym.sim.bundles.NoCollisionPass` nothing, decided while numba types the caller,
    so that a step without a collision pass holds none of this code. Compiled kernels only."""
    raise NotImplementedError("coupling_rounds: callable from compiled kernels only")


def _coupling_rounds(cd, x, v, inv_mass, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, vt_pairs,
                     ee_pairs, ref_x, prof):
    ob = world.obstacles
    it = 0
    for rnd in range(COUPLING_ROUNDS + 1):
        sw.x_pass[:] = x
        vt_pairs, ee_pairs = run_collision_pass(cd, x, v, sw.x_prev, inv_mass, fd.mass, heff, ob.restitution,
                                                ob.thickness, vt_pairs, ee_pairs, ref_x)
        if rnd == COUPLING_ROUNDS:  # the last pass, not coupled
            break
        hold_on_obstacles(x, v, heff, world, sw)
        p0 = momentum(v, fd.mass)
        itc = couple_collision_response(x, v, heff, opts, lv, ws, sw, prof)
        if itc < 0:
            break
        it += itc + coupled_newton(x, v, inv_mass, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, prof)
        if in_flight(sw.free, sw.con_saved, world.touching):
            keep_momentum(x, v, fd.mass, p0, heff, sw.free)
        sw.con[:] = sw.con_saved
    return vt_pairs, ee_pairs, it


@overload(coupling_rounds, jit_options={k: v for k, v in NJIT_FLAGS.items() if k != "cache"})
def _coupling_rounds_for(cd, x, v, inv_mass, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, vt_pairs,
                         ee_pairs, ref_x, prof):
    if getattr(cd, "instance_class", None) is NoCollisionPass:
        return lambda cd, x, v, inv_mass, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, vt_pairs, \
            ee_pairs, ref_x, prof: (vt_pairs, ee_pairs, 0)
    return _coupling_rounds


@njit(inline="always")
def coupled_newton(x, v, inv_mass, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, prof):
    """After :func:`couple_collision_response`: the step's Newton passes (``opts.n_newton`` > 1)
    from the positions the cloth has now, with the particles the collision pass moved held where
    it put them, so the rest of the cloth is solved on the nonlinear forces, not on the step's
    linearisation (which does not see the second-order stretch of an edge that a held particle
    turns). The step's start is ``sw.x_prev``, ``sw.v_start``; the estimate is the Δv that gives
    each particle its present position; afterwards every other free particle takes the solved
    velocity and its position. Returns PCG's iterations."""
    if opts.n_newton <= 1:
        return 0
    n = x.shape[0]
    fr = sw.free
    for q in range(n):
        for i in range(3):
            sw.dv[q, i] = ((x[q, i] - sw.x_prev[q, i] - (sw.dxh[q, i] if use2 else 0.0)) / heff - sw.v_start[q, i]
                           if fr[q] else 0.0)
    ok, it, _, _ = newton_passes(sw.x_prev, sw.v_start, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw,
                                 prof, 0.0)
    if ok:
        for q in range(n):
            if not fr[q] or sw.con[q] == 2:
                continue
            # a particle held along its displacement keeps the pass's velocity along it
            vn = 0.0
            if sw.con[q] == 1 and sw.con_saved[q] == 0:
                for i in range(3):
                    vn += (v[q, i] - sw.v_start[q, i] - sw.dv[q, i]) * sw.cn[q, i]
            for i in range(3):
                x[q, i] = sw.x_prev[q, i] + (sw.dxh[q, i] if use2 else 0.0) + heff * (sw.v_start[q, i] + sw.dv[q, i])
                v[q, i] = sw.v_start[q, i] + sw.dv[q, i] + vn * sw.cn[q, i]
    return it


@njit
def momentum(v, mass):
    """``Σ m_q v_q`` (g·cm/s), as three numbers."""
    p0, p1, p2 = 0.0, 0.0, 0.0
    for q in range(v.shape[0]):
        p0 += mass[q] * v[q, 0]
        p1 += mass[q] * v[q, 1]
        p2 += mass[q] * v[q, 2]
    return p0, p1, p2


@njit
def in_flight(free, con, touching):
    """Every particle free, none constrained by (``con``) or touching an obstacle."""
    for q in range(free.shape[0]):
        if not free[q] or con[q] != 0 or touching[q] >= 0:
            return False
    return True


@njit
def keep_momentum(x, v, mass, p0, heff, free):
    """Take back the momentum the coupling added in free flight: the uniform velocity
    ``(Σ m_q v_q − p0)/Σ m_q`` removed from every particle (and ``heff`` times it from the
    positions), which moves no particle relative to another."""
    p = momentum(v, mass)
    msum = 0.0
    for q in range(v.shape[0]):
        msum += mass[q]
    for i in range(3):
        c = (p[i] - p0[i]) / msum
        for q in range(v.shape[0]):
            if free[q]:
                v[q, i] -= c
                x[q, i] -= heff * c


@njit
def hold_on_obstacles(x, v, heff, world, sw):
    """Undo the part of the collision pass's displacement (from ``sw.x_pass`` to ``x``, cm) that
    pushed a particle resting on an obstacle (``world.touching``) into it, and the velocity that
    went with it (``/heff``): the obstacle carries that push, so a layer of cloth lying on one
    resting on the floor takes the whole separation, over the coupling's rounds."""
    ob = world.obstacles
    for q in range(x.shape[0]):
        k = world.touching[q]
        if k < 0:
            continue
        _, n0, n1, n2 = signed_distance(ob.types[k], world.prm[k], x[q, 0], x[q, 1], x[q, 2])
        dn = (x[q, 0] - sw.x_pass[q, 0]) * n0 + (x[q, 1] - sw.x_pass[q, 1]) * n1 + (x[q, 2] - sw.x_pass[q, 2]) * n2
        if dn < 0.0:
            x[q, 0] -= dn * n0
            x[q, 1] -= dn * n1
            x[q, 2] -= dn * n2
            v[q, 0] -= dn * n0 / heff
            v[q, 1] -= dn * n1 / heff
            v[q, 2] -= dn * n2 / heff


@njit
def couple_collision_response(x, v, heff, opts, lv, ws, sw, prof):
    """Feed the collision pass's displacements back into the step's linear system.

    The pass moved some free particles from ``sw.x_pass`` to ``x`` (cm; rigid-triangle impulses,
    each particle on its own). Each of them is held along its displacement d (its velocity change
    along d prescribed, ``z_q = d_q/β``; one already on an obstacle is held in full), and the
    step's own system ``(M̃ + β²H)·y = −(M̃ + β²H)·z``, filtered as in the step's solve (pinned
    particles and obstacle constraints kept), gives the velocity change ``y`` (cm/s) of every other
    particle and of the held ones across their displacement; ``v += y``, ``x += β·y``. The cloth
    next to a particle the pass moved follows it as its stiffness says (an in-plane neighbour
    almost rigidly, across a fold as the bending allows), instead of the edge between them taking
    the whole displacement as strain until the next step pulls it back. The matrix is the one the
    step's last solve used (the Newton estimate's), with its preconditioner (no new assembly or
    factorisation). The held particles stay marked in ``sw.con`` (the contact constraints saved in
    ``sw.con_saved``) for :func:`coupled_newton`. Returns PCG's iterations, or −1 when the pass
    moved nothing (nothing is done)."""
    n = x.shape[0]
    fr = sw.free
    z = sw.delta
    sw.con_saved[:] = sw.con
    held = 0
    for q in range(n):
        d2 = 0.0
        for i in range(3):
            d = x[q, i] - sw.x_pass[q, i]
            z[q, i] = d / heff
            d2 += d * d
        if fr[q] and d2 > HELD_SHIFT2:
            if sw.con[q] == 0:  # held along its displacement, free across it
                d = math.sqrt(d2)
                sw.con[q] = 1
                for i in range(3):
                    sw.cn[q, i] = (x[q, i] - sw.x_pass[q, i]) / d
            else:  # already constrained by an obstacle: held
                sw.con[q] = 2
            held += 1
        else:
            z[q, 0] = z[q, 1] = z[q, 2] = 0.0
    if held == 0:
        return -1
    h2 = heff * heff
    matvec_A(z, sw.md, h2, sw.H, fr, sw.rhs)
    for q in range(n):
        for i in range(3):
            sw.rhs[q, i] = -sw.rhs[q, i]
    it, _ = filtered_pcg(False, sw.rhs, sw.dv, sw.cg, opts, h2, fr, sw.con, sw.cn, sw.md, lv, ws, sw.stale,
                         sw.bslot, prof)
    for q in range(n):
        if fr[q]:
            for i in range(3):
                v[q, i] += sw.dv[q, i]
                x[q, i] += heff * sw.dv[q, i]
    return it


@njit
def below_floor_velocity(dv, md, floor2):
    """``Σ m̃_q |Δv_q|² ≤ floor2`` (False when the floor is 0: off): a velocity correction whose
    mass-weighted RMS is within the Newton tolerance."""
    if floor2 <= 0.0:
        return False
    s = 0.0
    for q in range(dv.shape[0]):
        s += md[q] * (dv[q, 0] * dv[q, 0] + dv[q, 1] * dv[q, 1] + dv[q, 2] * dv[q, 2])
    return s <= floor2


@njit
def min_free_mass(md, fr):
    """The smallest lumped mass (g) of a free particle (inf if none)."""
    m = math.inf
    for q in range(md.shape[0]):
        if fr[q] and md[q] < m:
            m = md[q]
    return m


@njit
def largest_square(dv):
    """``max_q |Δv_q|²``, (cm/s)²."""
    b = 0.0
    for q in range(dv.shape[0]):
        b = max(b, dv[q, 0] * dv[q, 0] + dv[q, 1] * dv[q, 1] + dv[q, 2] * dv[q, 2])
    return b


@njit(inline="always")
def update(x, v, heff, use2, sw):
    """``v += Δv`` for free particles (pinned ones keep their prescribed velocity; kinetic friction
    is already in the solve), then ``x += β·v`` (BDF2: ``x += dxh + β·v``)."""
    n = x.shape[0]
    for q in range(n):
        if sw.free[q]:
            for i in range(3):
                v[q, i] += sw.dv[q, i]
    for q in range(n):
        for i in range(3):
            x[q, i] += (sw.dxh[q, i] if use2 else 0.0) + heff * v[q, i]
