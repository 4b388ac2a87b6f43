"""Geometry of the collision pass: small 3-vector algebra on tuples (so predicates compile to
straight-line code), the exact predicates of continuous collision detection (signed volumes,
segment against triangle, closest points) and the spatial hash of the broad phase.

Positions in cm; every kernel works on plain arrays and tuples.
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import kernel_only


# ============================================================================ small vector algebra
@kernel_only
def vsub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@kernel_only
def vadd(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@kernel_only
def vscale(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


@kernel_only
def vdot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@kernel_only
def vcross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@kernel_only
def vrow(x, i):
    return (x[i, 0], x[i, 1], x[i, 2])


@kernel_only
def vnorm(a):
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


# ============================================================================ predicates
@kernel_only
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
    ap = vsub(a, p)
    bp = vsub(b, p)
    cp = vsub(c, p)
    return -vdot(ap, vcross(bp, cp))


@kernel_only
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


@kernel_only
def closest_point_triangle(p, a, b, c):
    """Closest point of triangle abc to p (Ericson, Real-Time Collision Detection §5.1.5).

    Returns (wa, wb, wc) barycentric weights of the closest point."""
    ab = vsub(b, a)
    ac = vsub(c, a)
    ap = vsub(p, a)
    d1 = vdot(ab, ap)
    d2 = vdot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bp = vsub(p, b)
    d3 = vdot(ab, bp)
    d4 = vdot(ac, bp)
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return 1.0 - v, v, 0.0
    cp = vsub(p, c)
    d5 = vdot(ab, cp)
    d6 = vdot(ac, cp)
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
        da = vnorm(ap)
        db = vnorm(bp)
        dc = vnorm(cp)
        if da <= db and da <= dc:
            return 1.0, 0.0, 0.0
        if db <= dc:
            return 0.0, 1.0, 0.0
        return 0.0, 0.0, 1.0
    v = vb / den
    w = vc / den
    return 1.0 - v - w, v, w


@kernel_only
def closest_points_segments(p1, q1, p2, q2):
    """Parameters (s, t) ∈ [0, 1]² of the closest points ``p1 + s(q1 − p1)``, ``p2 + t(q2 − p2)``
    of two segments (Ericson §5.1.9), robust to degenerate and parallel segments."""
    d1 = vsub(q1, p1)
    d2 = vsub(q2, p2)
    r = vsub(p1, p2)
    a = vdot(d1, d1)
    e = vdot(d2, d2)
    f = vdot(d2, r)
    eps = 1e-30
    if a <= eps and e <= eps:
        return 0.0, 0.0
    if a <= eps:
        return 0.0, min(max(f / e, 0.0), 1.0)
    c = vdot(d1, r)
    if e <= eps:
        return min(max(-c / a, 0.0), 1.0), 0.0
    b = vdot(d1, d2)
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


# ============================================================================ spatial hash
@kernel_only
def _hash(i, j, k, mask):
    return ((i * 73856093) ^ (j * 19349663) ^ (k * 83492791)) & mask


@kernel_only
def _cell_range(lo, hi, b, inv_cell):
    """Index ranges (i0, i1, j0, j1, k0, k1), inclusive, of the hash cells that AABB b covers."""
    return (int(math.floor(lo[b, 0] * inv_cell)), int(math.floor(hi[b, 0] * inv_cell)),
            int(math.floor(lo[b, 1] * inv_cell)), int(math.floor(hi[b, 1] * inv_cell)),
            int(math.floor(lo[b, 2] * inv_cell)), int(math.floor(hi[b, 2] * inv_cell)))


@kernel_only
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


@kernel_only
def _overlap(lo, hi, a, b):
    return (lo[a, 0] <= hi[b, 0] and lo[b, 0] <= hi[a, 0] and lo[a, 1] <= hi[b, 1] and lo[b, 1] <= hi[a, 1]
            and lo[a, 2] <= hi[b, 2] and lo[b, 2] <= hi[a, 2])


@kernel_only
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


@kernel_only
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


@kernel_only
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
