"""The band preconditioner: the whole matrix factored by a banded Cholesky in lattice-line order,
for small lattices (what ``preconditioner="auto"`` picks while its factorisation work is small).
"""

from __future__ import annotations

import math

from .._numba import kernel_only

from .lines import block_norm


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



@kernel_only
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



@kernel_only
def band_assemble(Dblk, free, h2, A, slot, Ab):
    """Fill the band matrix ``Ab`` from the diagonal blocks ``Dblk`` (mass, h²H, contact penalty)
    and the off-diagonal blocks of h²H within the band; a block X beyond it (the coupling of a
    bending triple's ends across lines) is dropped and ``|X|_F·I`` added to both its particles'
    diagonal blocks, which keeps the band matrix SPD (``[[cI, −X], [−Xᵀ, cI]]`` is PSD for
    c ≥ |X|₂). Pinned particles get identity rows (their couplings are left out, as the filter
    removes them)."""
    Ab[:] = 0.0
    w = (Ab.shape[1] - 3) // 3
    for q in range(Dblk.shape[0]):
        o = 3 * slot[q]
        for j in range(3):
            if not free[q]:
                Ab[o + j, 0] = 1.0
                continue
            for i in range(j, 3):
                Ab[o + j, i - j] = Dblk[q, i, j]
    for q in range(Dblk.shape[0]):
        if not free[q]:
            continue
        for s in range(A.row_off[q], A.row_off[q + 1]):
            c = A.col[s]
            if slot[c] >= slot[q] or not free[c]:  # each pair once, from its later particle's row
                continue
            if slot[q] - slot[c] <= w:
                _band_add(Ab, slot, q, c, A.vals[s], h2)
                continue
            bound = h2 * block_norm(A.vals, s)
            for p in (q, c):
                o = 3 * slot[p]
                for i in range(3):
                    Ab[o + i, 0] += bound



@kernel_only
def band_cholesky(Ab):
    """Lower Cholesky factor of the band matrix in place (same storage; right-looking, by
    columns). False if not SPD.

    The factor is kept in double precision. Where the band holds the whole matrix (no bending
    ends outside it) the first PCG iteration is then exact; a single-precision factor, about a
    fifth faster to compute, leaves each solve inexact by up to the CG tolerance, and at
    RibbonDrop-v1's 1e-3 that kept a ribbon lying on the floor moving at about 1 cm/s for ever
    (``docs/solver_core.md``)."""
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



@kernel_only
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



@kernel_only
def band_factor(Dblk, free, h2, A, slot, Ab):
    """:func:`band_assemble` then :func:`band_cholesky` into ``Ab``; False if the matrix is not SPD
    (non-finite or indefinite)."""
    band_assemble(Dblk, free, h2, A, slot, Ab)
    return band_cholesky(Ab)
