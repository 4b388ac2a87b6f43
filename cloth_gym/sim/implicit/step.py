"""The implicit step as a list of named stages (see :mod:`cloth_gym.sim.implicit`).

Each (sub)step of ``h`` seconds, in order (:func:`run_implicit`):

1. :func:`evaluate_forces` — every force at the start of the step;
2. :func:`prepare` — lumped mass (with absolute damping and air drag's linearisation) and the
   obstacle contacts' constraints and friction dampers;
3. :func:`assemble` — the stiffness blocks of H and the preconditioner's set-up;
4. :func:`right_hand_side` — ``h·(f − h·H·v)`` (BDF2: with its history terms);
5. :func:`first_solve` — PCG for the velocity change Δv (warm-started), its momentum balance made
   exact in free flight (:func:`~cloth_gym.sim.implicit.cg.exact_momentum`);
6. :func:`friction_resolve` — the solve again where friction's dampers were too weak;
7. :func:`~cloth_gym.sim.implicit.newton.newton_passes` — further Newton passes
   (``SolveOptions.newton`` a :class:`~.bundles.NewtonPasses`) until the next correction is within
   ``SolveOptions.newton_tol``;
8. :func:`update` — ``v += Δv``, ``x += h·v``;
9. :func:`~cloth_gym.sim.substep.finish_substep` — obstacles, strain limiter, collision pass and
   the divergence check, shared with the explicit integrator; with ``SolveOptions.couple_collisions``
   :func:`~cloth_gym.sim.implicit.coupling.coupled_finish`, where each collision pass is followed
   by the step's solve again with the particles the pass moved held where it put them
   (:mod:`cloth_gym.sim.implicit.coupling`), until a pass moves nothing.

Every stage adds its time to its :class:`~cloth_gym.sim.bundles.Phase` of the profile; the
band preconditioner's lazy factorisation is counted under FACTOR wherever it happens.

The stages, and the loop over steps, are inlined into :func:`run_implicit` (``inline="always"``:
numba types them into their caller's IR) rather than compiled as kernels of their own: numba
optimises each kernel's module again with every callee linked into it, so each layer of separate
kernels would pay again for the layers below it (docs/cli.md, "Where the first run's CPU goes").
The stages get the large bundles (``fd``, ``world``, ``lv``, ``ws`` and the :class:`StepWork`) by
reference (:func:`~cloth_gym.sim._numba.by_ref`): numba passes a NamedTuple by value, one
argument per array field, and counts references to each of its arrays wherever it is handed on.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .._numba import by_ref, copy_into, cycles, kernel_only, njit, runtime
from ..bundles import (N_PHASES, P_ASSEMBLY, P_FACTOR, P_FORCES, P_FRICTION, P_PREPARE, P_RHS, P_SOLVE,
                       Status)
from ..collision_kernels import COLLISION_PASS_BITS
from ..forces import (AIR, DAMPING, STRAIN_DAMPING, air_linearisation, eval_forces_at, eval_strain_damping,
                      lumped_mass)
from ..substep import finish_substep, needs_previous_positions
from .bundles import BAND_WARP, CGWork, Matrix
from .cg import exact_momentum, filtered_pcg
from .contact import FRICTION_PASSES, contact_constraints, refine_friction
from .coupling import coupled_finish
from .matrix import apply_H, implicit_rhs
from . import precondition as pc
from .multigrid import level_matrix
from .newton import newton_passes

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


@kernel_only
def step_work(inv_mass, opts, lv, ws):
    """The :class:`StepWork` of a run on ``N = inv_mass.shape[0]`` particles (free: ``inv_mass`` > 0),
    by reference (:func:`~cloth_gym.sim._numba.by_ref`)."""
    n = inv_mass.shape[0]
    fr = ws.free[0:n]
    for q in range(n):
        fr[q] = inv_mass[q] > 0.0
    bslot = lv.lw_slot[0:n] if opts.precond == BAND_WARP else lv.lf_slot[0:n]
    cg = CGWork(np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)))
    work = StepWork(np.empty((n, 3)), np.empty((n, 3)), np.zeros(n), np.empty((n, 3)), np.empty((n, 3)), cg,
                    np.zeros(n), np.zeros(n), np.zeros(n, dtype=np.int8), np.zeros((n, 3)), np.empty((n, 3)),
                    np.zeros((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)),
                    np.empty((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.empty(n), np.zeros(1, dtype=np.int64), fr,
                    ws.mdiag[0:n], level_matrix(0, lv, ws), bslot,
                    np.empty((n, 3) if opts.couple_collisions else (0, 3)), np.zeros(n, dtype=np.int8),
                    np.empty((n, 3) if opts.couple_collisions else (0, 3)))
    return by_ref(work)


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

    ``prof`` (PROFILE_SIZE,) int64: the phase profile, cycle counts per
    :class:`~cloth_gym.sim.bundles.Phase` and of the whole call, added to.

    Returns (status, step, particle, value): a :class:`~cloth_gym.sim.bundles.Status` code
    (NOT_SPD: the coarsest-level or band matrix was not positive definite), the step it happened
    at, and the particle and value it concerns."""
    start = cycles()
    out = _implicit_steps(n_steps, h, x, v, inv_mass, wind, stats, opts, guard, carry, by_ref(fd),
                          by_ref(world), by_ref(lv), by_ref(ws), prof)
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
        ok, it3, rel, passes = newton_passes(opts.newton, x, v, wind, heff, use2, opts, fd, world, contacts, lv, ws,
                                             sw, prof, rel)
        if not ok or sw.stale[0] == 2:  # a coarse or the band matrix was not SPD (non-finite state)
            return Status.NOT_SPD, s, -1, math.nan
        stats[s, 0] = it + it2 + it3
        stats[s, 1] = rel
        stats[s, 2] = 1 + passes
        if opts.warm_start:
            copy_into(carry.dv, sw.dv)
            carry.dv_ok[0] = 1
        if keep_prev:
            copy_into(sw.x_prev, x)
        coupled = opts.couple_collisions and (world.collision.flags & COLLISION_PASS_BITS) != 0
        if coupled:
            copy_into(sw.v_start, v)
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
        copy_into(sw.hist_v_old, carry.v)
    if opts.bdf2:
        copy_into(carry.x, x)
        copy_into(carry.v, v)
        carry.ok[0] = 1
    prof[P_RHS] += cycles() - t0


@njit(inline="always")
def first_solve(heff, opts, carry, lv, ws, sw, prof):
    """PCG for Δv (``sw.dv``), from the last step's Δv when warm-started. Returns (iterations,
    relative residual)."""
    t0 = cycles()
    warm = opts.warm_start and carry.dv_ok[0] == 1
    if warm:
        copy_into(sw.dv, carry.dv)
    factored = prof[P_FACTOR]
    it, rel = filtered_pcg(warm, sw.rhs, sw.dv, sw.cg, opts, heff * heff, sw.free, sw.con, sw.cn, sw.md, lv, ws,
                           sw.stale, sw.bslot, prof)
    if opts.momentum_exact:
        exact_momentum(sw.rhs, sw.dv, sw.md, sw.free, sw.con)
    prof[P_SOLVE] += cycles() - t0 - (prof[P_FACTOR] - factored)
    return it, rel


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
        copy_into(sw.md_before, sw.md)
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
