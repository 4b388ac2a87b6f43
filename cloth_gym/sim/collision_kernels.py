"""Numba kernels of the collision pass (docs/physics.md, collision): predicates, impulses, broad phase, contact passes.

Everything here works on plain arrays; :mod:`cloth_gym.sim.collision` holds the
options, the mesh obstacles and the packing. Vectors are handled as 3-tuples
of floats so that the predicates and the impulse compile to straight-line code.

Conventions: positions in cm, velocities in cm/s, masses in g (inverse masses
in 1/g; 0 means infinite mass: a pinned or gripped particle, a static
obstacle).
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit

# flag bits of the collision pass (CollisionOptions → Model.collision_args)
SELF_VT = 1  # vertex–triangle self-collision
SELF_EE = 2  # edge–edge self-collision
ANGULAR = 4  # rigid-triangle response includes rotation
EXACT = 8  # exact (Baraff) impulse magnitude instead of eq. (22)
MESH = 16  # triangle-mesh obstacles present
COLLISION_PASS_BITS = SELF_VT | SELF_EE | MESH  # any of these: the integrators run collision_pass

GAP_TOL = 1e-3  # a gap within 0.1 % of the thickness counts as kept (no correction, no new sweep)
RESTING_SPEED = 1.0  # cm/s: below this approach speed an impact is inelastic (no jitter at rest)


# ============================================================================ small vector algebra
@njit
def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit
def _add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@njit
def _scale(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


@njit
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit
def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit
def _row(x, i):
    return (x[i, 0], x[i, 1], x[i, 2])


@njit
def _norm(a):
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


# ============================================================================ predicates
@njit
def signed_volume(p, a, b, c):
    """The paper's 4×4 determinant ("Euclid S-form") of homogeneous points::

        | p 1 |
        | a 1 |  =  −(a − p)·((b − p) × (c − p))
        | b 1 |
        | c 1 |

    Six times the signed volume of the tetrahedron (p, a, b, c), cm³; zero when
    the four points are coplanar. Computed from differences (the expansion of
    the determinant along its column of ones), which is exact for coplanar
    integer inputs."""
    ap = _sub(a, p)
    bp = _sub(b, p)
    cp = _sub(c, p)
    return -_dot(ap, _cross(bp, cp))


@njit
def segment_triangle(p, q, a, b, c):
    """Does the segment p → q cross the (closed) triangle abc? Signed volumes (docs/physics.md, collision).

    Crossing iff ``V(p,a,b,c)`` and ``V(q,a,b,c)`` differ in sign (one may be 0:
    an end on the plane) and ``V(p,q,a,b)``, ``V(p,q,b,c)``, ``V(p,q,c,a)`` share
    a sign (zeros allowed: through an edge or a vertex counts). A segment in the
    triangle's plane (both end volumes 0) and a degenerate triangle (its three
    edge volumes 0) never cross: proximity handles them.

    Returns (hit, s, wa, wb, wc): the crossing point is ``p + s(q − p)`` =
    ``wa·a + wb·b + wc·c`` (barycentric weights, summing to 1)."""
    vp = signed_volume(p, a, b, c)
    vq = signed_volume(q, a, b, c)
    if (vp > 0.0 and vq > 0.0) or (vp < 0.0 and vq < 0.0) or (vp == 0.0 and vq == 0.0):
        return False, -1.0, 0.0, 0.0, 0.0
    e_ab = signed_volume(p, q, a, b)
    e_bc = signed_volume(p, q, b, c)
    e_ca = signed_volume(p, q, c, a)
    pos = e_ab > 0.0 or e_bc > 0.0 or e_ca > 0.0
    neg = e_ab < 0.0 or e_bc < 0.0 or e_ca < 0.0
    if pos and neg:
        return False, -1.0, 0.0, 0.0, 0.0
    tot = e_ab + e_bc + e_ca
    if tot == 0.0:
        return False, -1.0, 0.0, 0.0, 0.0
    s = vp / (vp - vq)
    # the volume of the edge opposite a vertex weights that vertex
    return True, s, e_bc / tot, e_ca / tot, e_ab / tot


@njit
def closest_point_triangle(p, a, b, c):
    """Closest point of triangle abc to p (Ericson, Real-Time Collision Detection §5.1.5).

    Returns (wa, wb, wc) barycentric weights of the closest point."""
    ab = _sub(b, a)
    ac = _sub(c, a)
    ap = _sub(p, a)
    d1 = _dot(ab, ap)
    d2 = _dot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bp = _sub(p, b)
    d3 = _dot(ab, bp)
    d4 = _dot(ac, bp)
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return 1.0 - v, v, 0.0
    cp = _sub(p, c)
    d5 = _dot(ab, cp)
    d6 = _dot(ac, cp)
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return 1.0 - w, 0.0, w
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - w, w
    den = va + vb + vc
    if den == 0.0:  # degenerate triangle: nearest vertex
        da = _norm(ap)
        db = _norm(bp)
        dc = _norm(cp)
        if da <= db and da <= dc:
            return 1.0, 0.0, 0.0
        if db <= dc:
            return 0.0, 1.0, 0.0
        return 0.0, 0.0, 1.0
    v = vb / den
    w = vc / den
    return 1.0 - v - w, v, w


@njit
def closest_points_segments(p1, q1, p2, q2):
    """Parameters (s, t) ∈ [0, 1]² of the closest points ``p1 + s(q1 − p1)``, ``p2 + t(q2 − p2)``
    of two segments (Ericson §5.1.9), robust to degenerate and parallel segments."""
    d1 = _sub(q1, p1)
    d2 = _sub(q2, p2)
    r = _sub(p1, p2)
    a = _dot(d1, d1)
    e = _dot(d2, d2)
    f = _dot(d2, r)
    eps = 1e-30
    if a <= eps and e <= eps:
        return 0.0, 0.0
    if a <= eps:
        return 0.0, min(max(f / e, 0.0), 1.0)
    c = _dot(d1, r)
    if e <= eps:
        return min(max(-c / a, 0.0), 1.0), 0.0
    b = _dot(d1, d2)
    den = a * e - b * b
    s = min(max((b * f - c * e) / den, 0.0), 1.0) if den > 1e-12 * a * e else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t = 0.0
        s = min(max(-c / a, 0.0), 1.0)
    elif t > 1.0:
        t = 1.0
        s = min(max((b - c) / a, 0.0), 1.0)
    return s, t


# ============================================================================ rigid-triangle impulse
@njit
def _inv3_sym(I):
    """Inverse of a 3×3 matrix given as a 9-tuple (row major); (ok, inverse 9-tuple)."""
    a, b, c, d, e, f, g, h, k = I
    A = e * k - f * h
    B = -(d * k - f * g)
    C = d * h - e * g
    det = a * A + b * B + c * C
    scale = abs(a) + abs(e) + abs(k)
    if scale == 0.0 or abs(det) <= 1e-12 * scale * scale * scale:
        return False, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    inv = 1.0 / det
    return True, (A * inv, -(b * k - c * h) * inv, (b * f - c * e) * inv,
                  B * inv, (a * k - c * g) * inv, -(a * f - c * d) * inv,
                  C * inv, -(a * h - b * g) * inv, (a * e - b * d) * inv)


@njit
def _mat_vec(M, u):
    return (M[0] * u[0] + M[1] * u[1] + M[2] * u[2],
            M[3] * u[0] + M[4] * u[1] + M[5] * u[2],
            M[6] * u[0] + M[7] * u[1] + M[8] * u[2])


@njit
def triangle_rigid_body(xa, xb, xc, ma, mb, mc):
    """(total mass M (g), centre of mass x_c, ok, I⁻¹ as a 9-tuple) of three point masses.

    ``I = Σ m_i(|r_i|²𝟙 − r_i r_iᵀ)`` about x_c (g·cm²); ``ok`` is False for a
    degenerate (collinear) triangle, whose inertia is singular."""
    M = ma + mb + mc
    xc_ = _scale(_add(_add(_scale(xa, ma), _scale(xb, mb)), _scale(xc, mc)), 1.0 / M)
    I0 = I1 = I2 = I4 = I5 = I8 = 0.0
    for k in range(3):
        if k == 0:
            r = _sub(xa, xc_)
            m = ma
        elif k == 1:
            r = _sub(xb, xc_)
            m = mb
        else:
            r = _sub(xc, xc_)
            m = mc
        rr = _dot(r, r)
        I0 += m * (rr - r[0] * r[0])
        I4 += m * (rr - r[1] * r[1])
        I8 += m * (rr - r[2] * r[2])
        I1 -= m * r[0] * r[1]
        I2 -= m * r[0] * r[2]
        I5 -= m * r[1] * r[2]
    ok, Iinv = _inv3_sym((I0, I1, I2, I1, I4, I5, I2, I5, I8))
    return M, xc_, ok, Iinv


@njit
def impulse_response(w_p, contact, n, Mtri, xcm, ok, Iinv, angular, exact, v_rel, e):
    """Impulse magnitude j (g·cm/s) of the rigid-triangle response (docs/physics.md, collision) and the angular-velocity change per unit j.

    ``w_p``: inverse mass of the striking vertex (1/g). The triangle B (mass
    Mtri, centre xcm, inverse inertia Iinv; Mtri = inf for a static one) gets
    ``−J = −j·n`` at ``contact``. Returns (j, dω/dj (3-tuple), 1/M)."""
    inv_M = 0.0 if Mtri == math.inf else 1.0 / Mtri
    rot = angular and ok and inv_M > 0.0
    r_p = _sub(contact, xcm)
    dw = (0.0, 0.0, 0.0)
    ang = 0.0
    if rot:
        dw = _scale(_mat_vec(Iinv, _cross(r_p, n)), -1.0)  # ω change per unit j: I⁻¹(r_p × (−n))
        ang = -_dot(n, _cross(dw, r_p))  # n·((I⁻¹(r_p × n)) × r_p) ≥ 0
    den = w_p + inv_M + (ang if exact else 0.0)
    if den <= 0.0:
        return 0.0, dw, inv_M
    return -(1.0 + e) * v_rel / den, dw, inv_M


@njit
def apply_triangle_impulse(v, ia, ib, ic, xa, xb, xc, xcm, j, n, dw, inv_M, w_p, ip, out_scale):
    """Add the velocity changes of an impulse ``J = j·n`` on vertex ip and ``−J`` on the rigid
    triangle (ia, ib, ic) to ``v`` (each scaled by ``out_scale``; 1 for velocities, a step
    length for a position correction): ``Δv_p = J·w_p``, ``Δv_i = −J/M + (j·dω) × r_i``."""
    if w_p > 0.0:
        for k in range(3):
            v[ip, k] += out_scale * j * w_p * n[k]
    if inv_M == 0.0:
        return
    om = _scale(dw, j)
    for t in range(3):
        if t == 0:
            i = ia
            r = _sub(xa, xcm)
        elif t == 1:
            i = ib
            r = _sub(xb, xcm)
        else:
            i = ic
            r = _sub(xc, xcm)
        wr = _cross(om, r)
        for k in range(3):
            v[i, k] += out_scale * (-j * inv_M * n[k] + wr[k])


# ============================================================================ spatial hash
@njit
def _hash(i, j, k, mask):
    return ((i * 73856093) ^ (j * 19349663) ^ (k * 83492791)) & mask


@njit
def _cell_range(lo, hi, b, inv_cell):
    """Index ranges (i0, i1, j0, j1, k0, k1), inclusive, of the hash cells that AABB b covers."""
    return (int(math.floor(lo[b, 0] * inv_cell)), int(math.floor(hi[b, 0] * inv_cell)),
            int(math.floor(lo[b, 1] * inv_cell)), int(math.floor(hi[b, 1] * inv_cell)),
            int(math.floor(lo[b, 2] * inv_cell)), int(math.floor(hi[b, 2] * inv_cell)))


@njit
def hash_build(lo, hi, inv_cell, table_start, items, count):
    """Insert item b with AABB [lo[b], hi[b]] into every cell it covers.

    ``table_start`` (T + 1,) with T a power of two; ``items`` must hold all
    entries (call with ``count`` = −1 first to get the number needed). Returns the
    number of entries."""
    T = table_start.shape[0] - 1
    mask = T - 1
    table_start[:] = 0
    total = 0
    for b in range(lo.shape[0]):
        i0, i1, j0, j1, k0, k1 = _cell_range(lo, hi, b, inv_cell)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                for k in range(k0, k1 + 1):
                    table_start[_hash(i, j, k, mask) + 1] += 1
                    total += 1
    if count < 0 or total > items.shape[0]:
        return total
    for t in range(T):
        table_start[t + 1] += table_start[t]
    fill = table_start[:-1].copy()
    for b in range(lo.shape[0]):
        i0, i1, j0, j1, k0, k1 = _cell_range(lo, hi, b, inv_cell)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                for k in range(k0, k1 + 1):
                    h = _hash(i, j, k, mask)
                    items[fill[h]] = b
                    fill[h] += 1
    return total


@njit
def _overlap(lo, hi, a, b):
    return (lo[a, 0] <= hi[b, 0] and lo[b, 0] <= hi[a, 0] and lo[a, 1] <= hi[b, 1] and lo[b, 1] <= hi[a, 1]
            and lo[a, 2] <= hi[b, 2] and lo[b, 2] <= hi[a, 2])


@njit
def candidate_pairs(qlo, qhi, lo, hi, inv_cell, table_start, items, stamp, pairs, skip_same):
    """Pairs (query a, item b) whose AABBs overlap, found through the hash; returns how many
    (all are written when ``pairs`` is large enough). ``skip_same``: drop b ≤ a (queries and
    items are the same set)."""
    T = table_start.shape[0] - 1
    mask = T - 1
    stamp[:] = -1
    npairs = 0
    for a in range(qlo.shape[0]):
        i0, i1, j0, j1, k0, k1 = _cell_range(qlo, qhi, a, inv_cell)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                for k in range(k0, k1 + 1):
                    h = _hash(i, j, k, mask)
                    for e in range(table_start[h], table_start[h + 1]):
                        b = items[e]
                        if stamp[b] == a or (skip_same and b <= a):
                            continue
                        stamp[b] = a
                        if (qlo[a, 0] <= hi[b, 0] and lo[b, 0] <= qhi[a, 0] and qlo[a, 1] <= hi[b, 1]
                                and lo[b, 1] <= qhi[a, 1] and qlo[a, 2] <= hi[b, 2] and lo[b, 2] <= qhi[a, 2]):
                            if npairs < pairs.shape[0]:
                                pairs[npairs, 0] = a
                                pairs[npairs, 1] = b
                            npairs += 1
    return npairs


@njit
def swept_aabbs(x0, x1, idx, pad, lo, hi):
    """AABB of the points ``idx[b, :]`` at both times, inflated by ``pad`` (cm)."""
    for b in range(idx.shape[0]):
        for k in range(3):
            m = math.inf
            M = -math.inf
            for t in range(idx.shape[1]):
                p = idx[b, t]
                m = min(m, x0[p, k], x1[p, k])
                M = max(M, x0[p, k], x1[p, k])
            lo[b, k] = m - pad
            hi[b, k] = M + pad


@njit
def find_pairs(qlo, qhi, lo, hi, skip_same):
    """Broad phase: overlapping (query, item) AABB pairs through a spatial hash (cell = the
    largest item extent). Returns an (P, 2) array."""
    nb = lo.shape[0]
    ext = 1e-6
    for b in range(nb):
        for k in range(3):
            ext = max(ext, hi[b, k] - lo[b, k])
    for a in range(qlo.shape[0]):
        for k in range(3):
            ext = max(ext, qhi[a, k] - qlo[a, k])
    inv_cell = 1.0 / ext
    T = 64
    while T < 2 * nb:
        T *= 2
    table_start = np.zeros(T + 1, dtype=np.int64)
    n = hash_build(lo, hi, inv_cell, table_start, np.zeros(0, dtype=np.int64), -1)
    items = np.empty(n, dtype=np.int64)
    hash_build(lo, hi, inv_cell, table_start, items, 1)
    stamp = np.empty(nb, dtype=np.int64)
    pairs = np.empty((max(16, 8 * qlo.shape[0]), 2), dtype=np.int64)
    k = candidate_pairs(qlo, qhi, lo, hi, inv_cell, table_start, items, stamp, pairs, skip_same)
    if k > pairs.shape[0]:
        pairs = np.empty((k, 2), dtype=np.int64)
        candidate_pairs(qlo, qhi, lo, hi, inv_cell, table_start, items, stamp, pairs, skip_same)
    return pairs[:k]


# ============================================================================ self-collision
@njit
def _unit_normal(a, b, c):
    n = _cross(_sub(b, a), _sub(c, a))
    L = _norm(n)
    if L == 0.0:
        return False, (0.0, 0.0, 1.0)
    return True, _scale(n, 1.0 / L)


@njit
def _bary(x, i, j, k, wa, wb, wc):
    return (wa * x[i, 0] + wb * x[j, 0] + wc * x[k, 0],
            wa * x[i, 1] + wb * x[j, 1] + wc * x[k, 1],
            wa * x[i, 2] + wb * x[j, 2] + wc * x[k, 2])


@njit
def vertex_triangle_contact(p, ia, ib, ic, x0, x, thickness):
    """Narrow phase of one vertex–triangle pair (docs/physics.md, collision).

    Continuous: the vertex's motion relative to the triangle (its displacement
    minus the triangle's mean displacement) is tested against the triangle at
    the start of the step with :func:`segment_triangle`. Proximity: at the end
    of the step the vertex is within ``thickness`` of the triangle. The normal
    points to the side the vertex came from.

    Returns (kind, wa, wb, wc, n): kind 0 none, 1 crossing, 2 proximity."""
    P0 = _row(x0, p)
    a0 = _row(x0, ia)
    b0 = _row(x0, ib)
    c0 = _row(x0, ic)
    a1 = _row(x, ia)
    b1 = _row(x, ib)
    c1 = _row(x, ic)
    ok0, n0 = _unit_normal(a0, b0, c0)
    ok1, n1 = _unit_normal(a1, b1, c1)
    if not ok1:
        return 0, 0.0, 0.0, 0.0, n1
    side = _dot(n0, _sub(P0, a0)) if ok0 else _dot(n1, _sub(P0, a1))
    flip = _dot(n0, n1) if ok0 else 1.0
    sgn = 1.0 if side * flip >= 0.0 else -1.0
    n = _scale(n1, sgn)
    d_t = _scale(_add(_add(_sub(a1, a0), _sub(b1, b0)), _sub(c1, c0)), 1.0 / 3.0)
    P1 = _sub(_row(x, p), d_t)
    hit, s, wa, wb, wc = segment_triangle(P0, P1, a0, b0, c0)
    if hit:
        return 1, wa, wb, wc, n
    X = _row(x, p)
    if abs(_dot(n1, _sub(X, a1))) >= thickness:
        return 0, 0.0, 0.0, 0.0, n  # the common case: off the plane by more than the thickness
    wa, wb, wc = closest_point_triangle(X, a1, b1, c1)
    q = _bary(x, ia, ib, ic, wa, wb, wc)
    if _norm(_sub(X, q)) < thickness and wa > 0.0 and wb > 0.0 and wc > 0.0:
        return 2, wa, wb, wc, n
    return 0, 0.0, 0.0, 0.0, n


@njit
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
    xa = _row(x, ia)
    xb = _row(x, ib)
    xc = _row(x, ic)
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
    vrel = _sub(_row(v, p), vb)
    vn = _dot(n, vrel)
    if vn < 0.0:
        ee = e if -vn > RESTING_SPEED else 0.0
        j, dw, inv_M = impulse_response(w_p, contact, n, Mtri, xcm, ok, Iinv, angular, exact, vn, ee)
        apply_triangle_impulse(v, ia, ib, ic, xa, xb, xc, xcm, j, n, dw, inv_M, w_p, p, 1.0)
        apply_triangle_impulse(x, ia, ib, ic, xa, xb, xc, xcm, j, n, dw, inv_M, w_p, p, h_pos)
        # friction: tangential impulse ≤ μ j, translational distribution (conserves linear momentum)
        if mu > 0.0 and j > 0.0:
            vb = _bary(v, ia, ib, ic, wa, wb, wc)
            vrel = _sub(_row(v, p), vb)
            vt = _sub(vrel, _scale(n, _dot(n, vrel)))
            L = _norm(vt)
            den = w_p + inv_M
            if L > 0.0 and den > 0.0:
                jt = min(mu * j, L / den)
                tdir = _scale(vt, -1.0 / L)
                apply_triangle_impulse(v, ia, ib, ic, xa, xb, xc, xcm, jt, tdir, (0.0, 0.0, 0.0), inv_M, w_p, p, 1.0)
                apply_triangle_impulse(x, ia, ib, ic, xa, xb, xc, xcm, jt, tdir, (0.0, 0.0, 0.0), inv_M, w_p, p,
                                       h_pos)
        changed = 1
    # position correction to the thickness (same rigid distribution, unit restitution-free "impulse")
    contact = _bary(x, ia, ib, ic, wa, wb, wc)
    gap = _dot(n, _sub(_row(x, p), contact))
    if gap < thickness * (1.0 - GAP_TOL):
        j, dw, inv_M = impulse_response(w_p, contact, n, Mtri, xcm, ok, Iinv, angular, True,
                                        -(thickness - gap), 0.0)
        apply_triangle_impulse(x, ia, ib, ic, xa, xb, xc, xcm, j, n, dw, inv_M, w_p, p, 1.0)
        changed = 1
    return changed


@njit
def edge_edge_contact(e1a, e1b, e2a, e2b, x0, x, thickness):
    """Narrow phase of two edges: (kind, s, t, n) with the closest-point parameters s on
    edge 1 and t on edge 2 and n pointing from edge 1 to edge 2 (their side at the start).

    Continuous: the four points' signed volume changes sign over the step and, at the
    linearly interpolated coplanar instant, the edges are within ``thickness``. Proximity:
    within ``thickness`` at the end. kind 0 none, 1 crossing, 2 proximity."""
    A0 = _row(x0, e1a)
    B0 = _row(x0, e1b)
    C0 = _row(x0, e2a)
    D0 = _row(x0, e2b)
    A1 = _row(x, e1a)
    B1 = _row(x, e1b)
    C1 = _row(x, e2a)
    D1 = _row(x, e2b)
    V0 = signed_volume(A0, B0, C0, D0)
    V1 = signed_volume(A1, B1, C1, D1)
    crossing = V0 * V1 < 0.0
    s1, t1 = closest_points_segments(A1, B1, C1, D1)
    P1 = _add(A1, _scale(_sub(B1, A1), s1))
    Q1 = _add(C1, _scale(_sub(D1, C1), t1))
    d1 = _sub(Q1, P1)
    L1 = _norm(d1)
    if not crossing and L1 >= thickness:
        return 0, 0.0, 0.0, (0.0, 0.0, 1.0)  # the common case: apart at the end, no sign change
    s0, t0 = closest_points_segments(A0, B0, C0, D0)
    P = _add(A0, _scale(_sub(B0, A0), s0))
    Q = _add(C0, _scale(_sub(D0, C0), t0))
    dvec = _sub(Q, P)
    L0 = _norm(dvec)
    if L0 > 1e-12:
        n = _scale(dvec, 1.0 / L0)
    elif L1 > 1e-12:
        n = _scale(d1, 1.0 / L1)
    else:
        return 0, 0.0, 0.0, (0.0, 0.0, 1.0)
    if crossing:
        f = V0 / (V0 - V1)
        Af = _add(A0, _scale(_sub(A1, A0), f))
        Bf = _add(B0, _scale(_sub(B1, B0), f))
        Cf = _add(C0, _scale(_sub(C1, C0), f))
        Df = _add(D0, _scale(_sub(D1, D0), f))
        sf, tf = closest_points_segments(Af, Bf, Cf, Df)
        Pf = _add(Af, _scale(_sub(Bf, Af), sf))
        Qf = _add(Cf, _scale(_sub(Df, Cf), tf))
        if _norm(_sub(Qf, Pf)) < thickness and 0.0 < sf < 1.0 and 0.0 < tf < 1.0:
            return 1, sf, tf, n
    if L1 < thickness and 0.0 < s1 < 1.0 and 0.0 < t1 < 1.0:
        return 2, s1, t1, n
    return 0, 0.0, 0.0, n


@njit
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


@njit
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
        vrel = _add(vrel, _scale(_row(v, idx[k]), sg[k] * w[k]))
    vn = _dot(vrel, n)
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
                vrel = _add(vrel, _scale(_row(v, idx[k]), sg[k] * w[k]))
            vt = _sub(vrel, _scale(n, _dot(vrel, n)))
            L = _norm(vt)
            if L > 0.0:
                jt = min(mu * j, L / den)
                tdir = _scale(vt, -1.0 / L)
                for k in range(4):
                    c = sg[k] * jt * w[k] * inv_mass[idx[k]]
                    for d in range(3):
                        v[idx[k], d] += c * tdir[d]
                        x[idx[k], d] += h_pos * c * tdir[d]
        changed = 1
    P = (0.0, 0.0, 0.0)
    for k in range(4):
        P = _add(P, _scale(_row(x, idx[k]), sg[k] * w[k]))
    gap = _dot(P, n)
    if gap < thickness * (1.0 - GAP_TOL):
        j = _capped_impulse(thickness - gap, den, w, idx, inv_mass)
        for k in range(4):
            c = sg[k] * j * w[k] * inv_mass[idx[k]]
            for d in range(3):
                x[idx[k], d] += c * n[d]
        changed = 1
    return changed


@njit
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


@njit
def _max_shift(x, ref):
    m = 0.0
    for p in range(x.shape[0]):
        d = (x[p, 0] - ref[p, 0]) ** 2 + (x[p, 1] - ref[p, 1]) ** 2 + (x[p, 2] - ref[p, 2]) ** 2
        if not d <= m:  # also catches NaN and inf (the first call: ref = inf)
            m = d
    return math.sqrt(m)


@njit
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
        ref_x[:] = x
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
@njit
def collide_mesh(x, v, x0, inv_mass, mv, mf, mn, mmu, g_lo, g_inv_cell, g_dims, g_start, g_items, restitution,
                 thickness, stamp):
    """Particle contact with static triangle-mesh obstacles (infinite mass).

    Per particle: continuous detection of its segment x0 → x against the mesh's
    triangles (:func:`segment_triangle`, exact for static triangles), entering a
    face from its front (outward normal ``mn``); a crossing puts the particle back
    at the crossing point lifted by ``thickness`` along the face normal, keeping the
    tangential rest of its motion. Then proximity: the nearest face whose front
    the particle is on and which is within ``thickness`` pushes it out to
    ``thickness`` along the direction from the nearest point. The normal velocity
    ``v_n < 0`` becomes ``−e·v_n``, and Coulomb friction (the face's obstacle μ)
    acts on the tangential velocity, as for analytic obstacles.

    Broad phase: a static uniform grid (built once per model) of the mesh faces,
    ``g_start``/``g_items`` in CSR form; a particle's candidate faces are gathered once
    and shared by the continuous test and both proximity passes. Returns the number of particles in contact."""
    nx = g_dims[0]
    ny = g_dims[1]
    nz = g_dims[2]
    count = 0
    stamp[:] = -1
    qid = 0
    cand = np.empty(stamp.shape[0], dtype=np.int64)
    for p in range(x.shape[0]):
        if inv_mass[p] == 0.0:
            continue
        P0 = _row(x0, p)
        P1 = _row(x, p)
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
            continue
        # ---- candidate faces: those binned in the cells the swept segment touches (each once)
        nc = 0
        qid += 1
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
        # ---- continuous: earliest front-side crossing
        best_s = 2.0
        best_f = -1
        for m in range(nc):
            f = cand[m]
            a = _row(mv, mf[f, 0])
            n = _row(mn, f)
            if _dot(n, _sub(P0, a)) <= 0.0:
                continue  # came from behind: not an entry
            hit, s, wa, wb, wc = segment_triangle(P0, P1, a, _row(mv, mf[f, 1]), _row(mv, mf[f, 2]))
            if hit and s < best_s:
                best_s = s
                best_f = f
        touched = -1
        tn = (0.0, 0.0, 1.0)
        if best_f >= 0:
            n = _row(mn, best_f)
            r = _scale(_sub(P1, P0), 1.0 - best_s)
            E = _add(P0, _scale(_sub(P1, P0), best_s))
            rn = min(_dot(r, n), 0.0)
            X = _add(_add(E, _sub(r, _scale(n, rn))), _scale(n, thickness))
            for d in range(3):
                x[p, d] = X[d]
            touched = best_f
            tn = n
        # ---- proximity at the end of the step (two passes for concave corners)
        for _pass in range(2):
            X = _row(x, p)
            best_d = thickness * 1.01 + 1e-9
            best_f = -1
            best_q = X
            for m in range(nc):
                f = cand[m]
                a = _row(mv, mf[f, 0])
                b = _row(mv, mf[f, 1])
                cc = _row(mv, mf[f, 2])
                if _dot(_row(mn, f), _sub(X, a)) < 0.0:
                    continue  # behind the face
                wa, wb, wc = closest_point_triangle(X, a, b, cc)
                q = _add(_add(_scale(a, wa), _scale(b, wb)), _scale(cc, wc))
                d = _norm(_sub(X, q))
                if d < best_d:
                    best_d = d
                    best_f = f
                    best_q = q
            if best_f < 0:
                break
            if best_d > 1e-9:
                nn = _scale(_sub(X, best_q), 1.0 / best_d)
            else:
                nn = _row(mn, best_f)
            if best_d < thickness:
                X = _add(best_q, _scale(nn, thickness))
                for d in range(3):
                    x[p, d] = X[d]
            touched = best_f
            tn = nn
        if touched < 0:
            continue
        count += 1
        vv = _row(v, p)
        vn = _dot(vv, tn)
        if vn < 0.0:
            e = restitution if -vn > RESTING_SPEED else 0.0
            dvn = -(1.0 + e) * vn
            vt = _sub(vv, _scale(tn, vn))
            L = _norm(vt)
            sc = 0.0
            if L > 0.0:
                sc = max(0.0, 1.0 - mmu[touched] * dvn / L)
            for d in range(3):
                v[p, d] = vt[d] * sc - e * vn * tn[d]
    return count


@njit
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
