"""The PCG's inner kernels against plain references: the line preconditioner's block-tridiagonal
solves against numpy's dense solve, and bit for bit against each line solved alone; the block
product against the plain sums in Python; the fused filter-and-dot and update-and-norm passes
against the separate passes they replace (bit for bit: the solver's trajectories must not change)."""

from __future__ import annotations

import numpy as np

from cloth_gym.sim.implicit.cg import axpy_pair_norm2, filter_dot
from cloth_gym.sim.implicit.contact import filter_vec
from cloth_gym.sim.implicit.lines import line_blocks, line_solve
from cloth_gym.sim.implicit.bundles import Matrix
from cloth_gym.sim.implicit.matrix import apply_H, dot

RNG = np.random.default_rng(7)


def _lines_system(lengths):
    """Random SPD lines: particle order shuffled, per-slot couplings to the previous particle."""
    n = sum(lengths)
    idx = RNG.permutation(n)
    off = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    S = RNG.standard_normal((n, 3, 3))
    D = 12.0 * np.eye(3) + 0.5 * (S + S.transpose(0, 2, 1))
    low = 0.8 * RNG.standard_normal((n, 3, 3))
    add = RNG.random(n)
    return off, idx, D, low, add


def test_the_line_solve_solves_each_lines_block_tridiagonal_system():
    lengths = [5, 5, 1, 3, 7]  # equal and unequal lines, a line of one particle
    off, idx, D, low, add = _lines_system(lengths)
    n = len(idx)
    free = np.ones(n, dtype=np.bool_)
    piv = np.empty((n, 3, 3))
    line_blocks(D, add, free, off, idx, piv, low)
    r = RNG.standard_normal((n, 3))
    z0 = RNG.standard_normal((n, 3))
    z = z0.copy()
    line_solve(r, off, idx, piv, low, z, 0.5, np.empty((n, 3)))
    for a, b in zip(off[:-1], off[1:]):
        m = b - a
        M = np.zeros((3 * m, 3 * m))
        for k in range(m):
            M[3 * k:3 * k + 3, 3 * k:3 * k + 3] = D[idx[a + k]] + add[a + k] * np.eye(3)
            if k > 0:
                M[3 * k:3 * k + 3, 3 * k - 3:3 * k] = low[a + k]
                M[3 * k - 3:3 * k, 3 * k:3 * k + 3] = low[a + k].T
        x = np.linalg.solve(M, r[idx[a:b]].ravel()).reshape(m, 3)
        np.testing.assert_allclose(z[idx[a:b]], z0[idx[a:b]] + 0.5 * x, rtol=1e-12, atol=1e-12)


def test_lines_solved_in_pairs_equal_each_line_solved_alone_bit_for_bit():
    lengths = [4, 4, 0, 4, 2]  # a pair of equal length, an empty line, two lines paired with themselves
    off, idx, D, low, add = _lines_system(lengths)
    n = len(idx)
    piv = np.empty((n, 3, 3))
    line_blocks(D, add, np.ones(n, dtype=np.bool_), off, idx, piv, low)
    r = RNG.standard_normal((n, 3))
    z0 = RNG.standard_normal((n, 3))
    together = z0.copy()
    line_solve(r, off, idx, piv, low, together, 0.5, np.empty((n, 3)))
    alone = z0.copy()
    for L in range(len(lengths)):
        line_solve(r, off[L:L + 2], idx, piv, low, alone, 0.5, np.empty((n, 3)))
    assert together.tobytes() == alone.tobytes()


def test_the_block_product_is_the_plain_sums_in_column_order_bit_for_bit():
    n = 30
    rows = [np.sort(RNG.choice(n, size=RNG.integers(1, 9), replace=False)) for _ in range(n)]
    col = np.concatenate(rows).astype(np.int64)
    row_off = np.concatenate([[0], np.cumsum([len(r) for r in rows])]).astype(np.int64)
    stored = RNG.standard_normal((len(col) + 5, 3, 3))
    vals = stored[5:]  # C-contiguous, starting inside a larger array
    p = RNG.standard_normal((n, 3))
    y = np.empty((n, 3))
    apply_H(p, Matrix(row_off, col, np.zeros(n, dtype=np.int64), vals), y)
    for q in range(n):
        a = [0.0, 0.0, 0.0]
        for s in range(row_off[q], row_off[q + 1]):
            B, x = vals[s].tolist(), p[col[s]].tolist()
            for i in range(3):
                a[i] += B[i][0] * x[0] + B[i][1] * x[1] + B[i][2] * x[2]
        assert y[q].tolist() == a


def test_filter_dot_is_the_filter_then_the_dot_bit_for_bit():
    n = 400
    a = RNG.standard_normal((n, 3))
    b = RNG.standard_normal((n, 3))
    free = RNG.random(n) > 0.1
    con = RNG.integers(0, 3, n).astype(np.int8)
    cn = RNG.standard_normal((n, 3))
    cn /= np.linalg.norm(cn, axis=1)[:, None]
    ref = a.copy()
    filter_vec(ref, free, con, cn)
    assert np.all(ref[~free] == 0.0) and np.all(ref[con == 2] == 0.0)
    slide = free & (con == 1)
    np.testing.assert_allclose(np.einsum("ij,ij->i", ref[slide], cn[slide]), 0.0, atol=1e-12)
    out = a.copy()
    s = filter_dot(out, b, free, con, cn)
    assert np.array_equal(out, ref)
    assert s == dot(ref, b)


def test_axpy_pair_norm2_is_the_update_then_the_norm_bit_for_bit():
    n = 300
    x, r, p, Ap = (RNG.standard_normal((n, 3)) for _ in range(4))
    alpha = 0.37
    x1, r1 = x + alpha * p, r - alpha * Ap
    x2, r2 = x.copy(), r.copy()
    s = axpy_pair_norm2(x2, r2, p, Ap, alpha)
    assert np.array_equal(x1, x2) and np.array_equal(r1, r2)
    assert s == dot(r1, r1)
