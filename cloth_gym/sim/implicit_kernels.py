"""Numba kernels of the implicit integrator (see :mod:`cloth_gym.sim.implicit`).

Assembly of the stiffness approximation H per force type, the matrix-free
operator ``A = diag(m̃) + h²H``, block-Jacobi and line smoothers, and the
grid-transfer and vector kernels of the PCG / multigrid solve. Every kernel
works on one lattice level: arrays in, arrays out.
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit
from .forces import (DEG_PER_RAD, G, _cross, angle_geometry, edge_vector, breen_bend_torque, breen_stretch_slope,
                     breen_stretch_tension, eval_forces, kes_bend_torque, kes_poly, kes_stretch_slope,
                     kes_stretch_tension, reg_root_deriv, vertex_normals)
from .collision_kernels import COLLISION_PASS_BITS, collision_pass
from .integrators import check_state
from .obstacles import advance_obstacles, collide_particles, moved_obstacles, signed_distance



# ============================================================================ assembly
@njit
def _stretch_pull_and_slope(r, L, k, coef, alpha, breen, breen_c0):
    """Pull p(r) (dyne, > 0 pulls together) and dp/dr (dyne/cm) of one edge."""
    if breen:
        return breen_stretch_tension(r, L, breen_c0), breen_stretch_slope(r, L, breen_c0)
    eps = 100.0 * (r - L) / L
    return (kes_stretch_tension(eps, coef[k, 0], coef[k, 1], alpha, L),
            kes_stretch_slope(eps, coef[k, 0], coef[k, 1], alpha))


@njit
def assemble_stretch(x, edges, edge_dir, rest, coef, alpha, breen, breen_c0, K):
    """Per-edge 3×3 stiffness blocks ``K (E, 3, 3)`` (dyne/cm), PSD."""
    for e in range(edges.shape[0]):
        d0, d1, d2, r = edge_vector(x, edges[e, 0], edges[e, 1])
        K[e] = 0.0
        if r < 1e-12:
            continue
        p, dp = _stretch_pull_and_slope(r, rest[e], edge_dir[e], coef, alpha, breen, breen_c0)
        dp = max(dp, 0.0)
        t = max(p / r, 0.0)
        u = (d0 / r, d1 / r, d2 / r)
        for i in range(3):
            for j in range(3):
                K[e, i, j] = (dp - t) * u[i] * u[j]
            K[e, i, i] += t


@njit
def _bend_slope(psi, c0, c1, c2, sigma, x0, breen):
    h = 1e-6
    if breen:  # Breen's torque: by central differences
        t = breen_bend_torque(psi, c0, c1, c2, sigma, x0)
        tp = breen_bend_torque(min(psi + h, math.pi), c0, c1, c2, sigma, x0)
        tm = breen_bend_torque(max(psi - h, 0.0), c0, c1, c2, sigma, x0)
        tangent = (tp - tm) / (min(psi + h, math.pi) - max(psi - h, 0.0))
    else:  # T = M̂(K)·σ·G, K = 3/(2σ)·sin(2ψ/3): dT/dψ = G·M̂'(K)·cos(2ψ/3), analytically
        t = kes_bend_torque(psi, c0, c1, c2, sigma, x0)
        K = 1.5 / sigma * math.sin(2.0 * psi / 3.0)
        if K > 1e-9:
            tangent = G * (c0 * reg_root_deriv(K, x0) + c1 + 2.0 * c2 * K) * math.cos(2.0 * psi / 3.0)
        else:  # at the flat state: the one-sided slope T(h)/h (finite also without root regularisation)
            tangent = kes_bend_torque(h, c0, c1, c2, sigma, x0) / h
    secant = t / max(psi, 1e-2)
    return max(tangent, secant, 0.0)


@njit
def assemble_bending(x, triples, bend_dir, coef, sigma, x0, breen, B, kb):
    """Per-triple data for ``k·JᵀJ``: ``B (T, 8)`` = (ê1, 1/|e1|, ê2, 1/|e2|), ``kb (T,)`` dyne·cm."""
    for t in range(triples.shape[0]):
        e10, e11, e12, e20, e21, e22, n0, n1, n2, s, l1, l2 = angle_geometry(x, triples[t, 0], triples[t, 1],
                                                                              triples[t, 2], True)
        l1 = math.sqrt(l1)
        l2 = math.sqrt(l2)
        kb[t] = 0.0
        if l1 < 1e-12 or l2 < 1e-12:
            continue
        psi = math.atan2(s, e10 * e20 + e11 * e21 + e12 * e22)
        k = bend_dir[t]
        kb[t] = _bend_slope(psi, coef[k, 0], coef[k, 1], coef[k, 2], sigma, x0, breen)
        B[t, 0] = e10 / l1
        B[t, 1] = e11 / l1
        B[t, 2] = e12 / l1
        B[t, 3] = 1.0 / l1
        B[t, 4] = e20 / l2
        B[t, 5] = e21 / l2
        B[t, 6] = e22 / l2
        B[t, 7] = 1.0 / l2


@njit
def assemble_shear(x, corners, coef, sigma, x0, breen, Sg, ks):
    """Per-corner ∇γ ``Sg (S, 9)`` (for a, b, c; 1/cm) and ``ks (S,)`` = max(dT/dφ, 0) (dyne·cm)."""
    c0 = coef[0]
    c1 = coef[1]
    c2 = coef[2]
    for t in range(corners.shape[0]):
        a0, a1, a2, b0, b1, b2, n0, n1, n2, s, la, lc = angle_geometry(x, corners[t, 0], corners[t, 1],
                                                                        corners[t, 2], False)
        ks[t] = 0.0
        if s <= 1e-12 * math.sqrt(la * lc):
            continue
        phi = math.atan2(s, a0 * b0 + a1 * b1 + a2 * b2) - 0.5 * math.pi
        # dT/d|φ| analytically: T = C·F(|φ|·D)·cos φ (KES: C = Gσ²/4; Breen: C = Gσ³/20), D = 180/π
        # (at |φ| < 1e-7 the one-sided slope T(1e-7)/1e-7: finite also without root regularisation)
        a = max(abs(phi), 1e-7)
        xd = a * DEG_PER_RAD
        F = kes_poly(xd, c0, c1, c2, x0)
        C = 0.05 * G * sigma ** 3 if breen else 0.25 * G * sigma * sigma
        if abs(phi) < 1e-7:
            ks[t] = max(C * F * math.cos(a) / a, 0.0)
        else:
            dF = c0 * reg_root_deriv(xd, x0) + c1 + 2.0 * c2 * xd
            ks[t] = max(C * (dF * DEG_PER_RAD * math.cos(a) - F * math.sin(a)), 0.0)
        n0 /= s
        n1 /= s
        n2 /= s
        ga0, ga1, ga2 = _cross(n0, n1, n2, a0, a1, a2)
        gc0, gc1, gc2 = _cross(n0, n1, n2, b0, b1, b2)
        Sg[t, 0] = -ga0 / la
        Sg[t, 1] = -ga1 / la
        Sg[t, 2] = -ga2 / la
        Sg[t, 6] = gc0 / lc
        Sg[t, 7] = gc1 / lc
        Sg[t, 8] = gc2 / lc
        Sg[t, 3] = -(Sg[t, 0] + Sg[t, 6])
        Sg[t, 4] = -(Sg[t, 1] + Sg[t, 7])
        Sg[t, 5] = -(Sg[t, 2] + Sg[t, 8])


@njit
def air_linearisation(x, v, tris, wind, c_air, sigma, normals, drag):
    """Per-particle drag coefficient ``C_air·σ²·|n·u|`` (g/s): the diagonal part of −∂F_air/∂v."""
    vertex_normals(x, tris, normals)
    s2 = c_air * sigma * sigma
    for p in range(x.shape[0]):
        un = (normals[p, 0] * (v[p, 0] - wind[0]) + normals[p, 1] * (v[p, 1] - wind[1])
              + normals[p, 2] * (v[p, 2] - wind[2]))
        drag[p] = 2.0 * s2 * abs(un)  # d(|n·u|u)/du along u is 2|n·u|


# ============================================================================ operator
@njit
def apply_H(p, edges, K, triples, B, kb, corners, Sg, ks, y):
    """``y = H·p`` (dyne/cm × cm): the stiffness approximation, matrix-free."""
    y[:] = 0.0
    for e in range(edges.shape[0]):
        a = edges[e, 0]
        b = edges[e, 1]
        for i in range(3):
            s = 0.0
            for j in range(3):
                s += K[e, i, j] * (p[a, j] - p[b, j])
            y[a, i] += s
            y[b, i] -= s
    for t in range(triples.shape[0]):
        k = kb[t]
        if k == 0.0:
            continue
        a = triples[t, 0]
        b = triples[t, 1]
        c = triples[t, 2]
        # u = J_a (p_a − p_b) + J_c (p_c − p_b),  J = (I − ê êᵀ)/|e|
        da0 = p[a, 0] - p[b, 0]
        da1 = p[a, 1] - p[b, 1]
        da2 = p[a, 2] - p[b, 2]
        dc0 = p[c, 0] - p[b, 0]
        dc1 = p[c, 1] - p[b, 1]
        dc2 = p[c, 2] - p[b, 2]
        pa = B[t, 0] * da0 + B[t, 1] * da1 + B[t, 2] * da2
        pc = B[t, 4] * dc0 + B[t, 5] * dc1 + B[t, 6] * dc2
        u0 = B[t, 3] * (da0 - pa * B[t, 0]) + B[t, 7] * (dc0 - pc * B[t, 4])
        u1 = B[t, 3] * (da1 - pa * B[t, 1]) + B[t, 7] * (dc1 - pc * B[t, 5])
        u2 = B[t, 3] * (da2 - pa * B[t, 2]) + B[t, 7] * (dc2 - pc * B[t, 6])
        ua = B[t, 0] * u0 + B[t, 1] * u1 + B[t, 2] * u2
        uc = B[t, 4] * u0 + B[t, 5] * u1 + B[t, 6] * u2
        ka = k * B[t, 3]
        kc = k * B[t, 7]
        ya0 = ka * (u0 - ua * B[t, 0])
        ya1 = ka * (u1 - ua * B[t, 1])
        ya2 = ka * (u2 - ua * B[t, 2])
        yc0 = kc * (u0 - uc * B[t, 4])
        yc1 = kc * (u1 - uc * B[t, 5])
        yc2 = kc * (u2 - uc * B[t, 6])
        y[a, 0] += ya0
        y[a, 1] += ya1
        y[a, 2] += ya2
        y[c, 0] += yc0
        y[c, 1] += yc1
        y[c, 2] += yc2
        y[b, 0] -= ya0 + yc0
        y[b, 1] -= ya1 + yc1
        y[b, 2] -= ya2 + yc2
    for t in range(corners.shape[0]):
        k = ks[t]
        if k == 0.0:
            continue
        s = 0.0
        for q in range(3):
            pid = corners[t, q]
            for i in range(3):
                s += Sg[t, 3 * q + i] * p[pid, i]
        s *= k
        for q in range(3):
            pid = corners[t, q]
            for i in range(3):
                y[pid, i] += s * Sg[t, 3 * q + i]


@njit
def _bend_jacobians(B, t, Pa, Pc, S):
    """Bending triple t's ``J_a = (I − ê1ê1ᵀ)/|e1|``, ``J_c`` likewise (symmetric projectors,
    scaled) and their sum ``S = J_a + J_c``, from its row of ``B`` (:func:`assemble_bending`)."""
    for i in range(3):
        for j in range(3):
            d = 1.0 if i == j else 0.0
            Pa[i, j] = (d - B[t, i] * B[t, j]) * B[t, 3]
            Pc[i, j] = (d - B[t, 4 + i] * B[t, 4 + j]) * B[t, 7]
            S[i, j] = Pa[i, j] + Pc[i, j]


@njit
def diagonal_blocks(mdiag, h2, edges, K, triples, B, kb, corners, Sg, ks, Dblk):
    """3×3 diagonal blocks of ``A = diag(mdiag) + h²·H`` into ``Dblk (N, 3, 3)``."""
    n = mdiag.shape[0]
    Dblk[:] = 0.0
    Pa = np.empty((3, 3))
    Pc = np.empty((3, 3))
    S = np.empty((3, 3))
    for p in range(n):
        for i in range(3):
            Dblk[p, i, i] = mdiag[p]
    for e in range(edges.shape[0]):
        for q in range(2):
            pid = edges[e, q]
            for i in range(3):
                for j in range(3):
                    Dblk[pid, i, j] += h2 * K[e, i, j]
    for t in range(triples.shape[0]):
        k = kb[t]
        if k == 0.0:
            continue
        a = triples[t, 0]
        b = triples[t, 1]
        c = triples[t, 2]
        # a gets k·J_a², c gets k·J_c², b gets k·(J_a + J_c)²
        _bend_jacobians(B, t, Pa, Pc, S)
        hk = h2 * k
        for i in range(3):
            for j in range(3):
                Dblk[a, i, j] += hk * Pa[i, j] * B[t, 3]
                Dblk[c, i, j] += hk * Pc[i, j] * B[t, 7]
                Dblk[b, i, j] += hk * (S[i, 0] * S[0, j] + S[i, 1] * S[1, j] + S[i, 2] * S[2, j])
    for t in range(corners.shape[0]):
        k = ks[t]
        if k == 0.0:
            continue
        for q in range(3):
            pid = corners[t, q]
            for i in range(3):
                for j in range(3):
                    Dblk[pid, i, j] += h2 * k * Sg[t, 3 * q + i] * Sg[t, 3 * q + j]


@njit
def _inv3(M, out):
    a, b, c = M[0, 0], M[0, 1], M[0, 2]
    d, e, f = M[1, 0], M[1, 1], M[1, 2]
    g, h, i = M[2, 0], M[2, 1], M[2, 2]
    A = e * i - f * h
    B = -(d * i - f * g)
    C = d * h - e * g
    det = a * A + b * B + c * C
    inv = 1.0 / det
    out[0, 0] = A * inv
    out[0, 1] = -(b * i - c * h) * inv
    out[0, 2] = (b * f - c * e) * inv
    out[1, 0] = B * inv
    out[1, 1] = (a * i - c * g) * inv
    out[1, 2] = -(a * f - c * d) * inv
    out[2, 0] = C * inv
    out[2, 1] = -(a * h - b * g) * inv
    out[2, 2] = (a * e - b * d) * inv


@njit
def zero_row(r, q):
    """Set row q of an (N, 3) array to zero (pinned particles drop out of the solve)."""
    r[q, 0] = 0.0
    r[q, 1] = 0.0
    r[q, 2] = 0.0


@njit
def _matvec_A(p, mdiag, h2, edges, K, triples, B, kb, corners, Sg, ks, free, y):
    apply_H(p, edges, K, triples, B, kb, corners, Sg, ks, y)
    for q in range(p.shape[0]):
        if free[q]:
            for i in range(3):
                y[q, i] = mdiag[q] * p[q, i] + h2 * y[q, i]
        else:
            zero_row(y, q)


@njit
def _dot(a, b):
    s = 0.0
    for q in range(a.shape[0]):
        s += a[q, 0] * b[q, 0] + a[q, 1] * b[q, 1] + a[q, 2] * b[q, 2]
    return s


# ---------------------------------------------------------------- line preconditioner
@njit
def line_blocks(Dblk, free, lines_off, lines_idx, diag_out, low_out):
    """Block-tridiagonal factor data for the lines of direction ``d``.

    For each line (particles in order), the matrix has the full 3×3 diagonal
    blocks of A and the couplings between consecutive particles. Block Thomas factorisation: stores the inverted pivots in
    ``diag_out`` and the (unchanged) lower blocks in ``low_out`` (per particle
    slot, coupling to the previous particle of its line).
    """
    # edge lookup: coupling block for consecutive line particles = −h² K_e
    # (edges of direction d connect consecutive particles of a line)
    n_lines = lines_off.shape[0] - 1
    tmp = np.empty((3, 3))
    piv = np.empty((3, 3))
    for L in range(n_lines):
        s0 = lines_off[L]
        s1 = lines_off[L + 1]
        for s in range(s0, s1):
            q = lines_idx[s]
            piv[:, :] = Dblk[q]
            if not free[q]:
                piv[:, :] = 0.0
                for i in range(3):
                    piv[i, i] = 1.0
            elif s > s0:
                # piv = D_s − C_s · invpiv_{s−1} · C_sᵀ,  C_s = A[s, s−1]
                C = low_out[s]
                for i in range(3):
                    for j in range(3):
                        acc = 0.0
                        for k in range(3):
                            acc += C[i, k] * diag_out[s - 1, k, j]
                        tmp[i, j] = acc
                for i in range(3):
                    for j in range(3):
                        acc = 0.0
                        for k in range(3):
                            acc += tmp[i, k] * C[j, k]
                        piv[i, j] -= acc
            _inv3(piv, diag_out[s])


@njit
def set_line_couplings(h2, edges, edge_dir, K, corners, Sg, ks, free, d, slot_of, low_out):
    """Fill ``low_out[slot]`` with ``A[q, prev(q)]``, the block coupling particle q to its
    predecessor on its d-line: the stretch term −h²K_e of the d-edge between them, and
    the shear term h²k·g_q g_prevᵀ of every corner whose d-arm joins them (the corner's
    third particle is off the line, its couplings are dropped; what stays is PSD)."""
    low_out[:] = 0.0
    for e in range(edges.shape[0]):
        if edge_dir[e] != d:
            continue
        a = edges[e, 0]
        b = edges[e, 1]
        if not (free[a] and free[b]):
            continue
        s = max(slot_of[a], slot_of[b])
        for i in range(3):
            for j in range(3):
                low_out[s, i, j] -= h2 * K[e, i, j]
    arm = 0 if d == 0 else 2  # warp arm (a, b) or weft arm (c, b) of a shear corner
    for t in range(corners.shape[0]):
        k = ks[t]
        if k == 0.0:
            continue
        q = corners[t, arm]
        b = corners[t, 1]
        if not (free[q] and free[b]):
            continue
        # block A[late, early] = h²k·g_late g_earlyᵀ (ol, oe: offsets of the two in the 9-vector)
        if slot_of[q] > slot_of[b]:
            late, ol, oe = q, 3 * arm, 3
        else:
            late, ol, oe = b, 3, 3 * arm
        s = slot_of[late]
        for i in range(3):
            for j in range(3):
                low_out[s, i, j] += h2 * k * Sg[t, ol + i] * Sg[t, oe + j]


@njit
def line_solve(r, lines_off, lines_idx, invpiv, low, z, scale, work):
    """z += scale · L⁻¹ r for block-tridiagonal L (forward/back substitution per line)."""
    n_lines = lines_off.shape[0] - 1
    for L in range(n_lines):
        s0 = lines_off[L]
        s1 = lines_off[L + 1]
        # forward: y_s = invpiv_s (r_s − C_s y_{s−1})
        for s in range(s0, s1):
            q = lines_idx[s]
            t0 = r[q, 0]
            t1 = r[q, 1]
            t2 = r[q, 2]
            if s > s0:
                C = low[s]
                t0 -= C[0, 0] * work[s - 1, 0] + C[0, 1] * work[s - 1, 1] + C[0, 2] * work[s - 1, 2]
                t1 -= C[1, 0] * work[s - 1, 0] + C[1, 1] * work[s - 1, 1] + C[1, 2] * work[s - 1, 2]
                t2 -= C[2, 0] * work[s - 1, 0] + C[2, 1] * work[s - 1, 1] + C[2, 2] * work[s - 1, 2]
            P = invpiv[s]
            work[s, 0] = P[0, 0] * t0 + P[0, 1] * t1 + P[0, 2] * t2
            work[s, 1] = P[1, 0] * t0 + P[1, 1] * t1 + P[1, 2] * t2
            work[s, 2] = P[2, 0] * t0 + P[2, 1] * t1 + P[2, 2] * t2
        # backward: x_s = y_s − invpiv_s C_{s+1}ᵀ x_{s+1}
        for s in range(s1 - 2, s0 - 1, -1):
            C = low[s + 1]
            x0 = work[s + 1, 0]
            x1 = work[s + 1, 1]
            x2 = work[s + 1, 2]
            t0 = C[0, 0] * x0 + C[1, 0] * x1 + C[2, 0] * x2
            t1 = C[0, 1] * x0 + C[1, 1] * x1 + C[2, 1] * x2
            t2 = C[0, 2] * x0 + C[1, 2] * x1 + C[2, 2] * x2
            P = invpiv[s]
            work[s, 0] -= P[0, 0] * t0 + P[0, 1] * t1 + P[0, 2] * t2
            work[s, 1] -= P[1, 0] * t0 + P[1, 1] * t1 + P[1, 2] * t2
            work[s, 2] -= P[2, 0] * t0 + P[2, 1] * t1 + P[2, 2] * t2
        for s in range(s0, s1):
            q = lines_idx[s]
            z[q, 0] += scale * work[s, 0]
            z[q, 1] += scale * work[s, 1]
            z[q, 2] += scale * work[s, 2]


# ============================================================================ vector kernels
@njit
def smooth_apply(r, precond, Dinv, free, lw_off, lw_idx, lw_piv, lw_low, lf_off, lf_idx, lf_piv, lf_low,
                 work, scale, z):
    """``z = scale · S r``: S = block Jacobi (precond 0) or ½(L_warp⁻¹ + L_weft⁻¹) (precond 1)."""
    n = r.shape[0]
    if precond == 1:
        z[:] = 0.0
        line_solve(r, lw_off, lw_idx, lw_piv, lw_low, z, 0.5 * scale, work)
        line_solve(r, lf_off, lf_idx, lf_piv, lf_low, z, 0.5 * scale, work)
        for q in range(n):
            if not free[q]:
                zero_row(z, q)
    else:
        for q in range(n):
            if free[q]:
                for i in range(3):
                    z[q, i] = scale * (Dinv[q, i, 0] * r[q, 0] + Dinv[q, i, 1] * r[q, 1] + Dinv[q, i, 2] * r[q, 2])
            else:
                zero_row(z, q)


@njit
def invert_blocks(Dblk, Dinv):
    for q in range(Dblk.shape[0]):
        _inv3(Dblk[q], Dinv[q])


@njit
def restrict(r_f, P_idx, P_w, free_c, r_c):
    """``r_c = Pᵀ r_f`` (full weighting), zero at pinned coarse particles."""
    r_c[:] = 0.0
    for f in range(r_f.shape[0]):
        for k in range(P_idx.shape[1]):
            c = P_idx[f, k]
            if c >= 0:
                w = P_w[f, k]
                r_c[c, 0] += w * r_f[f, 0]
                r_c[c, 1] += w * r_f[f, 1]
                r_c[c, 2] += w * r_f[f, 2]
    for c in range(r_c.shape[0]):
        if not free_c[c]:
            zero_row(r_c, c)


@njit
def prolong_add(e_c, P_idx, P_w, free_f, x_f):
    """``x_f += P e_c`` (bilinear), nothing added at pinned fine particles."""
    for f in range(x_f.shape[0]):
        if not free_f[f]:
            continue
        for k in range(P_idx.shape[1]):
            c = P_idx[f, k]
            if c >= 0:
                w = P_w[f, k]
                x_f[f, 0] += w * e_c[c, 0]
                x_f[f, 1] += w * e_c[c, 1]
                x_f[f, 2] += w * e_c[c, 2]


@njit
def restrict_scalar(a_f, P_idx, P_w, a_c):
    a_c[:] = 0.0
    for f in range(a_f.shape[0]):
        for k in range(P_idx.shape[1]):
            c = P_idx[f, k]
            if c >= 0:
                a_c[c] += P_w[f, k] * a_f[f]


@njit
def dense_matrix(mdiag, h2, edges, K, triples, B, kb, corners, Sg, ks, free, out):
    """Dense ``A`` (3N × 3N) of a small level; identity rows/columns at pinned particles."""
    n = mdiag.shape[0]
    e = np.zeros((n, 3))
    y = np.empty((n, 3))
    for q in range(n):
        for i in range(3):
            col = 3 * q + i
            if not free[q]:
                out[:, col] = 0.0
                out[col, col] = 1.0
                continue
            e[q, i] = 1.0
            _matvec_A(e, mdiag, h2, edges, K, triples, B, kb, corners, Sg, ks, free, y)
            e[q, i] = 0.0
            for p in range(n):
                for j in range(3):
                    out[3 * p + j, col] = y[p, j]


@njit
def axpy_pair(x, r, p, Ap, alpha):
    """x += α p;  r −= α Ap."""
    for q in range(x.shape[0]):
        for i in range(3):
            x[q, i] += alpha * p[q, i]
            r[q, i] -= alpha * Ap[q, i]


@njit
def xpby(z, beta, p):
    """p = z + β p."""
    for q in range(p.shape[0]):
        for i in range(3):
            p[q, i] = z[q, i] + beta * p[q, i]


@njit
def residual(b, x, mdiag, h2, edges, K, triples, B, kb, corners, Sg, ks, free, r):
    """``r = b − A x`` (zero at pinned particles)."""
    _matvec_A(x, mdiag, h2, edges, K, triples, B, kb, corners, Sg, ks, free, r)
    for q in range(b.shape[0]):
        if free[q]:
            for i in range(3):
                r[q, i] = b[q, i] - r[q, i]


@njit
def implicit_rhs(f, v, h, edges, K, triples, B, kb, corners, Sg, ks, free, rhs):
    """``rhs = h (f − h H v)``, zero at pinned particles."""
    apply_H(v, edges, K, triples, B, kb, corners, Sg, ks, rhs)
    for q in range(f.shape[0]):
        for i in range(3):
            rhs[q, i] = h * (f[q, i] - h * rhs[q, i]) if free[q] else 0.0


@njit
def lumped_mass(mass, damping_rate, use_damping, drag, h, mdiag):
    for q in range(mass.shape[0]):
        mdiag[q] = mass[q] * (1.0 + (h * damping_rate if use_damping else 0.0)) + h * drag[q]


# ============================================================================ contact constraints
# Regularisation speed of Coulomb friction (cm/s): below it friction acts as a viscous damper of
# coefficient μ|f_n|/V_EPS, so a particle under a tangential load below μ|f_n| creeps at most this fast.
FRICTION_V_EPS = 1e-2
FRICTION_PASSES = 1  # at most this many re-solves per step with raised friction dampers (refine_friction)
FRICTION_REFINE_SPEED = 0.5  # cm/s: refine_friction leaves particles sliding slower than this at the end of the solve
FRICTION_REFINE_RATIO = 2.0  # refine_friction raises a damper that brakes with less than 1/this of μ|f_n|


@njit
def contact_constraints(x, v, f, touching, types, params, friction, mass, h, cn, con, cfric, md, ob_vel, free,
                        fmax):
    """Contact constraints and implicit Coulomb friction for the solve (Baraff–Witkin filter).

    A particle that touched an obstacle last step and is pressed into it (``f·n < 0``) is
    constrained (``con = 1``): its normal velocity is set to the obstacle's and kept there by
    the filter. Friction is Coulomb's, taken *implicitly*: a damper of coefficient
    ``c = μ|f_n| / max(s, V_EPS)`` (g/s, into ``cfric``), with ``f_n = f·n`` from the forces at
    the start of the step, ``s = |u_t + h·f_t/m| − h·μ|f_n|/m`` the end-of-step sliding speed
    predicted from the step's forces (``u_t`` the tangential velocity relative to the
    obstacle, ``f_t`` the tangential force) and V_EPS = :data:`FRICTION_V_EPS`. Its force
    ``−c·u_t`` is added to ``f`` and its ``h·c`` to the particle's diagonal ``md``. For a lone
    particle the update is then exact Coulomb: sliding at speed s against μ|f_n|, or held
    (``s ≤ 0``: creep below V_EPS) when the tangential load is below μ|f_n|. A damper cannot
    reverse the motion and keeps the system SPD whatever Δt: this is what makes large steps
    onto a table stable (the explicit friction force that this replaced made the 41×41
    tablecloth explode at Δt = 5 ms).
    Pinned and kinematic particles (``free`` False) keep their prescribed velocity: no constraint.
    ``fmax`` gets the friction bound μ|f_n| (dyne) of each constrained particle (0 elsewhere), for
    :func:`refine_friction`.
    """
    for p in range(x.shape[0]):
        con[p] = 0
        cfric[p] = 0.0
        fmax[p] = 0.0
        k = touching[p]
        if k < 0 or not free[p]:
            continue
        d, n0, n1, n2 = signed_distance(types[k], params[k], x[p, 0], x[p, 1], x[p, 2])
        fn = f[p, 0] * n0 + f[p, 1] * n1 + f[p, 2] * n2
        if fn >= 0.0:
            continue
        cn[p, 0] = n0
        cn[p, 1] = n1
        cn[p, 2] = n2
        w0 = ob_vel[k, 0]
        w1 = ob_vel[k, 1]
        w2 = ob_vel[k, 2]
        vn = (v[p, 0] - w0) * n0 + (v[p, 1] - w1) * n1 + (v[p, 2] - w2) * n2
        v[p, 0] -= vn * n0
        v[p, 1] -= vn * n1
        v[p, 2] -= vn * n2
        con[p] = 1
        u0 = v[p, 0] - w0
        u1 = v[p, 1] - w1
        u2 = v[p, 2] - w2
        # the end-of-step sliding speed predicted from this step's forces: |u + h·f_t/m| − h·μ|f_n|/m
        # (≤ 0: it sticks); with c = μ|f_n|/speed the damped update reproduces Coulomb exactly for a
        # lone particle, instead of over-braking a particle that starts to slide
        im = 1.0 / mass[p]
        p0 = u0 + h * (f[p, 0] - fn * n0) * im
        p1 = u1 + h * (f[p, 1] - fn * n1) * im
        p2 = u2 + h * (f[p, 2] - fn * n2) * im
        slide = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2) + h * friction[k] * fn * im
        c = -friction[k] * fn / max(slide, FRICTION_V_EPS)
        cfric[p] = c
        fmax[p] = -friction[k] * fn
        md[p] += h * c
        f[p, 0] -= c * u0
        f[p, 1] -= c * u1
        f[p, 2] -= c * u2


@njit
def refine_friction(v, dv, con, cn, cfric, fmax, touching, ob_vel, h, md, rhs):
    """Second friction pass after a solve: where the solve's end-of-step sliding speed ``s`` is
    below 1/:data:`FRICTION_REFINE_RATIO` (= ½) of the one :func:`contact_constraints` predicted
    (the damper then brakes with less than half of μ|f_n|), raise the damper to
    ``c = μ|f_n|/s`` — for particles still sliding faster than :data:`FRICTION_REFINE_SPEED`
    (a slower one's velocity could change by less than that): its extra force
    ``−Δc·u_t`` goes into ``rhs`` (× h) and ``h·Δc`` into ``md``. Returns whether anything changed
    (then solve again). The prediction uses the particle's own mass: it overestimates the sliding
    of a cloth whose internal forces cancel over the solve, e.g. one released stretched at
    Δt = 50 ms, which without this pass kept most of its speed and skated on the table. Raising c
    from a speed reached with the smaller c keeps the friction force below μ|f_n|. The thresholds
    trade accuracy for solves: a ratio of 1.2 with two re-solves braked the released CornerLift
    cloth at Coulomb's rate, these settings at about 70 % of it, for far fewer CG iterations on the
    41×41 drop. A 20 cm cloth stretched by 1 % and sliding at 30 cm/s on a table slides within 4 %
    of Coulomb's distance at h = 10 ms, but 1.47 cm instead of 0.79 at h = 50 ms (ratio 1.25 with
    two re-solves: 1.13 cm); unstretched, 0.74 cm at 50 ms."""
    changed = False
    for p in range(v.shape[0]):
        if con[p] != 1 or fmax[p] == 0.0:
            continue
        k = touching[p]
        e0 = v[p, 0] + dv[p, 0] - ob_vel[k, 0]
        e1 = v[p, 1] + dv[p, 1] - ob_vel[k, 1]
        e2 = v[p, 2] + dv[p, 2] - ob_vel[k, 2]
        en = e0 * cn[p, 0] + e1 * cn[p, 1] + e2 * cn[p, 2]
        e0 -= en * cn[p, 0]
        e1 -= en * cn[p, 1]
        e2 -= en * cn[p, 2]
        sl = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        if sl <= FRICTION_REFINE_SPEED:  # the re-solve could change its velocity by at most sl
            continue
        c = fmax[p] / sl
        if c <= FRICTION_REFINE_RATIO * cfric[p]:
            continue
        dc = c - cfric[p]
        u0 = v[p, 0] - ob_vel[k, 0]  # tangential at the start (the normal part was removed)
        u1 = v[p, 1] - ob_vel[k, 1]
        u2 = v[p, 2] - ob_vel[k, 2]
        rhs[p, 0] -= h * dc * u0
        rhs[p, 1] -= h * dc * u1
        rhs[p, 2] -= h * dc * u2
        md[p] += h * dc
        cfric[p] = c
        changed = True
    return changed


@njit
def friction_force(v, con, cn, cfric, touching, ob_vel, out):
    """The implicit friction force ``−c·u_t`` (dyne) at velocity ``v`` (for further Newton passes)."""
    for p in range(v.shape[0]):
        zero_row(out, p)
        if con[p] != 1 or cfric[p] == 0.0:
            continue
        k = touching[p]
        u0 = v[p, 0] - ob_vel[k, 0]
        u1 = v[p, 1] - ob_vel[k, 1]
        u2 = v[p, 2] - ob_vel[k, 2]
        un = u0 * cn[p, 0] + u1 * cn[p, 1] + u2 * cn[p, 2]
        out[p, 0] = -cfric[p] * (u0 - un * cn[p, 0])
        out[p, 1] = -cfric[p] * (u1 - un * cn[p, 1])
        out[p, 2] = -cfric[p] * (u2 - un * cn[p, 2])


@njit
def filter_vec(r, free, con, cn):
    """Baraff–Witkin filter S: zero at pinned and sticking particles, normal component removed
    at sliding ones."""
    for p in range(r.shape[0]):
        if not free[p] or con[p] == 2:
            zero_row(r, p)
        elif con[p] == 1:
            d = r[p, 0] * cn[p, 0] + r[p, 1] * cn[p, 1] + r[p, 2] * cn[p, 2]
            r[p, 0] -= d * cn[p, 0]
            r[p, 1] -= d * cn[p, 1]
            r[p, 2] -= d * cn[p, 2]


# ============================================================================ strain limiting
@njit
def _move_pair(arr, a, b, wa, wb, s, d0, d1, d2):
    """``arr[a] += wa·s·d``, ``arr[b] −= wb·s·d``: a pairwise, momentum-conserving correction."""
    arr[a, 0] += wa * s * d0
    arr[a, 1] += wa * s * d1
    arr[a, 2] += wa * s * d2
    arr[b, 0] -= wb * s * d0
    arr[b, 1] -= wb * s * d1
    arr[b, 2] -= wb * s * d2


@njit
def _limited_edge(x, inv_mass, edges, e):
    """(a, b, 1/m_a, 1/m_b, x_b − x_a, |x_b − x_a|) of edge e, for the strain limiter's passes."""
    a = edges[e, 0]
    b = edges[e, 1]
    d0, d1, d2, r = edge_vector(x, a, b)
    return a, b, inv_mass[a], inv_mass[b], d0, d1, d2, r


@njit
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


@njit
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


# ============================================================================ dense Cholesky (coarsest level)
@njit
def cholesky_inplace(A):
    """Lower Cholesky factor of SPD ``A`` in place (upper part left as is). Returns False if not SPD."""
    n = A.shape[0]
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= A[j, k] * A[j, k]
        if s <= 0.0:
            return False
        d = math.sqrt(s)
        A[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= A[i, k] * A[j, k]
            A[i, j] = s / d
    return True


@njit
def cholesky_solve(L, b, x):
    n = L.shape[0]
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


# ============================================================================ banded Cholesky (small lattices)
# The "band" preconditioner: the whole matrix the line smoother approximates, factored exactly, but
# for one simplification. Particles are numbered along lattice lines (the shorter direction's line
# order, ``slot``), so every stretch, shear and bending-neighbour coupling lies within a band of
# half-width w particles (one line plus one); the only coupling beyond it, between the two ends a, c
# of a bending triple (two lattice steps apart), is dropped, and k·J_aᵀJ_a, k·J_cᵀJ_c added to
# their diagonal blocks instead, which keeps the matrix above the exact one (−D ≤ C ≤ D for
# C = k[[0, J_aᵀJ_c], [J_cᵀJ_a, 0]], D = k·diag(J_aᵀJ_a, J_cᵀJ_c)): SPD by construction.
# Storage, LAPACK's lower band by columns: ``Ab[j, k] = M[j + k, j]`` (column j from its diagonal
# down, k ≤ bw), j = 3·slot + component; rows of Ab are contiguous, so the factorisation's and the
# forward solve's inner loops are independent updates along a row (vectorised), not reductions.


@njit
def _band_add(Ab, slot, p, q, M, scale):
    """Add ``scale·M`` as block (p, q) and its transpose as (q, p) of the symmetric band matrix."""
    sp = slot[p]
    sq = slot[q]
    if sp > sq:  # block (p, q) is below the diagonal: entry (3sp + i, 3sq + j)
        for i in range(3):
            for j in range(3):
                Ab[3 * sq + j, 3 * (sp - sq) + i - j] += scale * M[i, j]
    else:  # its transpose (q, p) is: entry (3sq + j, 3sp + i) = M[i, j]
        for i in range(3):
            for j in range(3):
                Ab[3 * sp + i, 3 * (sq - sp) + j - i] += scale * M[i, j]


@njit
def band_assemble(Dblk, free, h2, edges, K, triples, B, kb, corners, Sg, ks, slot, Ab):
    """Fill the band matrix ``Ab`` from the diagonal blocks ``Dblk`` (mass, h²H, contact penalty)
    and the off-diagonal blocks of h²H (see the section comment). Pinned particles get identity
    rows (their couplings are left out, as the filter removes them)."""
    Ab[:] = 0.0
    M = np.empty((3, 3))
    Pa = np.empty((3, 3))
    Pc = np.empty((3, 3))
    S = np.empty((3, 3))
    for q in range(Dblk.shape[0]):
        o = 3 * slot[q]
        for j in range(3):
            if not free[q]:
                Ab[o + j, 0] = 1.0
                continue
            for i in range(j, 3):
                Ab[o + j, i - j] = Dblk[q, i, j]
    for e in range(edges.shape[0]):
        a = edges[e, 0]
        b = edges[e, 1]
        if free[a] and free[b]:
            _band_add(Ab, slot, a, b, K[e], -h2)
    for t in range(corners.shape[0]):
        k = ks[t]
        if k == 0.0:
            continue
        for u in range(3):
            for w in range(u + 1, 3):
                pu = corners[t, u]
                pw = corners[t, w]
                if not (free[pu] and free[pw]):
                    continue
                for i in range(3):
                    for j in range(3):
                        M[i, j] = Sg[t, 3 * u + i] * Sg[t, 3 * w + j]
                _band_add(Ab, slot, pu, pw, M, h2 * k)
    for t in range(triples.shape[0]):
        k = kb[t]
        if k == 0.0:
            continue
        a = triples[t, 0]
        b = triples[t, 1]
        c = triples[t, 2]
        _bend_jacobians(B, t, Pa, Pc, S)
        hk = h2 * k
        # blocks (a, b) = −k J_a (J_a + J_c) and (c, b) = −k J_c (J_a + J_c) (J symmetric)
        if free[a] and free[b]:
            for i in range(3):
                for j in range(3):
                    M[i, j] = Pa[i, 0] * S[0, j] + Pa[i, 1] * S[1, j] + Pa[i, 2] * S[2, j]
            _band_add(Ab, slot, a, b, M, -hk)
        if free[c] and free[b]:
            for i in range(3):
                for j in range(3):
                    M[i, j] = Pc[i, 0] * S[0, j] + Pc[i, 1] * S[1, j] + Pc[i, 2] * S[2, j]
            _band_add(Ab, slot, c, b, M, -hk)
        # the dropped (a, c) coupling's bound on the diagonal: k J_aᵀJ_a at a, k J_cᵀJ_c at c
        for end in range(2):
            q = a if end == 0 else c
            if not free[q]:
                continue
            o = 3 * slot[q]
            for j in range(3):
                for i in range(j, 3):
                    Ab[o + j, i - j] += hk * ((Pa[i, j] * B[t, 3]) if end == 0 else (Pc[i, j] * B[t, 7]))


@njit
def band_cholesky(Ab):
    """Lower Cholesky factor of the band matrix in place (same storage; right-looking, by
    columns). False if not SPD."""
    n = Ab.shape[0]
    bw = Ab.shape[1] - 1
    for j in range(n):
        d = Ab[j, 0]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        Ab[j, 0] = d
        m = min(bw, n - 1 - j)
        for k in range(1, m + 1):
            Ab[j, k] /= d
        for k in range(1, m + 1):  # the trailing column c = j + k loses L[c:, j]·L[c, j]
            lk = Ab[j, k]
            if lk == 0.0:
                continue
            c = j + k
            for t in range(m - k + 1):
                Ab[c, t] -= Ab[j, k + t] * lk
    return True


@njit
def band_apply(L, idx, free, r, z, y):
    """``z = M⁻¹ r`` with the band factor L (slot order ``idx``: the particle at each slot)."""
    n = L.shape[0]
    bw = L.shape[1] - 1
    for s in range(idx.shape[0]):
        q = idx[s]
        for i in range(3):
            y[3 * s + i] = r[q, i] if free[q] else 0.0
    for j in range(n):  # L y = b, by columns
        yj = y[j] / L[j, 0]
        y[j] = yj
        for k in range(1, min(bw, n - 1 - j) + 1):
            y[j + k] -= L[j, k] * yj
    for j in range(n - 1, -1, -1):  # Lᵀ x = y, by rows of Lᵀ (columns of L): four partial sums
        m = min(bw, n - 1 - j)
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        a3 = 0.0
        k = 1
        while k + 3 <= m:
            a0 += L[j, k] * y[j + k]
            a1 += L[j, k + 1] * y[j + k + 1]
            a2 += L[j, k + 2] * y[j + k + 2]
            a3 += L[j, k + 3] * y[j + k + 3]
            k += 4
        while k <= m:
            a0 += L[j, k] * y[j + k]
            k += 1
        y[j] = (y[j] - ((a0 + a1) + (a2 + a3))) / L[j, 0]
    for s in range(idx.shape[0]):
        q = idx[s]
        for i in range(3):
            z[q, i] = y[3 * s + i] if free[q] else 0.0


# ============================================================================ contact penalty (preconditioner only)
CONTACT_PENALTY = 1.0e3


@njit
def contact_penalty(Dblk, con, cn, pen):
    """``pen_q = κ·(tr D_q / 3)·n nᵀ`` for constrained particles, 0 elsewhere (see :func:`mg_setup`)."""
    for q in range(Dblk.shape[0]):
        if con[q] != 1:
            for i in range(3):
                for j in range(3):
                    pen[q, i, j] = 0.0
            continue
        k = CONTACT_PENALTY * (Dblk[q, 0, 0] + Dblk[q, 1, 1] + Dblk[q, 2, 2]) / 3.0
        for i in range(3):
            for j in range(3):
                pen[q, i, j] = k * cn[q, i] * cn[q, j]


@njit
def raise_diagonal(md, md_before, con, cn, Dblk, pen):
    """Add the rise ``δ_q = md_q − md_before_q`` of the lumped diagonal (the friction re-solve's
    raised dampers) to level 0's preconditioner blocks in place: ``D_q += δ_q·I`` and, at a
    constrained particle, its contact penalty ``κ·(tr D_q/3)·n nᵀ`` grows by ``κ·δ_q·n nᵀ``.
    The same blocks as :func:`mg_setup` would rebuild from scratch (up to rounding), without
    re-assembling the diagonal blocks and line couplings of the particles that did not change."""
    for q in range(md.shape[0]):
        d = md[q] - md_before[q]
        if d == 0.0:
            continue
        for i in range(3):
            Dblk[q, i, i] += d
        if con[q] == 1:
            k = CONTACT_PENALTY * d
            for i in range(3):
                for j in range(3):
                    Dblk[q, i, j] += k * cn[q, i] * cn[q, j]
                    pen[q, i, j] += k * cn[q, i] * cn[q, j]


@njit
def restrict_blocks(a_f, P_idx, P_w, a_c):
    """Coarse 3×3 blocks ``a_c = Σ_f w_f a_f`` (lumped like the mass)."""
    a_c[:] = 0.0
    for f in range(a_f.shape[0]):
        if a_f[f, 0, 0] + a_f[f, 1, 1] + a_f[f, 2, 2] == 0.0:
            continue
        for k in range(P_idx.shape[1]):
            c = P_idx[f, k]
            if c >= 0:
                w = P_w[f, k]
                for i in range(3):
                    for j in range(3):
                        a_c[c, i, j] += w * a_f[f, i, j]


@njit
def add_blocks(a, out):
    for q in range(a.shape[0]):
        for i in range(3):
            for j in range(3):
                out[q, i, j] += a[q, i, j]


# ============================================================================ the whole step, all levels
# Levels are stored concatenated: level l's particle arrays are rows n_off[l]:n_off[l+1] of the
# particle-sized arrays, its edges rows e_off[l]:e_off[l+1], etc. Indices inside a level are local.
# (A numba typed List costs seconds per process to build; a tuple compiles once per level count.)


@njit
def mg_setup(x, h2, precond, n_levels, n_off, e_off, b_off, c_off, i_off, lwo_off, lfo_off, sigma_l,
             inject, P_idx, P_w, rest, edges, edge_dir, triples, bend_dir, corners,
             flags, stretch_coef, alpha, breen_c0, bend_coef, x0_curv, shear_coef, x0_shear,
             xl, K, B, kb, Sg, ks, mdiag, free, Dblk, Dinv,
             lw_off, lw_idx, lw_slot, lw_piv, lw_low, lf_off, lf_idx, lf_slot, lf_piv, lf_low, chol, con, cn, pen,
             assemble=True):
    """Assemble H on every level (coarse positions injected from the fine ones), restrict the
    lumped mass, set up the smoothers and factor the coarsest level. Level 0's ``mdiag`` and
    ``free`` rows must be set by the caller. Returns False if the coarsest matrix is not SPD.
    With ``assemble=False`` the H of the last call is kept (only the mass diagonal changed:
    the friction re-solve).

    Contact constraints (``con``, normals ``cn``) enter the *preconditioner* as a stiff penalty
    ``pen_q = κ·d_q·n nᵀ`` on the diagonal block of each constrained particle (κ =
    :data:`CONTACT_PENALTY`, d_q the block's mean diagonal), restricted to the coarse levels like
    the mass: without it the coarse-grid corrections move particles lying on a table through it,
    the filter throws that away and PCG needs 4–5× more iterations once the cloth lands."""
    breen = (flags >> 6) & 1 == 1
    n0 = n_off[1]
    if assemble:
        xl[0:n0] = x
    for l in range(n_levels):
        a, b = n_off[l], n_off[l + 1]
        ea, eb = e_off[l], e_off[l + 1]
        ba, bb = b_off[l], b_off[l + 1]
        ca, cb = c_off[l], c_off[l + 1]
        if l > 0:
            pa, pb = n_off[l - 1], n_off[l]
            inj = inject[i_off[l - 1]:i_off[l]]
            for c in range(b - a):
                if assemble:
                    for i in range(3):
                        xl[a + c, i] = xl[pa + inj[c], i]
                free[a + c] = free[pa + inj[c]]
            restrict_scalar(mdiag[pa:pb], P_idx[pa:pb], P_w[pa:pb], mdiag[a:b])
            restrict_blocks(pen[pa:pb], P_idx[pa:pb], P_w[pa:pb], pen[a:b])
        x_l = xl[a:b]
        if assemble and (flags >> 1) & 1:
            assemble_stretch(x_l, edges[ea:eb], edge_dir[ea:eb], rest[ea:eb], stretch_coef, alpha, breen, breen_c0,
                             K[ea:eb])
        if assemble and (flags >> 2) & 1:
            assemble_bending(x_l, triples[ba:bb], bend_dir[ba:bb], bend_coef, sigma_l[l], x0_curv, breen, B[ba:bb],
                             kb[ba:bb])
        if assemble and (flags >> 3) & 1:
            assemble_shear(x_l, corners[ca:cb], shear_coef, sigma_l[l], x0_shear, breen, Sg[ca:cb], ks[ca:cb])
        diagonal_blocks(mdiag[a:b], h2, edges[ea:eb], K[ea:eb], triples[ba:bb], B[ba:bb], kb[ba:bb], corners[ca:cb],
                        Sg[ca:cb], ks[ca:cb], Dblk[a:b])
        if l == 0:
            contact_penalty(Dblk[a:b], con, cn, pen[a:b])
        add_blocks(pen[a:b], Dblk[a:b])
        if precond >= 2:
            pass  # the band factor (one level only) is built by filtered_pcg, when a solve needs it
        elif precond == 1:
            wo = lw_off[lwo_off[l]:lwo_off[l + 1]]
            fo = lf_off[lfo_off[l]:lfo_off[l + 1]]
            set_line_couplings(h2, edges[ea:eb], edge_dir[ea:eb], K[ea:eb], corners[ca:cb], Sg[ca:cb], ks[ca:cb],
                               free[a:b], 0, lw_slot[a:b], lw_low[a:b])
            line_blocks(Dblk[a:b], free[a:b], wo, lw_idx[a:b], lw_piv[a:b], lw_low[a:b])
            set_line_couplings(h2, edges[ea:eb], edge_dir[ea:eb], K[ea:eb], corners[ca:cb], Sg[ca:cb], ks[ca:cb],
                               free[a:b], 1, lf_slot[a:b], lf_low[a:b])
            line_blocks(Dblk[a:b], free[a:b], fo, lf_idx[a:b], lf_piv[a:b], lf_low[a:b])
        else:
            invert_blocks(Dblk[a:b], Dinv[a:b])
    if n_levels > 1:
        l = n_levels - 1
        a, b = n_off[l], n_off[l + 1]
        ea, eb = e_off[l], e_off[l + 1]
        ba, bb = b_off[l], b_off[l + 1]
        ca, cb = c_off[l], c_off[l + 1]
        dense_matrix(mdiag[a:b], h2, edges[ea:eb], K[ea:eb], triples[ba:bb], B[ba:bb], kb[ba:bb], corners[ca:cb],
                     Sg[ca:cb], ks[ca:cb], free[a:b], chol)
        for q in range(b - a):
            if free[a + q]:
                for i in range(3):
                    for j in range(3):
                        chol[3 * q + i, 3 * q + j] += pen[a + q, i, j]
        return cholesky_inplace(chol)
    return True


@njit
def _smooth_level(l, r, z, scale, precond, n_off, lwo_off, lfo_off, Dinv, free, lw_off, lw_idx, lw_piv, lw_low,
                  lf_off, lf_idx, lf_piv, lf_low, work):
    a, b = n_off[l], n_off[l + 1]
    smooth_apply(r, precond, Dinv[a:b], free[a:b], lw_off[lwo_off[l]:lwo_off[l + 1]], lw_idx[a:b], lw_piv[a:b],
                 lw_low[a:b], lf_off[lfo_off[l]:lfo_off[l + 1]], lf_idx[a:b], lf_piv[a:b], lf_low[a:b], work[a:b],
                 scale, z)


@njit
def _residual_level(l, rl, zl, out, h2, n_off, e_off, b_off, c_off, mdiag, edges, K, triples, B, kb, corners, Sg,
                    ks, free, pen):
    """``out = rl − (A_l + pen_l) zl`` on level l (the operator the preconditioner approximates)."""
    a, b = n_off[l], n_off[l + 1]
    ea, eb = e_off[l], e_off[l + 1]
    ba, bb = b_off[l], b_off[l + 1]
    ca, cb = c_off[l], c_off[l + 1]
    residual(rl, zl, mdiag[a:b], h2, edges[ea:eb], K[ea:eb], triples[ba:bb], B[ba:bb], kb[ba:bb], corners[ca:cb],
             Sg[ca:cb], ks[ca:cb], free[a:b], out)
    pq = pen[a:b]
    fq = free[a:b]
    for q in range(b - a):
        if fq[q] and pq[q, 0, 0] + pq[q, 1, 1] + pq[q, 2, 2] != 0.0:
            for i in range(3):
                out[q, i] -= pq[q, i, 0] * zl[q, 0] + pq[q, i, 1] * zl[q, 1] + pq[q, i, 2] * zl[q, 2]


@njit
def mg_precondition(r, z, h2, precond, omega, n_levels, n_off, e_off, b_off, c_off, lwo_off, lfo_off,
                    P_idx, P_w, edges, K, triples, B, kb, corners, Sg, ks, mdiag, free, Dinv,
                    lw_off, lw_idx, lw_piv, lw_low, lf_off, lf_idx, lf_piv, lf_low, work, rin, zl, res, corr,
                    chol, cvec, cout, pen):
    """``z = B r``: one symmetric V-cycle (damped line/Jacobi smoothing, dense coarsest solve), or
    the smoother alone for a single level."""
    if precond >= 2:
        band_apply(chol, lw_idx[0:n_off[1]] if precond == 2 else lf_idx[0:n_off[1]], free, r, z, cvec)
        return
    if n_levels == 1:
        _smooth_level(0, r, z, 1.0, precond, n_off, lwo_off, lfo_off, Dinv, free, lw_off, lw_idx, lw_piv, lw_low,
                      lf_off, lf_idx, lf_piv, lf_low, work)
        return
    rin[0:n_off[1]] = r
    for l in range(n_levels - 1):
        a, b = n_off[l], n_off[l + 1]
        c = n_off[l + 2]
        _smooth_level(l, rin[a:b], zl[a:b], omega, precond, n_off, lwo_off, lfo_off, Dinv, free, lw_off, lw_idx,
                      lw_piv, lw_low, lf_off, lf_idx, lf_piv, lf_low, work)
        _residual_level(l, rin[a:b], zl[a:b], res[a:b], h2, n_off, e_off, b_off, c_off, mdiag, edges, K, triples, B,
                        kb, corners, Sg, ks, free, pen)
        restrict(res[a:b], P_idx[a:b], P_w[a:b], free[b:c], rin[b:c])
    last = n_levels - 1
    a, b = n_off[last], n_off[last + 1]
    for q in range(b - a):
        for i in range(3):
            cvec[3 * q + i] = rin[a + q, i] if free[a + q] else 0.0
    cholesky_solve(chol, cvec, cout)
    for q in range(b - a):
        for i in range(3):
            zl[a + q, i] = cout[3 * q + i] if free[a + q] else 0.0
    for l in range(n_levels - 2, -1, -1):
        a, b = n_off[l], n_off[l + 1]
        c = n_off[l + 2]
        prolong_add(zl[b:c], P_idx[a:b], P_w[a:b], free[a:b], zl[a:b])
        _residual_level(l, rin[a:b], zl[a:b], res[a:b], h2, n_off, e_off, b_off, c_off, mdiag, edges, K, triples, B,
                        kb, corners, Sg, ks, free, pen)
        _smooth_level(l, res[a:b], corr[a:b], omega, precond, n_off, lwo_off, lfo_off, Dinv, free, lw_off, lw_idx,
                      lw_piv, lw_low, lf_off, lf_idx, lf_piv, lf_low, work)
        for q in range(a, b):
            for i in range(3):
                zl[q, i] += corr[q, i]
    z[:] = zl[0:n_off[1]]


@njit
def _below_floor(r, md, floor2):
    """``Σ |r_q|² / m̃_q ≤ floor2`` (False when the floor is 0: off)."""
    if floor2 <= 0.0:
        return False
    s = 0.0
    for q in range(r.shape[0]):
        if md[q] > 0.0:
            s += (r[q, 0] * r[q, 0] + r[q, 1] * r[q, 1] + r[q, 2] * r[q, 2]) / md[q]
    return s <= floor2


@njit
def filtered_pcg(warm, rhs, dv, r, z, p, Ap, tol, vtol, max_iter, h2, precond, omega, fr, con, cn, md,
                 Dblk0, bslot, stale,
                 edges0, K0, triples0, B0, kb0, corners0, Sg0, ks0,
                 n_levels, n_off, e_off, b_off, c_off, lwo_off, lfo_off, P_idx, P_w, edges, K, triples, B, kb,
                 corners, Sg, ks, mdiag, free, Dinv, lw_off, lw_idx, lw_piv, lw_low, lf_off, lf_idx, lf_piv, lf_low,
                 work, rin, zl, res, corr, chol, cvec, cout, pen):
    """Filtered PCG (Baraff–Witkin): solve ``S A S Δv = S b``; returns (iterations, |r|/|b|).

    It starts from Δv = 0, or with ``warm`` from the filtered ``dv`` it is given (the friction
    re-solve starts from the first solve's Δv); the tolerance is relative to ``|S b|`` either way.

    ``vtol`` (cm/s, 0: off) is an absolute floor: it also stops once ``‖r‖_{M̃⁻¹} ≤ vtol·√(Σ m̃)``
    (M̃ = diag(``md``), the lumped mass with the dampers). As A ≥ M̃ (H is positive
    semi-definite), the error e of Δv then has a mass-weighted RMS ``√(Σ m̃|e|² / Σ m̃) ≤ vtol``:
    a cloth at rest, whose filtered right-hand side is tiny, is not solved to ``tol`` relative to
    nothing.

    The band preconditioner (``precond`` ≥ 2) is factored here, from the level-0 blocks ``Dblk0``
    in slot order ``bslot``, when ``stale[0] == 1`` and the solve iterates at all (a cloth at
    rest needs none: it costs no factorisation); ``stale[0]`` becomes 0, or 2 if the matrix was
    not SPD (the solve then stops)."""
    r[:] = rhs
    filter_vec(r, fr, con, cn)
    bnorm = math.sqrt(_dot(r, r))
    if warm and bnorm > 0.0:
        filter_vec(dv, fr, con, cn)
        _matvec_A(dv, md, h2, edges0, K0, triples0, B0, kb0, corners0, Sg0, ks0, fr, Ap)
        filter_vec(Ap, fr, con, cn)
        for q in range(r.shape[0]):
            for i in range(3):
                r[q, i] -= Ap[q, i]
    else:
        dv[:] = 0.0
    it = 0
    rel = math.sqrt(_dot(r, r)) / bnorm if bnorm > 0.0 else 0.0
    floor2 = 0.0
    if vtol > 0.0:
        msum = 0.0
        for q in range(md.shape[0]):
            if fr[q]:
                msum += md[q]
        floor2 = vtol * vtol * msum
    if bnorm > 0.0 and rel > tol and not _below_floor(r, md, floor2):
        if precond >= 2 and stale[0] == 1:
            band_assemble(Dblk0, fr, h2, edges0, K0, triples0, B0, kb0, corners0, Sg0, ks0, bslot, chol)
            stale[0] = 0 if band_cholesky(chol) else 2
            if stale[0] == 2:
                return it, rel
        mg_precondition(r, z, h2, precond, omega, n_levels, n_off, e_off, b_off, c_off, lwo_off, lfo_off,
                        P_idx, P_w, edges, K, triples, B, kb, corners, Sg, ks, mdiag, free, Dinv,
                        lw_off, lw_idx, lw_piv, lw_low, lf_off, lf_idx, lf_piv, lf_low, work, rin, zl, res, corr,
                        chol, cvec, cout, pen)
        filter_vec(z, fr, con, cn)
        p[:] = z
        rz = _dot(r, z)
        while it < max_iter:
            _matvec_A(p, md, h2, edges0, K0, triples0, B0, kb0, corners0, Sg0, ks0, fr, Ap)
            filter_vec(Ap, fr, con, cn)
            pAp = _dot(p, Ap)
            if pAp <= 0.0:
                break
            a = rz / pAp
            axpy_pair(dv, r, p, Ap, a)
            it += 1
            rel = math.sqrt(_dot(r, r)) / bnorm
            if rel <= tol or _below_floor(r, md, floor2):
                break
            mg_precondition(r, z, h2, precond, omega, n_levels, n_off, e_off, b_off, c_off, lwo_off, lfo_off,
                            P_idx, P_w, edges, K, triples, B, kb, corners, Sg, ks, mdiag, free, Dinv,
                            lw_off, lw_idx, lw_piv, lw_low, lf_off, lf_idx, lf_piv, lf_low, work, rin, zl, res,
                            corr, chol, cvec, cout, pen)
            filter_vec(z, fr, con, cn)
            rz_new = _dot(r, z)
            xpby(z, rz_new / rz, p)
            rz = rz_new
    return it, rel


@njit
def run_implicit_mg(n_steps, h, x, v, inv_mass, wind, max_speed, max_strain_percent, tol, vtol, max_iter, precond, omega,
                    stats, bdf2, hist_x, hist_v, hist_ok, n_newton, strain_limit, strain_iters, touching, ob_offset, ob_vel, ob_types, ob_params, ob_friction, restitution, thickness,
                    cflags, citers, cthick, cmu, ctris, cedges, cpoints, cmargin, mv, mf, mn, mmu,
                    g_lo, g_inv_cell, g_dims, g_start, g_items, stamp,
                    flags, mass, gravity, damping_rate, alpha, c_air, sigma,
                    edges0, edge_dir0, rest0, stretch_coef, breen_c0,
                    triples0, bend_dir0, bend_coef, x0_curv, corners0, shear_coef, x0_shear, tris,
                    n_levels, n_off, e_off, b_off, c_off, i_off, lwo_off, lfo_off, sigma_l,
                    inject, P_idx, P_w, rest, edges, edge_dir, triples, bend_dir, corners,
                    xl, K, B, kb, Sg, ks, mdiag, free, Dblk, Dinv,
                    lw_off, lw_idx, lw_slot, lw_piv, lw_low, lf_off, lf_idx, lf_slot, lf_piv, lf_low,
                    work, rin, zl, res, corr, chol, cvec, cout, pen):
    """``n_steps`` backward-Euler steps of ``h`` (see :mod:`cloth_gym.sim.implicit`), all in numba.

    ``stats`` (n_steps, 2) gets (CG iterations, relative residual). With ``bdf2``
    the steps are BDF2 (second order) once a previous state is in ``hist_x``,
    ``hist_v`` (``hist_ok[0] == 1``; the first step is backward Euler, which
    fills them). Returns (status, step, particle, value) as the explicit runner;
    status 4: the coarsest-level (or band) matrix was not SPD."""
    n = x.shape[0]
    f = np.empty((n, 3))
    normals = np.empty((n, 3))
    drag = np.zeros(n)
    rhs = np.empty((n, 3))
    dv = np.empty((n, 3))
    r = np.empty((n, 3))
    z = np.empty((n, 3))
    p = np.empty((n, 3))
    Ap = np.empty((n, 3))
    cfric = np.zeros(n)
    fmax = np.zeros(n)
    x_prev = np.empty((n, 3))
    dxh = np.zeros((n, 3))
    tmp = np.empty((n, 3))
    xk = np.empty((n, 3))
    vk = np.empty((n, 3))
    dv_k = np.empty((n, 3))
    ffric = np.zeros((n, 3))
    hist_v_old = np.zeros((n, 3))
    md_before = np.empty(n)
    stale = np.zeros(1, dtype=np.int64)  # the band preconditioner: 1 = to factor before its next use
    Dblk0 = Dblk[0:n]
    bslot = lw_slot[0:n] if precond == 2 else lf_slot[0:n]
    mg = (n_levels, n_off, e_off, b_off, c_off, lwo_off, lfo_off, P_idx, P_w, edges, K, triples, B, kb,
          corners, Sg, ks, mdiag, free, Dinv, lw_off, lw_idx, lw_piv, lw_low, lf_off, lf_idx, lf_piv, lf_low,
          work, rin, zl, res, corr, chol, cvec, cout, pen)
    con = np.zeros(n, dtype=np.int8)
    cn = np.zeros((n, 3))
    fr = free[0:n]
    for q in range(n):
        fr[q] = inv_mass[q] > 0.0
    use_air = (flags >> 4) & 1 == 1
    use_damping = (flags >> 5) & 1 == 1
    contacts = ob_types.shape[0] > 0
    prm = moved_obstacles(ob_params, ob_offset)
    moving = np.any(ob_vel != 0.0)
    collide = (cflags & COLLISION_PASS_BITS) != 0
    vt_pairs = np.zeros((0, 2), dtype=np.int64)  # self-collision pair lists, kept across steps
    ee_pairs = np.zeros((0, 2), dtype=np.int64)
    ref_x = np.full((n if collide else 0, 3), np.inf)
    ne = e_off[1]
    nb = b_off[1]
    nc = c_off[1]
    K0 = K[0:ne]
    B0 = B[0:nb]
    kb0 = kb[0:nb]
    Sg0 = Sg[0:nc]
    ks0 = ks[0:nc]
    md = mdiag[0:n]
    for s in range(n_steps):
        eval_forces(x, v, wind, flags, mass, gravity, damping_rate, alpha, c_air, sigma,
                    edges0, edge_dir0, rest0, stretch_coef, breen_c0, triples0, bend_dir0, bend_coef, x0_curv,
                    corners0, shear_coef, x0_shear, tris, normals, f)
        # BDF2: (M + βC + β²H)Δv = β f − β²H v + ⅓M(v − v₋₁) − (β/3)H(x − x₋₁),  β = 2h/3;
        #       x₊₁ = x + ⅓(x − x₋₁) + β v₊₁.   Backward Euler: β = h and no history terms.
        use2 = bdf2 and hist_ok[0] == 1
        heff = 2.0 * h / 3.0 if use2 else h
        h2 = heff * heff
        if use_air:
            air_linearisation(x, v, tris, wind, c_air, sigma, normals, drag)
        lumped_mass(mass, damping_rate, use_damping, drag, heff, md)
        if contacts:
            contact_constraints(x, v, f, touching, ob_types, prm, ob_friction, mass, heff, cn, con, cfric, md, ob_vel,
                                fr, fmax)
        stale[0] = 1  # the band factor, if used, is rebuilt on demand
        ok = mg_setup(x, h2, precond, n_levels, n_off, e_off, b_off, c_off, i_off, lwo_off, lfo_off, sigma_l,
                      inject, P_idx, P_w, rest, edges, edge_dir, triples, bend_dir, corners,
                      flags, stretch_coef, alpha, breen_c0, bend_coef, x0_curv, shear_coef, x0_shear,
                      xl, K, B, kb, Sg, ks, mdiag, free, Dblk, Dinv,
                      lw_off, lw_idx, lw_slot, lw_piv, lw_low, lf_off, lf_idx, lf_slot, lf_piv, lf_low, chol, con, cn, pen)
        if not ok:
            return 4, s, -1, math.nan
        implicit_rhs(f, v, heff, edges0, K0, triples0, B0, kb0, corners0, Sg0, ks0, fr, rhs)
        if use2:
            for q in range(n):
                for i in range(3):
                    dxh[q, i] = (x[q, i] - hist_x[q, i]) / 3.0
            apply_H(dxh, edges0, K0, triples0, B0, kb0, corners0, Sg0, ks0, tmp)
            for q in range(n):
                if fr[q]:
                    for i in range(3):
                        rhs[q, i] += mass[q] * (v[q, i] - hist_v[q, i]) / 3.0 - heff * tmp[q, i]
        if use2:
            hist_v_old[:] = hist_v
        if bdf2:
            hist_x[:] = x
            hist_v[:] = v
            hist_ok[0] = 1
        # ---- Newton: the first pass is the Baraff–Witkin linearised step; further passes
        # re-evaluate forces and H at the current estimate and solve for the correction
        it, rel = filtered_pcg(False, rhs, dv, r, z, p, Ap, tol, vtol, max_iter, h2, precond, omega, fr, con, cn, md,
                               Dblk0, bslot, stale, edges0, K0, triples0, B0, kb0, corners0, Sg0, ks0, *mg)
        for _ in range(FRICTION_PASSES if contacts else 0):
            md_before[:] = md
            if not refine_friction(v, dv, con, cn, cfric, fmax, touching, ob_vel, heff, md, rhs):
                break
            # the preconditioner again, with the raised dampers on the diagonal (a sticking
            # particle's h·c is orders of magnitude above its mass: without it PCG stalls); H is kept.
            # One level: the changed diagonal blocks in place, then the lines (or blocks) refactored
            stale[0] = 1  # the band factor, if used, is rebuilt on demand
            if n_levels == 1:
                raise_diagonal(md, md_before, con, cn, Dblk[0:n], pen[0:n])
                if precond == 1:
                    line_blocks(Dblk[0:n], fr, lw_off[lwo_off[0]:lwo_off[1]], lw_idx[0:n], lw_piv[0:n], lw_low[0:n])
                    line_blocks(Dblk[0:n], fr, lf_off[lfo_off[0]:lfo_off[1]], lf_idx[0:n], lf_piv[0:n], lf_low[0:n])
                elif precond == 0:
                    invert_blocks(Dblk[0:n], Dinv[0:n])
            else:
                ok = mg_setup(x, h2, precond, n_levels, n_off, e_off, b_off, c_off, i_off, lwo_off, lfo_off, sigma_l,
                              inject, P_idx, P_w, rest, edges, edge_dir, triples, bend_dir, corners,
                              flags, stretch_coef, alpha, breen_c0, bend_coef, x0_curv, shear_coef, x0_shear,
                              xl, K, B, kb, Sg, ks, mdiag, free, Dblk, Dinv,
                              lw_off, lw_idx, lw_slot, lw_piv, lw_low, lf_off, lf_idx, lf_slot, lf_piv, lf_low, chol,
                              con, cn, pen, False)
                if not ok:
                    return 4, s, -1, math.nan
            it2, rel = filtered_pcg(True, rhs, dv, r, z, p, Ap, tol, vtol, max_iter, h2, precond, omega, fr, con, cn, md,
                                    Dblk0, bslot, stale, edges0, K0, triples0, B0, kb0, corners0, Sg0, ks0, *mg)
            it += it2
        for newton in range(1, n_newton):
            for q in range(n):
                for i in range(3):
                    vk[q, i] = v[q, i] + (dv[q, i] if fr[q] else 0.0)
                    xk[q, i] = x[q, i] + (dxh[q, i] if use2 else 0.0) + heff * vk[q, i]
            eval_forces(xk, vk, wind, flags, mass, gravity, damping_rate, alpha, c_air, sigma,
                        edges0, edge_dir0, rest0, stretch_coef, breen_c0, triples0, bend_dir0, bend_coef, x0_curv,
                        corners0, shear_coef, x0_shear, tris, normals, f)
            stale[0] = 1  # the band factor, if used, is rebuilt on demand
            ok = mg_setup(xk, h2, precond, n_levels, n_off, e_off, b_off, c_off, i_off, lwo_off, lfo_off, sigma_l,
                          inject, P_idx, P_w, rest, edges, edge_dir, triples, bend_dir, corners,
                          flags, stretch_coef, alpha, breen_c0, bend_coef, x0_curv, shear_coef, x0_shear,
                          xl, K, B, kb, Sg, ks, mdiag, free, Dblk, Dinv,
                          lw_off, lw_idx, lw_slot, lw_piv, lw_low, lf_off, lf_idx, lf_slot, lf_piv, lf_low, chol, con, cn, pen)
            if not ok:
                return 4, s, -1, math.nan
            # −g(Δv) = β f(x_k, v_k) − M Δv (+ ⅓M(v − v₋₁) for BDF2), plus friction at v_k
            if contacts:
                friction_force(vk, con, cn, cfric, touching, ob_vel, ffric)
            for q in range(n):
                for i in range(3):
                    if fr[q]:
                        rhs[q, i] = heff * (f[q, i] + ffric[q, i]) - mass[q] * dv[q, i]
                        if use2:
                            rhs[q, i] += mass[q] * (v[q, i] - hist_v_old[q, i]) / 3.0
                    else:
                        rhs[q, i] = 0.0
            dv_k[:] = dv
            it2, rel = filtered_pcg(False, rhs, dv, r, z, p, Ap, tol, vtol, max_iter, h2, precond, omega, fr, con, cn, md,
                                    Dblk0, bslot, stale, edges0, K0, triples0, B0, kb0, corners0, Sg0, ks0, *mg)
            it += it2
            for q in range(n):
                for i in range(3):
                    dv[q, i] += dv_k[q, i]
        if stale[0] == 2:  # the band matrix was not SPD (non-finite state)
            return 4, s, -1, math.nan
        stats[s, 0] = it
        stats[s, 1] = rel
        # ---- update (kinetic friction already in the solve), obstacle contact
        if contacts or collide:
            x_prev[:] = x
        for q in range(n):  # pinned particles keep their prescribed velocity
            if fr[q]:
                for i in range(3):
                    v[q, i] += dv[q, i]
        if moving:
            advance_obstacles(ob_params, ob_offset, ob_vel, heff, prm)
        for q in range(n):
            for i in range(3):
                x[q, i] += (dxh[q, i] if use2 else 0.0) + heff * v[q, i]
        if contacts:
            collide_particles(x, v, x_prev, inv_mass, ob_types, prm, ob_friction, restitution, thickness,
                              touching, ob_vel, heff)
        if strain_limit > 0.0:  # after the obstacles: an edge they stretched is limited too
            limit_strain(x, v, inv_mass, edges0, rest0, strain_limit, strain_iters)
        if collide:
            vt_pairs, ee_pairs = collision_pass(x, v, x_prev, inv_mass, mass, heff, restitution, thickness,
                                                cflags, citers, cthick, cmu, ctris, cedges, cpoints, cmargin, mv, mf, mn,
                                                mmu, g_lo, g_inv_cell, g_dims, g_start, g_items, stamp,
                                                vt_pairs, ee_pairs, ref_x)
        status, pp, value = check_state(x, v, edges0, rest0, max_speed, max_strain_percent)
        if status != 0:
            return status, s, pp, value
    return 0, n_steps, -1, 0.0
