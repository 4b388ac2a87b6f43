"""The collision response coupled to the implicit solve (``SolveOptions.couple_collisions``;
:func:`coupled_finish`, the step's last stage in its place).

After the step's solve, each collision pass is followed by the step solved again with the
particles the pass moved held along their displacement: the step's linear system first
(:func:`couple_collision_response`), then its Newton passes (:func:`coupled_newton`), up to
COUPLING_ROUNDS rounds a substep (:func:`coupling_rounds`), so that the cloth around a particle
the pass moves follows it instead of the edge between them taking the displacement as strain.
"""

from __future__ import annotations

import math

from .._numba import chosen_by_type, copy_into, cycles, kernel_only, njit
from ..bundles import P_COLLISION, P_FACTOR, P_NEWTON, NoCollisionPass
from ..collision_kernels import run_collision_pass
from ..obstacles import signed_distance
from ..substep import closing_stage, obstacle_stage
from .cg import filtered_pcg
from .matrix import matvec_A
from .newton import newton_passes


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


def _coupling_rounds(cd, x, v, inv_mass, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, vt_pairs,
                     ee_pairs, ref_x, prof):
    ob = world.obstacles
    it = 0
    # free flight: every particle free, none constrained by or touching an obstacle (the rounds
    # change neither), so each round's added momentum is taken back
    flying = in_flight(sw.free, sw.con, world.touching)
    p0 = (0.0, 0.0, 0.0)
    for rnd in range(COUPLING_ROUNDS + 1):
        copy_into(sw.x_pass, x)
        vt_pairs, ee_pairs = run_collision_pass(cd, x, v, sw.x_prev, inv_mass, fd.mass, heff, ob.restitution,
                                                ob.thickness, vt_pairs, ee_pairs, ref_x)
        if rnd == COUPLING_ROUNDS:  # the last pass, not coupled
            break
        hold_on_obstacles(x, v, heff, world, sw)
        if flying:
            p0 = momentum(v, fd.mass)
        itc = couple_collision_response(x, v, heff, opts, lv, ws, sw, prof)
        if itc < 0:
            break
        it += itc + coupled_newton(x, v, inv_mass, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, prof)
        if flying:
            keep_momentum(x, v, fd.mass, p0, heff, sw.free)
        copy_into(sw.con, sw.con_saved)
    return vt_pairs, ee_pairs, it


@chosen_by_type
def coupling_rounds(cd, x, v, inv_mass, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, vt_pairs,
                    ee_pairs, ref_x, prof):
    """At most COUPLING_ROUNDS rounds of the collision pass, :func:`hold_on_obstacles`,
    :func:`couple_collision_response` and :func:`coupled_newton` (in free flight the momentum the
    round added taken back: :func:`keep_momentum`), until a pass moves nothing (else one last
    pass). Returns the pass's pair lists and the PCG iterations. For ``cd`` a
    :class:`~cloth_gym.sim.bundles.NoCollisionPass` nothing, decided while numba types the caller,
    so that a step without a collision pass holds none of this code. Compiled kernels only."""
    if getattr(cd, "instance_class", None) is NoCollisionPass:
        return lambda cd, x, v, inv_mass, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, vt_pairs, \
            ee_pairs, ref_x, prof: (vt_pairs, ee_pairs, 0)
    return _coupling_rounds


@njit(inline="always")
def coupled_newton(x, v, inv_mass, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, prof):
    """After :func:`couple_collision_response`: the step's Newton passes (``opts.newton`` > one pass)
    from the positions the cloth has now, with the particles the collision pass moved held where
    it put them, so the rest of the cloth is solved on the nonlinear forces, not on the step's
    linearisation (which does not see the second-order stretch of an edge that a held particle
    turns). The step's start is ``sw.x_prev``, ``sw.v_start``; the estimate is the Δv that gives
    each particle its present position; afterwards every other free particle takes the solved
    velocity and its position. Returns PCG's iterations."""
    if opts.newton.passes <= 1:
        return 0
    n = x.shape[0]
    fr = sw.free
    for q in range(n):
        for i in range(3):
            sw.dv[q, i] = ((x[q, i] - sw.x_prev[q, i] - (sw.dxh[q, i] if use2 else 0.0)) / heff - sw.v_start[q, i]
                           if fr[q] else 0.0)
    ok, it, _, _ = newton_passes(opts.newton, sw.x_prev, sw.v_start, wind, heff, use2, opts, fd, world, contacts,
                                 lv, ws, sw, prof, 0.0)
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


@kernel_only
def momentum(v, mass):
    """``Σ m_q v_q`` (g·cm/s), as three numbers."""
    p0, p1, p2 = 0.0, 0.0, 0.0
    for q in range(v.shape[0]):
        p0 += mass[q] * v[q, 0]
        p1 += mass[q] * v[q, 1]
        p2 += mass[q] * v[q, 2]
    return p0, p1, p2


@kernel_only
def in_flight(free, con, touching):
    """Every particle free, none constrained by (``con``) or touching an obstacle."""
    for q in range(free.shape[0]):
        if not free[q] or con[q] != 0 or touching[q] >= 0:
            return False
    return True


@kernel_only
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


@kernel_only
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


@kernel_only
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
    copy_into(sw.con_saved, sw.con)
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
