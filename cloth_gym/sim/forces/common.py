"""Scalar helpers shared by the force laws: the regularised square root of the KES polynomials,
small vector products, and the geometry of an angle at a particle."""

from __future__ import annotations

import math


from .._numba import kernel_only

PI = math.pi


@kernel_only
def reg_root(x, x0):
    """Regularised square root ``x / sqrt(x + x0)`` (= sqrt(x) for x0 = 0), x ≥ 0."""
    if x0 > 0.0:
        return x / math.sqrt(x + x0)
    return math.sqrt(x)


@kernel_only
def reg_root_deriv(x, x0):
    """d/dx of :func:`reg_root`."""
    if x0 > 0.0:
        r = math.sqrt(x + x0)
        return (x + 2.0 * x0) / (2.0 * r * r * r)
    return 0.5 / math.sqrt(x) if x > 0.0 else math.inf


@kernel_only
def kes_poly(x, c0, c1, c2, x0):
    """``c0·x^½ + c1·x + c2·x²`` with the regularised root, x ≥ 0."""
    return c0 * reg_root(x, x0) + c1 * x + c2 * x * x


@kernel_only
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@kernel_only
def edge_vector(x, a, b):
    """(d0, d1, d2, r): ``x_b − x_a`` and its length, cm."""
    d0 = x[b, 0] - x[a, 0]
    d1 = x[b, 1] - x[a, 1]
    d2 = x[b, 2] - x[a, 2]
    return d0, d1, d2, math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@kernel_only
def angle_geometry(x, a, b, c, chain):
    """Vectors of the angle at particle b and their cross product.

    ``chain=True`` (bend triple a–b–c): ``u = x_b − x_a``, ``w = x_c − x_b`` (ψ = angle(u, w)).
    ``chain=False`` (shear corner): ``u = x_a − x_b``, ``w = x_c − x_b`` (γ = angle(u, w)).
    Returns (u0, u1, u2, w0, w1, w2, n0, n1, n2, |u × w|, |u|², |w|²), n = u × w (not normalised).
    """
    if chain:
        u0 = x[b, 0] - x[a, 0]
        u1 = x[b, 1] - x[a, 1]
        u2 = x[b, 2] - x[a, 2]
    else:
        u0 = x[a, 0] - x[b, 0]
        u1 = x[a, 1] - x[b, 1]
        u2 = x[a, 2] - x[b, 2]
    w0 = x[c, 0] - x[b, 0]
    w1 = x[c, 1] - x[b, 1]
    w2 = x[c, 2] - x[b, 2]
    n0, n1, n2 = _cross(u0, u1, u2, w0, w1, w2)
    s = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    return (u0, u1, u2, w0, w1, w2, n0, n1, n2, s, u0 * u0 + u1 * u1 + u2 * u2, w0 * w0 + w1 * w1 + w2 * w2)


@kernel_only
def bend_angle(x, a, b, c):
    """Bend angle ψ ∈ [0, π] of triple (a, b, c) and |e1 × e2| (cm²)."""
    e10, e11, e12, e20, e21, e22, n0, n1, n2, s, l1, l2 = angle_geometry(x, a, b, c, True)
    return math.atan2(s, e10 * e20 + e11 * e21 + e12 * e22), s


@kernel_only
def add_corner_blocks(vals, blocks, X, Y, Z):
    """Add the 3×3 blocks of ``JᵀJ`` for a three-particle element (a, b, c) whose Jacobian is
    ``[J_a, −(J_a + J_c), J_c]`` (bending triples, shear corners) to ``vals``: ``X = J_aᵀJ_a``,
    ``Y = J_cᵀJ_c``, ``Z = J_aᵀJ_c`` (all scaled by the element's stiffness), ``blocks`` the
    element's nine block indices (a, b, c) × (a, b, c), row-major."""
    aa, ab, ac = blocks[0], blocks[1], blocks[2]
    ba, bb, bc = blocks[3], blocks[4], blocks[5]
    ca, cb, cc = blocks[6], blocks[7], blocks[8]
    for i in range(3):
        for j in range(3):
            xij, yij, zij, zji = X[i, j], Y[i, j], Z[i, j], Z[j, i]
            vals[aa, i, j] += xij
            vals[cc, i, j] += yij
            vals[ac, i, j] += zij
            vals[ca, i, j] += zji
            vals[ab, i, j] -= xij + zij
            vals[ba, i, j] -= xij + zji
            vals[cb, i, j] -= zji + yij
            vals[bc, i, j] -= zij + yij
            vals[bb, i, j] += xij + zij + zji + yij


@kernel_only
def damp_three_particle_element(u, a, b, c, g, coef, f):
    """Add ``−coef·(g·u)·g`` to ``f`` for a three-particle element (a, b, c) whose strain measure
    has gradient ``g`` = (g_a, g_c) (6,) and ``g_b = −(g_a + g_c)``: the strain-rate damping force
    of a bending triple or shear corner (``coef`` = β·k, g·s·cm)."""
    rate = 0.0
    for i in range(3):
        rate += g[i] * (u[a, i] - u[b, i]) + g[3 + i] * (u[c, i] - u[b, i])
    s = coef * rate
    for i in range(3):
        f[a, i] -= s * g[i]
        f[c, i] -= s * g[3 + i]
        f[b, i] += s * (g[i] + g[3 + i])
