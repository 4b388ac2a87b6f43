"""Stretch: the lattice edges' tension, KES (warp/weft curves, softer in compression) or Breen's.

One home for the force: its scalar law and slope, the force on the particles, and its 3×3
stiffness blocks for the implicit solver (:func:`linearise_stretch`). Units: cm, dyne; strain in
percent.
"""

from __future__ import annotations

from ...units import G
from .._numba import kernel_only
from .common import edge_vector


@kernel_only
def add_pair(f, a, b, s, d0, d1, d2):
    """``f_a += s·d``, ``f_b −= s·d``: an equal and opposite pair of forces along ``d = x_b − x_a``."""
    f[a, 0] += s * d0
    f[a, 1] += s * d1
    f[a, 2] += s * d2
    f[b, 0] -= s * d0
    f[b, 1] -= s * d1
    f[b, 2] -= s * d2


@kernel_only
def kes_stretch_tension(eps, c1, c2, alpha, rest):
    """Pull (dyne, > 0 pulls the pair together) of a KES edge at strain ``eps`` (percent), eqs. (7)–(9).

    Tension: ``F̂(ε)·σ·G``; compression: ``−α·F̂(|ε|)·σ·G`` (pushes apart).
    """
    a = abs(eps)
    mag = (c1 * a + c2 * a * a) * rest * G
    if eps < 0.0:
        return -alpha * mag
    return mag


@kernel_only
def breen_stretch_tension(r, rest, c0):
    """Pull (dyne, > 0 pulls together) of Breen's eq. (1) at length ``r`` (cm)."""
    d = r - rest
    if r > rest:
        return 5.0 * c0 * d ** 4 / rest ** 5
    return -c0 * (4.0 * r + rest) * d ** 4 / (rest * rest)


@kernel_only
def kes_stretch_slope(eps, c1, c2, alpha):
    """d(pull)/dr (dyne/cm) of :func:`kes_stretch_tension`: ``100·G·(c1 + 2·c2·|ε|)``, × α in compression."""
    k = 100.0 * G * (c1 + 2.0 * c2 * abs(eps))
    return alpha * k if eps < 0.0 else k


@kernel_only
def breen_stretch_slope(r, rest, c0):
    """d(pull)/dr (dyne/cm) of :func:`breen_stretch_tension`."""
    d = r - rest
    if r > rest:
        return 20.0 * c0 * d ** 3 / rest ** 5
    return -c0 * (4.0 * d ** 4 + 4.0 * (4.0 * r + rest) * d ** 3) / (rest * rest)


@kernel_only
def eval_stretch(x, edges, edge_dir, rest, width, coef, alpha, breen, breen_c0, f):
    """Stretch edges (E, 2): KES law per direction (``coef[dir] = (c1, c2)``), or Breen's (1), each
    edge's pull times its ``width`` (the fabric it stands for, in σ: 1 inside, ½ on the outline)."""
    for e in range(edges.shape[0]):
        a = edges[e, 0]
        b = edges[e, 1]
        d0, d1, d2, r = edge_vector(x, a, b)
        if r < 1e-12:
            continue
        s = width[e] * stretch_pull(r, rest[e], edge_dir[e], coef, alpha, breen, breen_c0) / r
        add_pair(f, a, b, s, d0, d1, d2)


@kernel_only
def damp_stretch(x, u, edges, edge_dir, rest, width, coef, alpha, breen, breen_c0, beta, f):
    """Add the strain-rate damping of the edges at positions ``x`` (cm) and velocities ``u``
    (cm/s) to ``f`` (dyne): a pull ``β·k·ṙ`` along each edge, ``ṙ = d̂·(u_b − u_a)`` its rate of
    extension and ``k`` its stiffness (the clamped slope of :func:`linearise_stretch`, times its
    width). Rigid motion has ``ṙ = 0``. The force is ``−C·u`` with C the damping matrix that
    :func:`linearise_stretch` adds."""
    for e in range(edges.shape[0]):
        a = edges[e, 0]
        b = edges[e, 1]
        d0, d1, d2, r = edge_vector(x, a, b)
        if r < 1e-12:
            continue
        p, dp = stretch_pull_and_slope(r, rest[e], edge_dir[e], coef, alpha, breen, breen_c0)
        if dp <= 0.0:
            continue
        rate = (d0 * (u[b, 0] - u[a, 0]) + d1 * (u[b, 1] - u[a, 1]) + d2 * (u[b, 2] - u[a, 2])) / r
        s = beta * width[e] * dp * rate / r
        add_pair(f, a, b, s, d0, d1, d2)


@kernel_only
def stretch_pull(r, L, k, coef, alpha, breen, breen_c0):
    """Pull p(r) (dyne, > 0 pulls together) of one edge of length ``r`` (cm), rest length ``L`` (cm)
    and direction ``k``: Breen's law or the KES one of its direction."""
    if breen:
        return breen_stretch_tension(r, L, breen_c0)
    return kes_stretch_tension(100.0 * (r - L) / L, coef[k, 0], coef[k, 1], alpha, L)


@kernel_only
def stretch_pull_and_slope(r, L, k, coef, alpha, breen, breen_c0):
    """Pull p(r) (dyne, > 0 pulls together, :func:`stretch_pull`) and dp/dr (dyne/cm) of one edge."""
    if breen:
        slope = breen_stretch_slope(r, L, breen_c0)
    else:
        slope = kes_stretch_slope(100.0 * (r - L) / L, coef[k, 0], coef[k, 1], alpha)
    return stretch_pull(r, L, k, coef, alpha, breen, breen_c0), slope


@kernel_only
def linearise_stretch(x, edges, edge_dir, rest, width, coef, alpha, breen, breen_c0, damp, emap, vals):
    """Add each edge's stiffness to the block matrix ``vals`` (nnz, 3, 3), dyne/cm: with
    ``K = w·(p'(r)·d̂d̂ᵀ + (p/r)·(I − d̂d̂ᵀ))`` (w the edge's width, p the pull, d̂ the edge
    direction; both terms clamped at 0, which keeps K PSD in compression), blocks (a, a) and
    (b, b) get +K, (a, b) and (b, a) −K; ``emap (E, 4)`` holds the indices of those four blocks in
    ``vals``. ``damp`` = β/h adds the strain-rate damping matrix over h, ``damp·w·p'·d̂d̂ᵀ`` (the
    material part of K only: it does not resist rotation)."""
    for e in range(edges.shape[0]):
        d0, d1, d2, r = edge_vector(x, edges[e, 0], edges[e, 1])
        if r < 1e-12:
            continue
        p, dp = stretch_pull_and_slope(r, rest[e], edge_dir[e], coef, alpha, breen, breen_c0)
        w = width[e]
        dp = max(dp, 0.0)
        t = w * max(p / r, 0.0)
        dp = w * dp * (1.0 + damp)
        u0 = d0 / r
        u1 = d1 / r
        u2 = d2 / r
        aa, ab, ba, bb = emap[e, 0], emap[e, 1], emap[e, 2], emap[e, 3]
        u = (u0, u1, u2)
        for i in range(3):
            for j in range(3):
                k = (dp - t) * u[i] * u[j] + (t if i == j else 0.0)
                vals[aa, i, j] += k
                vals[bb, i, j] += k
                vals[ab, i, j] -= k
                vals[ba, i, j] -= k
