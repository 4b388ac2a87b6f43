"""Numba kernels of the collision pass (docs/physics.md, collision): impulses and contact passes.

Everything here works on plain arrays; :mod:`cloth_gym.sim.geometry` holds the predicates and the
broad phase, :mod:`cloth_gym.sim.collision` the
options, the mesh obstacles and the packing. Vectors are handled as 3-tuples
of floats so that the predicates and the impulse compile to straight-line code.

Conventions: positions in cm, velocities in cm/s, masses in g (inverse masses
in 1/g; 0 means infinite mass: a pinned or gripped particle, a static
obstacle).
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import chosen_by_type, copy_into, kernel_only
from .bundles import NoCollisionPass
from .geometry import (closest_point_triangle, closest_points_segments, find_pairs, segment_triangle, signed_volume,
                       swept_aabbs, vadd, vcross, vdot, vnorm, vrow, vscale, vsub)
from .rigid_triangle import apply_triangle_impulse, impulse_response, triangle_rigid_body

# flag bits of the collision pass (CollisionOptions → Model.collision_args)
SELF_VT = 1  # vertex–triangle self-collision
SELF_EE = 2  # edge–edge self-collision
ANGULAR = 4  # rigid-triangle response includes rotation
EXACT = 8  # exact (Baraff) impulse magnitude instead of eq. (22)
MESH = 16  # triangle-mesh obstacles present
COLLISION_PASS_BITS = SELF_VT | SELF_EE | MESH  # any of these: the integrators run collision_pass

GAP_TOL = 1e-3  # a gap within 0.1 % of the thickness counts as kept (no correction, no new sweep)
RESTING_SPEED = 1.0  # cm/s: below this approach speed an impact is inelastic (no jitter at rest)


# ============================================================================ self-collision
@kernel_only
def _unit_normal(a, b, c):
    n = vcross(vsub(b, a), vsub(c, a))
    L = vnorm(n)
    if L == 0.0:
        return False, (0.0, 0.0, 1.0)
    return True, vscale(n, 1.0 / L)


@kernel_only
def _bary(x, i, j, k, wa, wb, wc):
    return (wa * x[i, 0] + wb * x[j, 0] + wc * x[k, 0],
            wa * x[i, 1] + wb * x[j, 1] + wc * x[k, 1],
            wa * x[i, 2] + wb * x[j, 2] + wc * x[k, 2])


@kernel_only
def vertex_triangle_contact(p, ia, ib, ic, x0, x, thickness):
    """Narrow phase of one vertex–triangle pair (docs/physics.md, collision).

    Continuous: the vertex's motion relative to the triangle (its displacement
    minus the triangle's mean displacement) is tested against the triangle at
    the start of the step with :func:`segment_triangle`. Proximity: at the end
    of the step the vertex is within ``thickness`` of the triangle. The normal
    points to the side the vertex came from.

    Returns (kind, wa, wb, wc, n): kind 0 none, 1 crossing, 2 proximity."""
    P0 = vrow(x0, p)
    a0 = vrow(x0, ia)
    b0 = vrow(x0, ib)
    c0 = vrow(x0, ic)
    a1 = vrow(x, ia)
    b1 = vrow(x, ib)
    c1 = vrow(x, ic)
    ok0, n0 = _unit_normal(a0, b0, c0)
    ok1, n1 = _unit_normal(a1, b1, c1)
    if not ok1:
        return 0, 0.0, 0.0, 0.0, n1
    side = vdot(n0, vsub(P0, a0)) if ok0 else vdot(n1, vsub(P0, a1))
    flip = vdot(n0, n1) if ok0 else 1.0
    sgn = 1.0 if side * flip >= 0.0 else -1.0
    n = vscale(n1, sgn)
    d_t = vscale(vadd(vadd(vsub(a1, a0), vsub(b1, b0)), vsub(c1, c0)), 1.0 / 3.0)
    P1 = vsub(vrow(x, p), d_t)
    hit, s, wa, wb, wc = segment_triangle(P0, P1, a0, b0, c0)
    if hit:
        return 1, wa, wb, wc, n
    X = vrow(x, p)
    if abs(vdot(n1, vsub(X, a1))) >= thickness:
        return 0, 0.0, 0.0, 0.0, n  # the common case: off the plane by more than the thickness
    wa, wb, wc = closest_point_triangle(X, a1, b1, c1)
    q = _bary(x, ia, ib, ic, wa, wb, wc)
    if vnorm(vsub(X, q)) < thickness and wa > 0.0 and wb > 0.0 and wc > 0.0:
        return 2, wa, wb, wc, n
    return 0, 0.0, 0.0, 0.0, n


@kernel_only
def resolve_vertex_triangle(p, ia, ib, ic, wa, wb, wc, n, x, v, inv_mass, mass, h_pos, thickness, e, mu,
                            angular, exact):
    """Rigid-triangle response (docs/physics.md, collision) of vertex p against triangle (ia, ib, ic) at the
    barycentric point (wa, wb, wc), normal n. Velocity: an impulse when they approach
    (``v_rel < 0``), then Coulomb friction on the tangential relative velocity. Position:
    the same distribution pushes the gap to ``thickness`` (positions only, no velocity).
    ``x`` moves with ``h_pos·Δv`` so that the step's positions follow its velocities.
    Returns 1 if anything changed."""
    w_p = inv_mass[p]
    static = inv_mass[ia] == 0.0 or inv_mass[ib] == 0.0 or inv_mass[ic] == 0.0
    if w_p == 0.0 and static:
        return 0
    xa = vrow(x, ia)
    xb = vrow(x, ib)
    xc = vrow(x, ic)
    if static:
        Mtri = math.inf
        xcm = xa
        ok = False
        Iinv = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    else:
        Mtri, xcm, ok, Iinv = triangle_rigid_body(xa, xb, xc, mass[ia], mass[ib], mass[ic])
    contact = _bary(x, ia, ib, ic, wa, wb, wc)
    changed = 0
    vb = _bary(v, ia, ib, ic, wa, wb, wc)
    vrel = vsub(vrow(v, p), vb)
    vn = vdot(n, vrel)
    if vn < 0.0:
        ee = e if -vn > RESTING_SPEED else 0.0
        j, dw, inv_M = impulse_response(w_p, contact, n, Mtri, xcm, ok, Iinv, angular, exact, vn, ee)
        apply_triangle_impulse(v, ia, ib, ic, xa, xb, xc, xcm, j, n, dw, inv_M, w_p, p, 1.0)
        apply_triangle_impulse(x, ia, ib, ic, xa, xb, xc, xcm, j, n, dw, inv_M, w_p, p, h_pos)
        # friction: tangential impulse ≤ μ j, translational distribution (conserves linear momentum)
        if mu > 0.0 and j > 0.0:
            vb = _bary(v, ia, ib, ic, wa, wb, wc)
            vrel = vsub(vrow(v, p), vb)
            vt = vsub(vrel, vscale(n, vdot(n, vrel)))
            L = vnorm(vt)
            den = w_p + inv_M
            if L > 0.0 and den > 0.0:
                jt = min(mu * j, L / den)
                tdir = vscale(vt, -1.0 / L)
                apply_triangle_impulse(v, ia, ib, ic, xa, xb, xc, xcm, jt, tdir, (0.0, 0.0, 0.0), inv_M, w_p, p, 1.0)
                apply_triangle_impulse(x, ia, ib, ic, xa, xb, xc, xcm, jt, tdir, (0.0, 0.0, 0.0), inv_M, w_p, p,
                                       h_pos)
        changed = 1
    # position correction to the thickness (same rigid distribution, unit restitution-free "impulse")
    contact = _bary(x, ia, ib, ic, wa, wb, wc)
    gap = vdot(n, vsub(vrow(x, p), contact))
    if gap < thickness * (1.0 - GAP_TOL):
        j, dw, inv_M = impulse_response(w_p, contact, n, Mtri, xcm, ok, Iinv, angular, True,
                                        -(thickness - gap), 0.0)
        apply_triangle_impulse(x, ia, ib, ic, xa, xb, xc, xcm, j, n, dw, inv_M, w_p, p, 1.0)
        changed = 1
    return changed


@kernel_only
def edge_edge_contact(e1a, e1b, e2a, e2b, x0, x, thickness):
    """Narrow phase of two edges: (kind, s, t, n) with the closest-point parameters s on
    edge 1 and t on edge 2 and n pointing from edge 1 to edge 2 (their side at the start).

    Continuous: the four points' signed volume changes sign over the step and, at the
    linearly interpolated coplanar instant, the edges are within ``thickness``. Proximity:
    within ``thickness`` at the end. kind 0 none, 1 crossing, 2 proximity."""
    A0 = vrow(x0, e1a)
    B0 = vrow(x0, e1b)
    C0 = vrow(x0, e2a)
    D0 = vrow(x0, e2b)
    A1 = vrow(x, e1a)
    B1 = vrow(x, e1b)
    C1 = vrow(x, e2a)
    D1 = vrow(x, e2b)
    V0 = signed_volume(A0, B0, C0, D0)
    V1 = signed_volume(A1, B1, C1, D1)
    crossing = V0 * V1 < 0.0
    s1, t1 = closest_points_segments(A1, B1, C1, D1)
    P1 = vadd(A1, vscale(vsub(B1, A1), s1))
    Q1 = vadd(C1, vscale(vsub(D1, C1), t1))
    d1 = vsub(Q1, P1)
    L1 = vnorm(d1)
    if not crossing and L1 >= thickness:
        return 0, 0.0, 0.0, (0.0, 0.0, 1.0)  # the common case: apart at the end, no sign change
    s0, t0 = closest_points_segments(A0, B0, C0, D0)
    P = vadd(A0, vscale(vsub(B0, A0), s0))
    Q = vadd(C0, vscale(vsub(D0, C0), t0))
    dvec = vsub(Q, P)
    L0 = vnorm(dvec)
    if L0 > 1e-12:
        n = vscale(dvec, 1.0 / L0)
    elif L1 > 1e-12:
        n = vscale(d1, 1.0 / L1)
    else:
        return 0, 0.0, 0.0, (0.0, 0.0, 1.0)
    if crossing:
        f = V0 / (V0 - V1)
        Af = vadd(A0, vscale(vsub(A1, A0), f))
        Bf = vadd(B0, vscale(vsub(B1, B0), f))
        Cf = vadd(C0, vscale(vsub(C1, C0), f))
        Df = vadd(D0, vscale(vsub(D1, D0), f))
        sf, tf = closest_points_segments(Af, Bf, Cf, Df)
        Pf = vadd(Af, vscale(vsub(Bf, Af), sf))
        Qf = vadd(Cf, vscale(vsub(Df, Cf), tf))
        if vnorm(vsub(Qf, Pf)) < thickness and 0.0 < sf < 1.0 and 0.0 < tf < 1.0:
            return 1, sf, tf, n
    if L1 < thickness and 0.0 < s1 < 1.0 and 0.0 < t1 < 1.0:
        return 2, s1, t1, n
    return 0, 0.0, 0.0, n


@kernel_only
def _capped_impulse(change, den, w, idx, inv_mass):
    """``change/den`` (the linear-weight impulse that changes the closest points' normal gap, or
    its rate, by ``change``), capped so that no particle's own change ``j·w_i/m_i`` exceeds
    ``change``."""
    j = change / den
    for k in range(4):
        per_j = w[k] * inv_mass[idx[k]]
        if per_j * j > change:
            j = change / per_j
    return j


@kernel_only
def resolve_edge_edge(e1a, e1b, e2a, e2b, s, t, n, x, v, inv_mass, h_pos, thickness, e, mu):
    """Impulse between the closest points of two edges, distributed by the linear weights
    (Bridson et al. 2002): ``Δv_i = ±j·w_i·n/m_i``; conserves linear momentum. Then the
    positions are pushed apart to ``thickness`` with the same weights.

    Where the closest point sits next to a held or pinned particle, the free particles' weights
    are tiny and the full response would move them by the deficit divided by that weight (500
    times the deficit at a weight of 1e-3, metres in one substep). So ``j`` is capped: no particle's
    velocity changes by more than ``(1 + e)·|v_n|`` and no particle moves by more than the gap's
    deficit; the other pairs and the next sweep resolve what is left. A scalar cap keeps linear
    momentum conserved; with four free particles of equal mass it never binds."""
    w = ((1.0 - s), s, (1.0 - t), t)
    idx = (e1a, e1b, e2a, e2b)
    sg = (-1.0, -1.0, 1.0, 1.0)
    den = 0.0
    for k in range(4):
        den += w[k] * w[k] * inv_mass[idx[k]]
    if den == 0.0:
        return 0
    vrel = (0.0, 0.0, 0.0)
    for k in range(4):
        vrel = vadd(vrel, vscale(vrow(v, idx[k]), sg[k] * w[k]))
    vn = vdot(vrel, n)
    changed = 0
    if vn < 0.0:
        ee = e if -vn > RESTING_SPEED else 0.0
        j = _capped_impulse(-(1.0 + ee) * vn, den, w, idx, inv_mass)
        for k in range(4):
            c = sg[k] * j * w[k] * inv_mass[idx[k]]
            for d in range(3):
                v[idx[k], d] += c * n[d]
                x[idx[k], d] += h_pos * c * n[d]
        if mu > 0.0:
            vrel = (0.0, 0.0, 0.0)
            for k in range(4):
                vrel = vadd(vrel, vscale(vrow(v, idx[k]), sg[k] * w[k]))
            vt = vsub(vrel, vscale(n, vdot(vrel, n)))
            L = vnorm(vt)
            if L > 0.0:
                jt = min(mu * j, L / den)
                tdir = vscale(vt, -1.0 / L)
                for k in range(4):
                    c = sg[k] * jt * w[k] * inv_mass[idx[k]]
                    for d in range(3):
                        v[idx[k], d] += c * tdir[d]
                        x[idx[k], d] += h_pos * c * tdir[d]
        changed = 1
    P = (0.0, 0.0, 0.0)
    for k in range(4):
        P = vadd(P, vscale(vrow(x, idx[k]), sg[k] * w[k]))
    gap = vdot(P, n)
    if gap < thickness * (1.0 - GAP_TOL):
        j = _capped_impulse(thickness - gap, den, w, idx, inv_mass)
        for k in range(4):
            c = sg[k] * j * w[k] * inv_mass[idx[k]]
            for d in range(3):
                x[idx[k], d] += c * n[d]
        changed = 1
    return changed


@kernel_only
def self_pairs(x0, x, pad, do_vt, do_ee, tris, tri_edges, point_idx):
    """Broad phase of self-collision: (vertex, triangle) and (edge, edge) pairs whose AABBs over
    the motion x0 → x, inflated by ``pad`` (cm), overlap; pairs sharing a vertex are dropped."""
    nt = tris.shape[0]
    vt = np.zeros((0, 2), dtype=np.int64)
    ee = np.zeros((0, 2), dtype=np.int64)
    if do_vt:
        tlo = np.empty((nt, 3))
        thi = np.empty((nt, 3))
        swept_aabbs(x0, x, tris, pad, tlo, thi)
        plo = np.empty((x.shape[0], 3))
        phi = np.empty((x.shape[0], 3))
        swept_aabbs(x0, x, point_idx, pad, plo, phi)
        cand = find_pairs(plo, phi, tlo, thi, False)
        keep = np.empty(cand.shape[0], dtype=np.bool_)
        for k in range(cand.shape[0]):
            p = cand[k, 0]
            t = cand[k, 1]
            keep[k] = not (p == tris[t, 0] or p == tris[t, 1] or p == tris[t, 2])
        vt = cand[keep]
    if do_ee:
        ne = tri_edges.shape[0]
        elo = np.empty((ne, 3))
        ehi = np.empty((ne, 3))
        swept_aabbs(x0, x, tri_edges, pad, elo, ehi)
        cand = find_pairs(elo, ehi, elo, ehi, True)
        keep = np.empty(cand.shape[0], dtype=np.bool_)
        for k in range(cand.shape[0]):
            a = cand[k, 0]
            b = cand[k, 1]
            keep[k] = not (tri_edges[a, 0] == tri_edges[b, 0] or tri_edges[a, 0] == tri_edges[b, 1]
                           or tri_edges[a, 1] == tri_edges[b, 0] or tri_edges[a, 1] == tri_edges[b, 1])
        ee = cand[keep]
    return vt, ee


@kernel_only
def _max_shift(x, ref):
    m = 0.0
    for p in range(x.shape[0]):
        d = (x[p, 0] - ref[p, 0]) ** 2 + (x[p, 1] - ref[p, 1]) ** 2 + (x[p, 2] - ref[p, 2]) ** 2
        if not d <= m:  # also catches NaN and inf (the first call: ref = inf)
            m = d
    return math.sqrt(m)


@kernel_only
def self_collide(x, v, x0, inv_mass, mass, h_pos, flags, iterations, thickness, restitution, mu, tris, tri_edges,
                 point_idx, margin, vt_pairs, ee_pairs, ref_x):
    """Self-collision pass after a step: x0 → x is the step's motion, v the end velocities.

    Broad phase with a Verlet margin: the pair lists (:func:`self_pairs`, AABBs inflated by
    ``(thickness + margin)/2``) are rebuilt only when a particle has moved more than
    ``margin/2`` from where it was at the last build (``ref_x``); until then no pair outside
    the lists can come within ``thickness``. Then up to ``iterations`` sweeps over the pairs:
    vertex–triangle (bit SELF_VT) and edge–edge (bit SELF_EE) narrow phase and response,
    stopping at the first sweep with nothing to do.

    Returns (vt_pairs, ee_pairs, contacts in the last sweep): keep the lists for the next call."""
    angular = (flags & ANGULAR) != 0
    exact = (flags & EXACT) != 0
    do_vt = (flags & SELF_VT) != 0
    do_ee = (flags & SELF_EE) != 0
    if max(_max_shift(x0, ref_x), _max_shift(x, ref_x)) > 0.5 * margin:
        vt_pairs, ee_pairs = self_pairs(x0, x, 0.5 * (thickness + margin), do_vt, do_ee, tris, tri_edges,
                                        point_idx)
        copy_into(ref_x, x)
    last = 0
    for it in range(iterations):
        count = 0
        for k in range(vt_pairs.shape[0]):
            p = vt_pairs[k, 0]
            t = vt_pairs[k, 1]
            ia = tris[t, 0]
            ib = tris[t, 1]
            ic = tris[t, 2]
            kind, wa, wb, wc, n = vertex_triangle_contact(p, ia, ib, ic, x0, x, thickness)
            if kind != 0:
                count += resolve_vertex_triangle(p, ia, ib, ic, wa, wb, wc, n, x, v, inv_mass, mass, h_pos,
                                                 thickness, restitution, mu, angular, exact)
        for k in range(ee_pairs.shape[0]):
            a = ee_pairs[k, 0]
            b = ee_pairs[k, 1]
            kind, s, t, n = edge_edge_contact(tri_edges[a, 0], tri_edges[a, 1], tri_edges[b, 0], tri_edges[b, 1],
                                              x0, x, thickness)
            if kind != 0:
                count += resolve_edge_edge(tri_edges[a, 0], tri_edges[a, 1], tri_edges[b, 0], tri_edges[b, 1],
                                           s, t, n, x, v, inv_mass, h_pos, thickness, restitution, mu)
        last = count
        if count == 0:
            break
    return vt_pairs, ee_pairs, last


# ============================================================================ mesh obstacles
@kernel_only
def collide_mesh(x, v, x0, inv_mass, mv, mf, mn, mmu, g_lo, g_inv_cell, g_dims, g_start, g_items, restitution,
                 thickness, stamp):
    """Particle contact with static triangle-mesh obstacles (infinite mass).

    Per particle: continuous detection of its segment x0 → x against the mesh's
    triangles (:func:`~cloth_gym.sim.geometry.segment_triangle`, exact for static triangles), entering a
    face from its front (outward normal ``mn``); a crossing puts the particle back
    at the crossing point lifted by ``thickness`` along the face normal, keeping the
    tangential rest of its motion (:func:`_mesh_crossing`). Then proximity: the nearest face whose front
    the particle is on and which is within ``thickness`` pushes it out to
    ``thickness`` along the direction from the nearest point (:func:`_mesh_proximity`). The normal velocity
    ``v_n < 0`` becomes ``−e·v_n``, and Coulomb friction (the face's obstacle μ)
    acts on the tangential velocity, as for analytic obstacles (:func:`_mesh_response`).

    Broad phase: a static uniform grid (built once per model) of the mesh faces,
    ``g_start``/``g_items`` in CSR form; a particle's candidate faces are gathered once
    (:func:`_mesh_candidates`) and shared by the continuous test and both proximity passes. Returns
    the number of particles in contact."""
    count = 0
    stamp[:] = -1
    qid = 0
    cand = np.empty(stamp.shape[0], dtype=np.int64)
    for p in range(x.shape[0]):
        if inv_mass[p] == 0.0:
            continue
        P0 = vrow(x0, p)
        P1 = vrow(x, p)
        qid += 1
        nc = _mesh_candidates(P0, P1, thickness, g_lo, g_inv_cell, g_dims, g_start, g_items, stamp, qid, cand)
        if nc < 0:
            continue
        touched, tn = _mesh_crossing(x, p, P0, P1, mv, mf, mn, cand, nc, thickness)
        touched, tn = _mesh_proximity(x, p, mv, mf, mn, cand, nc, thickness, touched, tn)
        if touched < 0:
            continue
        count += 1
        _mesh_response(v, p, tn, mmu[touched], restitution)
    return count


@kernel_only
def _mesh_candidates(P0, P1, thickness, g_lo, g_inv_cell, g_dims, g_start, g_items, stamp, qid, cand):
    """The faces binned in the grid cells the swept segment P0 → P1 (padded by ``thickness``)
    touches, each once (``stamp`` marks them with ``qid``), into ``cand``; returns their count, or −1
    when the segment misses the grid."""
    nx = g_dims[0]
    ny = g_dims[1]
    nz = g_dims[2]
    lo0 = min(P0[0], P1[0]) - thickness
    lo1 = min(P0[1], P1[1]) - thickness
    lo2 = min(P0[2], P1[2]) - thickness
    hi0 = max(P0[0], P1[0]) + thickness
    hi1 = max(P0[1], P1[1]) + thickness
    hi2 = max(P0[2], P1[2]) + thickness
    i0 = max(int(math.floor((lo0 - g_lo[0]) * g_inv_cell)), 0)
    j0 = max(int(math.floor((lo1 - g_lo[1]) * g_inv_cell)), 0)
    k0 = max(int(math.floor((lo2 - g_lo[2]) * g_inv_cell)), 0)
    i1 = min(int(math.floor((hi0 - g_lo[0]) * g_inv_cell)), nx - 1)
    j1 = min(int(math.floor((hi1 - g_lo[1]) * g_inv_cell)), ny - 1)
    k1 = min(int(math.floor((hi2 - g_lo[2]) * g_inv_cell)), nz - 1)
    if i0 > i1 or j0 > j1 or k0 > k1:
        return -1
    nc = 0
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            for k in range(k0, k1 + 1):
                c = (i * ny + j) * nz + k
                for e in range(g_start[c], g_start[c + 1]):
                    f = g_items[e]
                    if stamp[f] != qid:
                        stamp[f] = qid
                        cand[nc] = f
                        nc += 1
    return nc


@kernel_only
def _mesh_crossing(x, p, P0, P1, mv, mf, mn, cand, nc, thickness):
    """The earliest front-side crossing of P0 → P1 through a candidate face: particle p is put back
    at the crossing lifted by ``thickness`` along the face normal, keeping the tangential rest of its
    motion. Returns (face touched or −1, its normal)."""
    best_s = 2.0
    best_f = -1
    for m in range(nc):
        f = cand[m]
        a = vrow(mv, mf[f, 0])
        n = vrow(mn, f)
        if vdot(n, vsub(P0, a)) <= 0.0:
            continue  # came from behind: not an entry
        hit, s, wa, wb, wc = segment_triangle(P0, P1, a, vrow(mv, mf[f, 1]), vrow(mv, mf[f, 2]))
        if hit and s < best_s:
            best_s = s
            best_f = f
    touched = -1
    tn = (0.0, 0.0, 1.0)
    if best_f >= 0:
        n = vrow(mn, best_f)
        r = vscale(vsub(P1, P0), 1.0 - best_s)
        E = vadd(P0, vscale(vsub(P1, P0), best_s))
        rn = min(vdot(r, n), 0.0)
        X = vadd(vadd(E, vsub(r, vscale(n, rn))), vscale(n, thickness))
        for d in range(3):
            x[p, d] = X[d]
        touched = best_f
        tn = n
    return touched, tn


@kernel_only
def _mesh_proximity(x, p, mv, mf, mn, cand, nc, thickness, touched, tn):
    """Particle p pushed out to ``thickness`` from the nearest candidate face whose front it is on,
    two passes (concave corners). Returns (face touched, contact normal), ``touched``/``tn`` if none."""
    for _pass in range(2):
        X = vrow(x, p)
        best_d = thickness * 1.01 + 1e-9
        best_f = -1
        best_q = X
        for m in range(nc):
            f = cand[m]
            a = vrow(mv, mf[f, 0])
            b = vrow(mv, mf[f, 1])
            cc = vrow(mv, mf[f, 2])
            if vdot(vrow(mn, f), vsub(X, a)) < 0.0:
                continue  # behind the face
            wa, wb, wc = closest_point_triangle(X, a, b, cc)
            q = vadd(vadd(vscale(a, wa), vscale(b, wb)), vscale(cc, wc))
            d = vnorm(vsub(X, q))
            if d < best_d:
                best_d = d
                best_f = f
                best_q = q
        if best_f < 0:
            break
        if best_d > 1e-9:
            nn = vscale(vsub(X, best_q), 1.0 / best_d)
        else:
            nn = vrow(mn, best_f)
        if best_d < thickness:
            X = vadd(best_q, vscale(nn, thickness))
            for d in range(3):
                x[p, d] = X[d]
        touched = best_f
        tn = nn
    return touched, tn


@kernel_only
def _mesh_response(v, p, tn, mu, restitution):
    """Particle p's velocity after touching a static face of normal ``tn``: an approaching normal
    velocity ``v_n < 0`` becomes ``−e·v_n`` (inelastic below RESTING_SPEED), Coulomb friction ``mu``
    brakes the tangential velocity by at most ``mu·(1 + e)·|v_n|``."""
    vv = vrow(v, p)
    vn = vdot(vv, tn)
    if vn < 0.0:
        e = restitution if -vn > RESTING_SPEED else 0.0
        dvn = -(1.0 + e) * vn
        vt = vsub(vv, vscale(tn, vn))
        L = vnorm(vt)
        sc = 0.0
        if L > 0.0:
            sc = max(0.0, 1.0 - mu * dvn / L)
        for d in range(3):
            v[p, d] = vt[d] * sc - e * vn * tn[d]


@kernel_only
def collision_pass(x, v, x0, inv_mass, mass, h_pos, restitution, thickness, cd, vt_pairs, ee_pairs, ref_x):
    """The collision pass an integrator runs after each (sub)step, after the analytic obstacles:
    mesh obstacles (bit MESH; obstacle ``thickness``), then self-collision (bits SELF_VT,
    SELF_EE; ``cd.thickness_self``); ``cd`` a :class:`~cloth_gym.sim.bundles.CollisionData`.
    ``h_pos``: how far (s) a velocity change moves a particle in this step (Δt for Euler, 2Δt/3
    for BDF2). Nothing runs when ``cd.flags`` has none of the bits. ``vt_pairs``, ``ee_pairs``,
    ``ref_x``: the self-collision pair lists and where they were built (:func:`self_collide`);
    returns the lists to pass to the next call."""
    flags = cd.flags
    if (flags & MESH) != 0:
        collide_mesh(x, v, x0, inv_mass, cd.mv, cd.mf, cd.mn, cd.mmu, cd.g_lo, cd.g_inv_cell, cd.g_dims, cd.g_start,
                     cd.g_items, restitution, thickness, cd.stamp)
    if (flags & (SELF_VT | SELF_EE)) != 0:
        vt_pairs, ee_pairs, _ = self_collide(x, v, x0, inv_mass, mass, h_pos, flags, cd.iterations,
                                             cd.thickness_self, restitution, cd.mu_self, cd.tris, cd.tri_edges,
                                             cd.point_idx, cd.margin, vt_pairs, ee_pairs, ref_x)
    return vt_pairs, ee_pairs


@chosen_by_type
def run_collision_pass(cd, x, v, x0, inv_mass, mass, h_pos, restitution, thickness, vt_pairs, ee_pairs, ref_x):
    """:func:`collision_pass` for ``cd`` a :class:`~cloth_gym.sim.bundles.CollisionData`; for a
    :class:`~cloth_gym.sim.bundles.NoCollisionPass` nothing (the pair lists returned as given),
    decided while numba types the caller, so that a step compiled without a collision pass holds
    none of its code. Callable from compiled kernels only."""
    if getattr(cd, "instance_class", None) is NoCollisionPass:
        return lambda cd, x, v, x0, inv_mass, mass, h_pos, restitution, thickness, vt_pairs, ee_pairs, ref_x: (
            vt_pairs, ee_pairs)
    return lambda cd, x, v, x0, inv_mass, mass, h_pos, restitution, thickness, vt_pairs, ee_pairs, ref_x: (
        collision_pass(x, v, x0, inv_mass, mass, h_pos, restitution, thickness, cd, vt_pairs, ee_pairs, ref_x))
