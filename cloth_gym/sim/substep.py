"""The end of every (sub)step, shared by the explicit and the implicit integrator.

Once an integrator has new velocities and positions for a substep, :func:`finish_substep` moves
the obstacles, resolves contact with them, limits the strain (when a limiter is set), runs the
collision pass (self-collision, mesh obstacles) and checks the state for divergence — in that
order, in this one place. The checks report a :class:`~cloth_gym.sim.bundles.Status`.
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import chosen_by_type, cycles, kernel_only, njit
from .bundles import P_CHECKS, P_COLLISION, P_OBSTACLES, Status, Unlimited
from .collision_kernels import COLLISION_PASS_BITS, run_collision_pass
from .forces import edge_vector
from .obstacles import advance_obstacles, any_moving, collide_particles, keep_outside

__all__ = ["finish_substep", "obstacle_stage", "limiter_stage", "closing_stage", "needs_previous_positions",
           "check_state", "limit_strain", "STRAIN_LIMIT_RTOL", "LIMIT_TARGET"]


@kernel_only
def finish_substep(x, v, x_prev, inv_mass, h, fd, world, guard, vt_pairs, ee_pairs, ref_x, prof):
    """After a substep of ``h`` s moved the cloth from ``x_prev`` to ``x`` (cm) with end velocities
    ``v`` (cm/s): obstacles forward by ``world.vel·h``, obstacle contact (``world.touching``
    updated), the strain limiter of ``guard`` (:func:`obstacle_stage`), the collision pass, the
    obstacles again (:func:`~cloth_gym.sim.obstacles.keep_outside`: a particle the limiter or the
    collision pass pushed inside one is put back), then the divergence check (:func:`closing_stage`).

    Returns (status, particle, value, vt_pairs, ee_pairs): a :class:`~cloth_gym.sim.bundles.Status`
    code with the particle and value it concerns (speed cm/s or strain %), and the collision pass's
    pair lists for the next substep. ``x_prev`` is read only when there are obstacles or a collision
    pass. ``prof``: the phase profile's cycle counts (OBSTACLES, COLLISION, CHECKS; see
    :class:`~cloth_gym.sim.bundles.Phase`), added to."""
    t0 = cycles()
    obstacle_stage(x, v, x_prev, inv_mass, h, fd, world, guard)
    t1 = cycles()
    if (world.collision.flags & COLLISION_PASS_BITS) != 0:
        vt_pairs, ee_pairs = run_collision_pass(world.collision, x, v, x_prev, inv_mass, fd.mass, h,
                                                world.obstacles.restitution, world.obstacles.thickness, vt_pairs,
                                                ee_pairs, ref_x)
    status, p, value = closing_stage(x, v, inv_mass, fd, world, guard, t0, t1, cycles(), prof)
    return status, p, value, vt_pairs, ee_pairs


@njit(inline="always")
def obstacle_stage(x, v, x_prev, inv_mass, h, fd, world, guard):
    """The first part of :func:`finish_substep`: obstacles forward by ``world.vel·h``, obstacle
    contact (``world.touching`` updated) and the strain limiter of ``guard``."""
    ob = world.obstacles
    if any_moving(world.vel):
        advance_obstacles(ob.params, world.offset, world.vel, h, world.prm)
    if ob.types.shape[0] > 0:
        collide_particles(x, v, x_prev, inv_mass, ob.types, world.prm, ob.friction, ob.restitution, ob.thickness,
                          world.touching, world.vel, h)
    limiter_stage(guard, x, v, inv_mass, fd)  # after the obstacles: an edge they stretched is limited too


@njit(inline="always")
def closing_stage(x, v, inv_mass, fd, world, guard, t0, t1, t2, prof):
    """The last part of :func:`finish_substep`, after the collision pass: a particle the limiter
    or the collision pass pushed inside an obstacle is put back, then the divergence check; the
    profile gets OBSTACLES (``t0``–``t1`` and the put-back), COLLISION (``t1``–``t2``) and CHECKS.
    Returns (status, particle, value)."""
    ob = world.obstacles
    collide = (world.collision.flags & COLLISION_PASS_BITS) != 0
    if ob.types.shape[0] > 0 and (guard.strain_limit > 0.0 or collide):
        keep_outside(x, v, inv_mass, ob.types, world.prm, world.vel, world.touching)
    t3 = cycles()
    status, p, value = check_state(x, v, fd.edges, fd.rest, guard.max_speed, guard.max_strain_percent)
    prof[P_CHECKS] += cycles() - t3
    if collide:
        prof[P_COLLISION] += t2 - t1
    if ob.types.shape[0] > 0 or guard.strain_limit > 0.0:
        prof[P_OBSTACLES] += (t1 - t0) + (t3 - t2)
    return status, p, value


@chosen_by_type
def limiter_stage(guard, x, v, inv_mass, fd):
    """:func:`limit_strain` with the limit and the sweeps of ``guard`` (a
    :class:`~cloth_gym.sim.bundles.Guard`) where its limit is above 0; for an
    :class:`~cloth_gym.sim.bundles.Unlimited` guard nothing, decided while numba types the caller,
    so that a step compiled without the limiter holds none of its code. Callable from compiled
    kernels only."""
    if getattr(guard, "instance_class", None) is Unlimited:
        return lambda guard, x, v, inv_mass, fd: None

    def limited(guard, x, v, inv_mass, fd):
        if guard.strain_limit > 0.0:
            limit_strain(x, v, inv_mass, fd.edges, fd.rest, guard.strain_limit, guard.strain_iters)

    return limited


@kernel_only
def needs_previous_positions(world):
    """Does :func:`finish_substep` read ``x_prev`` (obstacles or a collision pass)?"""
    return world.obstacles.types.shape[0] > 0 or (world.collision.flags & COLLISION_PASS_BITS) != 0


@kernel_only
def check_state(x, v, edges, rest, max_speed, max_strain_percent):
    """(status, particle, value): a :class:`~cloth_gym.sim.bundles.Status` code — OK, NON_FINITE,
    SPEED (a particle faster than ``max_speed`` cm/s; value its speed) or STRAIN (an edge past
    ``max_strain_percent``; value its strain in %) — with the particle it concerns."""
    vmax2 = max_speed * max_speed
    for p in range(x.shape[0]):
        s2 = v[p, 0] ** 2 + v[p, 1] ** 2 + v[p, 2] ** 2
        if not (math.isfinite(x[p, 0]) and math.isfinite(x[p, 1]) and math.isfinite(x[p, 2])
                and math.isfinite(s2)):
            return Status.NON_FINITE, p, math.nan
        if s2 > vmax2:
            return Status.SPEED, p, math.sqrt(s2)
    lim = 1.0 + max_strain_percent / 100.0
    for e in range(edges.shape[0]):
        a = edges[e, 0]
        r = edge_vector(x, a, edges[e, 1])[3]
        if r > lim * rest[e]:
            return Status.STRAIN, a, 100.0 * (r / rest[e] - 1.0)
    return Status.OK, -1, 0.0


# ============================================================================ strain limiting
@kernel_only
def _move_pair(arr, a, b, wa, wb, s, d0, d1, d2):
    """``arr[a] += wa·s·d``, ``arr[b] −= wb·s·d``: a pairwise, momentum-conserving correction."""
    arr[a, 0] += wa * s * d0
    arr[a, 1] += wa * s * d1
    arr[a, 2] += wa * s * d2
    arr[b, 0] -= wb * s * d0
    arr[b, 1] -= wb * s * d1
    arr[b, 2] -= wb * s * d2


@kernel_only
def _limited_edge(x, inv_mass, edges, e):
    """(a, b, 1/m_a, 1/m_b, x_b − x_a, |x_b − x_a|) of edge e, for the strain limiter's passes."""
    a = edges[e, 0]
    b = edges[e, 1]
    d0, d1, d2, r = edge_vector(x, a, b)
    return a, b, inv_mass[a], inv_mass[b], d0, d1, d2, r


@kernel_only
def _filter_separation(x, v, inv_mass, edges, hit):
    """Remove the separating relative velocity along every edge with ``hit[e]`` (inelastic impulse)."""
    for e in range(edges.shape[0]):
        if not hit[e]:
            continue
        a, b, wa, wb, d0, d1, d2, r = _limited_edge(x, inv_mass, edges, e)
        if wa + wb == 0.0 or r == 0.0:
            continue
        vr = ((v[b, 0] - v[a, 0]) * d0 + (v[b, 1] - v[a, 1]) * d1 + (v[b, 2] - v[a, 2]) * d2) / r
        if vr > 0.0:
            _move_pair(v, a, b, wa, wb, vr / (r * (wa + wb)), d0, d1, d2)


# The strain limiter corrects an edge only when it is more than STRAIN_LIMIT_RTOL of the limit
# above it, and then shortens it to LIMIT_TARGET of the limit. Requiring every edge <= the limit
# and correcting to exactly the limit converges only asymptotically (each correction pushes the
# neighbours back a little): after the 41×41 tablecloth's impact at 50 ms every step used all
# 1,000 sweeps, ending at 0.9001 % for a 0.9 % limit (62 % of the run time).
STRAIN_LIMIT_RTOL = 0.01
LIMIT_TARGET = 0.5


@kernel_only
def limit_strain(x, v, inv_mass, edges, rest, limit, iters):
    """Strain limiting (Provot 1995, with Bridson et al. 2002's velocity filter): every lattice
    edge longer than ``(1 + limit·(1 + rtol))·L`` is shortened to ``(1 + t·limit)·L`` (rtol =
    :data:`STRAIN_LIMIT_RTOL` = 1 %, t = :data:`LIMIT_TARGET` = ½; the correction split by inverse
    mass, pinned and gripped particles do not move), Gauss–Seidel style, until no edge exceeds the
    threshold; then, on every edge it corrected, the separating part of the relative velocity
    along the edge is removed by an inelastic, momentum-conserving impulse. Velocities are never
    increased (``Δx/h`` is not added: that kick defeated table friction and kept the cloth
    sliding). It never acts on an edge below the limit, and a correction leaves the edge it
    corrects stretched by ``t·limit`` (over-relaxation that does not compress it).

    Shortening to half the limit rather than to the limit over-relaxes the iteration, and the
    work list makes each pass visit only the edges next to a particle a correction moved (one
    pass over all edges in order, then a queue holding each edge at most once). On the 41×41
    tablecloth at 50 ms with a 0.9 % limit, the limiter's edge visits per simulated second fell
    from 20,000 sweeps' worth (every step capped at 1,000) to about 600 (180–230 at the impact, 4 once it drapes), 0.08 s of CPU. ``iters`` caps the work
    at that many full sweeps' worth of edge visits. Returns (the largest strain after limiting,
    fraction; the edge visits made, in sweeps).

    Why: a linearised implicit step cannot see the second-order stretch of an edge that rotates
    (a cloth folding over a table edge at impact moves its overhang straight down for a whole
    step): at Δt = 10 ms the 41×41 tablecloth reaches 30–60 % strain for a step where the
    accurate (explicit, Δt = 18 µs) solution stays below 0.7 %. The limiter removes that
    error."""
    n = x.shape[0]
    m = edges.shape[0]
    # particle → incident edges (CSR)
    off = np.zeros(n + 1, dtype=np.int64)
    for e in range(m):
        off[edges[e, 0] + 1] += 1
        off[edges[e, 1] + 1] += 1
    for q in range(n):
        off[q + 1] += off[q]
    fill = off[:n].copy()
    inc = np.empty(2 * m, dtype=np.int64)
    for e in range(m):
        for j in range(2):
            q = edges[e, j]
            inc[fill[q]] = e
            fill[q] += 1
    queue = np.empty(m, dtype=np.int64)
    queued = np.ones(m, dtype=np.bool_)
    hit = np.zeros(m, dtype=np.bool_)
    for e in range(m):
        queue[e] = e
    head = 0
    count = m
    visits = 0
    cap = iters * m
    threshold = limit * (1.0 + STRAIN_LIMIT_RTOL)
    while count > 0 and visits < cap:
        e = queue[head]
        head = head + 1 if head + 1 < m else 0
        count -= 1
        queued[e] = False
        visits += 1
        a, b, wa, wb, d0, d1, d2, r = _limited_edge(x, inv_mass, edges, e)
        if wa + wb == 0.0 or r == 0.0 or r / rest[e] - 1.0 <= threshold:
            continue
        _move_pair(x, a, b, wa, wb, (r - (1.0 + LIMIT_TARGET * limit) * rest[e]) / (r * (wa + wb)), d0, d1, d2)
        hit[e] = True
        for j in range(2):
            q = a if j == 0 else b
            if inv_mass[q] == 0.0:
                continue
            for k in range(off[q], off[q + 1]):
                f = inc[k]
                if not queued[f]:
                    t = head + count
                    queue[t - m if t >= m else t] = f
                    queued[f] = True
                    count += 1
    _filter_separation(x, v, inv_mass, edges, hit)
    worst = 0.0
    for e in range(m):
        a, b, wa, wb, d0, d1, d2, r = _limited_edge(x, inv_mass, edges, e)
        if wa + wb > 0.0:
            worst = max(worst, r / rest[e] - 1.0)
    return worst, visits / m
