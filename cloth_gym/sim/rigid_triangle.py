"""The paper's collision response: a triangle hit by a particle or an edge moves as a rigid body
at the impact. :func:`triangle_rigid_body` gives its mass, centre of mass and inverse inertia
from its three particles; :func:`impulse_response` the impulse's magnitude (the paper's eq. (22),
or Baraff's exact one with ``exact``) and the triangle's change of angular velocity (with
``angular``); :func:`apply_triangle_impulse` spreads the triangle's new rigid motion over its
particles. Positions in cm, velocities in cm/s, masses in g.
"""

from __future__ import annotations

import math

from ._numba import kernel_only
from .geometry import vadd, vcross, vdot, vscale, vsub


@kernel_only
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


@kernel_only
def _mat_vec(M, u):
    return (M[0] * u[0] + M[1] * u[1] + M[2] * u[2],
            M[3] * u[0] + M[4] * u[1] + M[5] * u[2],
            M[6] * u[0] + M[7] * u[1] + M[8] * u[2])


@kernel_only
def triangle_rigid_body(xa, xb, xc, ma, mb, mc):
    """(total mass M (g), centre of mass x_c, ok, I⁻¹ as a 9-tuple) of three point masses.

    ``I = Σ m_i(|r_i|²𝟙 − r_i r_iᵀ)`` about x_c (g·cm²); ``ok`` is False for a
    degenerate (collinear) triangle, whose inertia is singular."""
    M = ma + mb + mc
    xc_ = vscale(vadd(vadd(vscale(xa, ma), vscale(xb, mb)), vscale(xc, mc)), 1.0 / M)
    I0 = I1 = I2 = I4 = I5 = I8 = 0.0
    for k in range(3):
        if k == 0:
            r = vsub(xa, xc_)
            m = ma
        elif k == 1:
            r = vsub(xb, xc_)
            m = mb
        else:
            r = vsub(xc, xc_)
            m = mc
        rr = vdot(r, r)
        I0 += m * (rr - r[0] * r[0])
        I4 += m * (rr - r[1] * r[1])
        I8 += m * (rr - r[2] * r[2])
        I1 -= m * r[0] * r[1]
        I2 -= m * r[0] * r[2]
        I5 -= m * r[1] * r[2]
    ok, Iinv = _inv3_sym((I0, I1, I2, I1, I4, I5, I2, I5, I8))
    return M, xc_, ok, Iinv


@kernel_only
def impulse_response(w_p, contact, n, Mtri, xcm, ok, Iinv, angular, exact, v_rel, e):
    """Impulse magnitude j (g·cm/s) of the rigid-triangle response (docs/physics.md, collision) and the angular-velocity change per unit j.

    ``w_p``: inverse mass of the striking vertex (1/g). The triangle B (mass
    Mtri, centre xcm, inverse inertia Iinv; Mtri = inf for a static one) gets
    ``−J = −j·n`` at ``contact``. Returns (j, dω/dj (3-tuple), 1/M)."""
    inv_M = 0.0 if Mtri == math.inf else 1.0 / Mtri
    rot = angular and ok and inv_M > 0.0
    r_p = vsub(contact, xcm)
    dw = (0.0, 0.0, 0.0)
    ang = 0.0
    if rot:
        dw = vscale(_mat_vec(Iinv, vcross(r_p, n)), -1.0)  # ω change per unit j: I⁻¹(r_p × (−n))
        ang = -vdot(n, vcross(dw, r_p))  # n·((I⁻¹(r_p × n)) × r_p) ≥ 0
    den = w_p + inv_M + (ang if exact else 0.0)
    if den <= 0.0:
        return 0.0, dw, inv_M
    return -(1.0 + e) * v_rel / den, dw, inv_M


@kernel_only
def apply_triangle_impulse(v, ia, ib, ic, xa, xb, xc, xcm, j, n, dw, inv_M, w_p, ip, out_scale):
    """Add the velocity changes of an impulse ``J = j·n`` on vertex ip and ``−J`` on the rigid
    triangle (ia, ib, ic) to ``v`` (each scaled by ``out_scale``; 1 for velocities, a step
    length for a position correction): ``Δv_p = J·w_p``, ``Δv_i = −J/M + (j·dω) × r_i``."""
    if w_p > 0.0:
        for k in range(3):
            v[ip, k] += out_scale * j * w_p * n[k]
    if inv_M == 0.0:
        return
    om = vscale(dw, j)
    for t in range(3):
        if t == 0:
            i = ia
            r = vsub(xa, xcm)
        elif t == 1:
            i = ib
            r = vsub(xb, xcm)
        else:
            i = ic
            r = vsub(xc, xcm)
        wr = vcross(om, r)
        for k in range(3):
            v[i, k] += out_scale * (-j * inv_M * n[k] + wr[k])
