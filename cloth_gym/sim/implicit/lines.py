"""The line and block-Jacobi preconditioners (and multigrid's smoother): exact block-tridiagonal
solves along the warp and the weft lines of the lattice, averaged, each line's matrix its principal
submatrix of A with the couplings two steps along it bounded onto the diagonal; or 3×3 diagonal
blocks inverted.
"""

from __future__ import annotations

import math

import numpy as np

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

    Each substitution is a chain through the line, one particle after the other: the running
    value stays in registers (``w0, w1, w2``) instead of a round trip through ``work`` (which keeps
    the forward pass's values for the backward one), and each particle's ``x`` goes into ``z`` as
    the backward pass reaches it. The same operations in the same order as one pass after the
    other, 1.4× faster on the 41 × 41 lattice."""
    n_lines = lines_off.shape[0] - 1
    for L in range(n_lines):
        s0 = lines_off[L]
        s1 = lines_off[L + 1]
        # forward: y_s = invpiv_s (r_s − C_s y_{s−1}),  C_s = low[s]
        w0 = 0.0
        w1 = 0.0
        w2 = 0.0
        for s in range(s0, s1):
            q = lines_idx[s]
            t0 = r[q, 0]
            t1 = r[q, 1]
            t2 = r[q, 2]
            if s > s0:
                C = low[s]
                t0 -= C[0, 0] * w0 + C[0, 1] * w1 + C[0, 2] * w2
                t1 -= C[1, 0] * w0 + C[1, 1] * w1 + C[1, 2] * w2
                t2 -= C[2, 0] * w0 + C[2, 1] * w1 + C[2, 2] * w2
            P = invpiv[s]
            w0 = P[0, 0] * t0 + P[0, 1] * t1 + P[0, 2] * t2
            w1 = P[1, 0] * t0 + P[1, 1] * t1 + P[1, 2] * t2
            w2 = P[2, 0] * t0 + P[2, 1] * t1 + P[2, 2] * t2
            work[s, 0] = w0
            work[s, 1] = w1
            work[s, 2] = w2
        # backward: x_s = y_s − invpiv_s C_{s+1}ᵀ x_{s+1}, from x_{last} = y_{last} (in w)
        for s in range(s1 - 1, s0 - 1, -1):
            if s < s1 - 1:
                C = low[s + 1]
                t0 = C[0, 0] * w0 + C[1, 0] * w1 + C[2, 0] * w2
                t1 = C[0, 1] * w0 + C[1, 1] * w1 + C[2, 1] * w2
                t2 = C[0, 2] * w0 + C[1, 2] * w1 + C[2, 2] * w2
                P = invpiv[s]
                w0 = work[s, 0] - (P[0, 0] * t0 + P[0, 1] * t1 + P[0, 2] * t2)
                w1 = work[s, 1] - (P[1, 0] * t0 + P[1, 1] * t1 + P[1, 2] * t2)
                w2 = work[s, 2] - (P[2, 0] * t0 + P[2, 1] * t1 + P[2, 2] * t2)
            q = lines_idx[s]
            z[q, 0] += scale * w0
            z[q, 1] += scale * w1
            z[q, 2] += scale * w2


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
