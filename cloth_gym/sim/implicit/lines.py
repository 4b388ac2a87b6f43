"""The line and block-Jacobi preconditioners (and multigrid's smoother): exact block-tridiagonal
solves along the warp and the weft lines of the lattice, averaged, each line's matrix its principal
submatrix of A with the couplings two steps along it bounded onto the diagonal; or 3×3 diagonal
blocks inverted.
"""

from __future__ import annotations

import math

import numpy as np
from numba import uint64

from .._numba import copy_into, kernel_only

from .bundles import LINES
from .matrix import inv3, zero_row


# ---------------------------------------------------------------- line preconditioner
@kernel_only
def line_blocks(Dblk, add, free, lines_off, lines_idx, diag_out, low_out):
    """Block-tridiagonal factor data for the lines of one direction.

    For each line (particles in order), the matrix has the full 3×3 diagonal blocks of A, raised by
    ``add[slot]·I`` (:func:`set_line_couplings`), and the couplings between consecutive particles
    (``low_out``). Block Thomas factorisation: stores the inverted pivots in ``diag_out`` and the
    (unchanged) lower blocks in ``low_out`` (per particle slot, coupling to the previous particle
    of its line).
    """
    n_lines = lines_off.shape[0] - 1
    tmp = np.empty((3, 3))
    piv = np.empty((3, 3))
    for L in range(n_lines):
        s0 = lines_off[L]
        s1 = lines_off[L + 1]
        for s in range(s0, s1):
            q = lines_idx[s]
            copy_into(piv, Dblk[q])
            for i in range(3):
                piv[i, i] += add[s]
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
            inv3(piv, diag_out[s])



@kernel_only
def block_norm(vals, s):
    """Frobenius norm of block s (an upper bound of its spectral norm)."""
    c = 0.0
    for i in range(3):
        for j in range(3):
            c += vals[s, i, j] * vals[s, i, j]
    return math.sqrt(c)



@kernel_only
def set_line_couplings(h2, A, free, prev, prev2, slot_of, low_out, add_out):
    """The line preconditioner's matrix for the lines of one direction: each line's principal
    submatrix of ``diag + h²H``, tridiagonal. ``low_out[slot]`` gets ``h²·H[q, prev(q)]``, the block
    coupling particle q to its predecessor on its line (``prev[q]``: that block's index in
    ``A.vals``, −1 for a line's first particle). A coupling two steps along the line (``prev2[q]``,
    a bending triple's ends) is beyond the tridiagonal: dropped, with its norm ``h²|X|_F`` added to
    both particles' diagonals (``add_out[slot]``), which keeps each line's matrix SPD (a principal
    submatrix of an SPD matrix is SPD, and ``[[cI, −X], [−Xᵀ, cI]]`` is PSD for c ≥ |X|₂). Couplings
    to other lines are left to the other direction's solve. Zero where a particle is pinned."""
    low_out[:] = 0.0
    add_out[:] = 0.0
    for q in range(prev.shape[0]):
        if not free[q]:
            continue
        s = prev[q]
        if s >= 0 and free[A.col[s]]:
            M = A.vals[s]
            o = slot_of[q]
            for i in range(3):
                for j in range(3):
                    low_out[o, i, j] = h2 * M[i, j]
        s = prev2[q]
        if s >= 0 and free[A.col[s]]:
            c = h2 * block_norm(A.vals, s)
            add_out[slot_of[q]] += c
            add_out[slot_of[A.col[s]]] += c



@kernel_only
def line_solve(r, lines_off, lines_idx, invpiv, low, z, scale, work):
    """z += scale · L⁻¹ r for block-tridiagonal L (forward/back substitution per line).

    Consecutive lines of equal length are solved two at a time (:func:`_line_pair`); a line left
    over, or next to one of another length (a disc's lines), goes through the same kernel paired
    with itself, about as fast as one line alone. Each line's operations and their order are those
    of one line solved alone, so the result is the same bit for bit, given that the lines of one
    direction share no particle (each particle has one slot, :func:`~.levels.lattice_lines`) and
    ``z`` is not ``r``."""
    n_lines = lines_off.shape[0] - 1
    L = 0
    while L < n_lines:
        n = lines_off[L + 1] - lines_off[L]
        if L + 1 < n_lines and lines_off[L + 2] - lines_off[L + 1] == n:
            _line_pair(r, lines_off[L], lines_off[L + 1], n, lines_idx, invpiv, low, z, scale, work)
            L += 2
        else:
            _line_pair(r, lines_off[L], lines_off[L], n, lines_idx, invpiv, low, z, scale, work)
            L += 1



@kernel_only
def _line_pair(r, a0, b0, n, lines_idx, invpiv, low, z, scale, work):
    """Two lines of ``n`` particles from slots ``a0`` and ``b0`` (the same line when ``a0 == b0``:
    its values are computed twice and added to ``z`` once) solved with their chains interleaved.

    Each substitution is a chain through its line, one particle after the other, each link waiting
    for the last (a 3×3 product, then another): one chain leaves the CPU idle most of the time, two
    keep it busy (on the 41 × 41 lattice both directions' applies ~1.5× faster than one line at a
    time). The running values stay in registers (``a*`` and ``b*``); ``work`` keeps the forward
    pass's values for the backward one, and each particle's ``x`` goes into ``z`` as the backward
    pass reaches it. Slots are unsigned: numba's wraparound test of a signed index costs on every
    load."""
    two = a0 != b0
    a_0 = a_1 = a_2 = b_0 = b_1 = b_2 = 0.0
    # forward: y_s = invpiv_s (r_s − C_s y_{s−1}),  C_s = low[s]
    for k in range(n):
        s = uint64(a0 + k)
        u = uint64(b0 + k)
        q = uint64(lines_idx[s])
        p = uint64(lines_idx[u])
        x0 = r[q, 0]
        x1 = r[q, 1]
        x2 = r[q, 2]
        y0 = r[p, 0]
        y1 = r[p, 1]
        y2 = r[p, 2]
        if k > 0:
            C = low[s]
            D = low[u]
            x0 -= C[0, 0] * a_0 + C[0, 1] * a_1 + C[0, 2] * a_2
            x1 -= C[1, 0] * a_0 + C[1, 1] * a_1 + C[1, 2] * a_2
            x2 -= C[2, 0] * a_0 + C[2, 1] * a_1 + C[2, 2] * a_2
            y0 -= D[0, 0] * b_0 + D[0, 1] * b_1 + D[0, 2] * b_2
            y1 -= D[1, 0] * b_0 + D[1, 1] * b_1 + D[1, 2] * b_2
            y2 -= D[2, 0] * b_0 + D[2, 1] * b_1 + D[2, 2] * b_2
        P = invpiv[s]
        Q = invpiv[u]
        a_0 = P[0, 0] * x0 + P[0, 1] * x1 + P[0, 2] * x2
        a_1 = P[1, 0] * x0 + P[1, 1] * x1 + P[1, 2] * x2
        a_2 = P[2, 0] * x0 + P[2, 1] * x1 + P[2, 2] * x2
        b_0 = Q[0, 0] * y0 + Q[0, 1] * y1 + Q[0, 2] * y2
        b_1 = Q[1, 0] * y0 + Q[1, 1] * y1 + Q[1, 2] * y2
        b_2 = Q[2, 0] * y0 + Q[2, 1] * y1 + Q[2, 2] * y2
        work[s, 0] = a_0
        work[s, 1] = a_1
        work[s, 2] = a_2
        work[u, 0] = b_0
        work[u, 1] = b_1
        work[u, 2] = b_2
    # backward: x_s = y_s − invpiv_s C_{s+1}ᵀ x_{s+1}, from x_{last} = y_{last} (in a*, b*)
    for k in range(n - 1, -1, -1):
        s = uint64(a0 + k)
        u = uint64(b0 + k)
        if k < n - 1:
            C = low[s + uint64(1)]
            D = low[u + uint64(1)]
            x0 = C[0, 0] * a_0 + C[1, 0] * a_1 + C[2, 0] * a_2
            x1 = C[0, 1] * a_0 + C[1, 1] * a_1 + C[2, 1] * a_2
            x2 = C[0, 2] * a_0 + C[1, 2] * a_1 + C[2, 2] * a_2
            y0 = D[0, 0] * b_0 + D[1, 0] * b_1 + D[2, 0] * b_2
            y1 = D[0, 1] * b_0 + D[1, 1] * b_1 + D[2, 1] * b_2
            y2 = D[0, 2] * b_0 + D[1, 2] * b_1 + D[2, 2] * b_2
            P = invpiv[s]
            Q = invpiv[u]
            a_0 = work[s, 0] - (P[0, 0] * x0 + P[0, 1] * x1 + P[0, 2] * x2)
            a_1 = work[s, 1] - (P[1, 0] * x0 + P[1, 1] * x1 + P[1, 2] * x2)
            a_2 = work[s, 2] - (P[2, 0] * x0 + P[2, 1] * x1 + P[2, 2] * x2)
            b_0 = work[u, 0] - (Q[0, 0] * y0 + Q[0, 1] * y1 + Q[0, 2] * y2)
            b_1 = work[u, 1] - (Q[1, 0] * y0 + Q[1, 1] * y1 + Q[1, 2] * y2)
            b_2 = work[u, 2] - (Q[2, 0] * y0 + Q[2, 1] * y1 + Q[2, 2] * y2)
        q = uint64(lines_idx[s])
        z[q, 0] += scale * a_0
        z[q, 1] += scale * a_1
        z[q, 2] += scale * a_2
        if two:
            p = uint64(lines_idx[u])
            z[p, 0] += scale * b_0
            z[p, 1] += scale * b_1
            z[p, 2] += scale * b_2


# ============================================================================ vector kernels
@kernel_only
def smooth_apply(r, precond, Dinv, free, lw_off, lw_idx, lw_piv, lw_low, lf_off, lf_idx, lf_piv, lf_low,
                 work, scale, z):
    """``z = scale · S r``: S = block Jacobi (``Precond.JACOBI``) or ½(L_warp⁻¹ + L_weft⁻¹) (``LINES``)."""
    n = r.shape[0]
    if precond == LINES:
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



@kernel_only
def invert_blocks(Dblk, Dinv):
    for q in range(Dblk.shape[0]):
        inv3(Dblk[q], Dinv[q])
