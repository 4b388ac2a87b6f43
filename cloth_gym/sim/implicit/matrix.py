"""Block-sparse matrix algebra of the implicit solve: the operator ``A = diag(m̃) + h²H`` applied
row by row, its diagonal blocks, 3×3 inverses, the right-hand side ``h·(f − h·H·v)``, the dense
(coarsest-level) matrix and its Cholesky factor, and the vector updates of CG.

``H`` is a :class:`~cloth_gym.sim.implicit.bundles.Matrix` (3×3 blocks on the lattice's stencil);
pinned and kinematic particles (``free`` False) have zero rows.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import types, uint64
from numba.core import cgutils
from numba.extending import intrinsic

from .._numba import kernel_only


# ============================================================================ operator
# The product gathers row by row (each row's sum in column order), so it can run in parallel rows
# without changing a bit. It does not: numba segfaults when a cached function that calls a
# parallel=True one is loaded from its on-disk cache, and on the 41×41 tablecloth 2 OpenMP
# threads cut the wall time of a 1 ms step by 16 % while raising its CPU time by 67 % (the threads
# spin between the many short parallel regions of a CG iteration; docs/benchmark.md).



@intrinsic
def block_product_add(typingctx, vals, s, p0, p1, p2, acc):
    """``acc + vals[s]·(p0, p1, p2)`` in lanes 0–2 of a 4-tuple (lane 3 is not used): the block's three
    columns gathered from its nine values by vector shuffles, multiplied by the three components and
    added up as one 4-wide vector each.

    Lane i computes ``acc_i + ((B_i0·p0 + B_i1·p1) + B_i2·p2)``, the plain loop's expression in its
    order (no fused multiply-add), so the sums are the same bit for bit; numba's LLVM does not
    vectorise the plain loop. ``vals`` is a C-contiguous (n_blocks, 3, 3) float64 array (any other
    layout is refused when the caller compiles), ``s`` a block index in range (not checked)."""
    acc4 = types.UniTuple(types.float64, 4)
    if not (isinstance(vals, types.Array) and vals.ndim == 3 and vals.dtype == types.float64 and vals.layout == "C"
            and isinstance(s, types.Integer) and acc == acc4):
        return None
    sig = acc4(vals, s, types.float64, types.float64, types.float64, acc4)  # numba casts p0–p2 to float64

    def codegen(context, builder, signature, args):
        i32 = ir.IntType(32)
        f64 = ir.DoubleType()
        v4 = ir.VectorType(f64, 4)
        v8 = ir.VectorType(f64, 8)
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        stride = cgutils.unpack_tuple(builder, ary.strides, 3)[0]  # bytes from one block to the next
        index = context.cast(builder, args[1], signature.args[1], types.intp)
        byte = builder.gep(builder.bitcast(ary.data, ir.IntType(8).as_pointer()), [builder.mul(index, stride)])
        first = builder.bitcast(byte, f64.as_pointer())
        eight = builder.load(builder.bitcast(first, v8.as_pointer()), align=8)  # B00 … B21
        ninth = builder.insert_element(ir.Constant(v8, [0.0] * 8),
                                       builder.load(builder.gep(first, [ir.Constant(ir.IntType(64), 8)]), align=8),
                                       ir.Constant(i32, 1))  # (0, B22, 0, …): lanes 8, 9 of a shuffle

        def column(lanes):
            return builder.shuffle_vector(eight, ninth, ir.Constant(ir.VectorType(i32, 4), lanes))

        def splat(x):
            one = builder.insert_element(ir.Constant(v4, ir.Undefined), x, ir.Constant(i32, 0))
            return builder.shuffle_vector(one, ir.Constant(v4, ir.Undefined), ir.Constant(ir.VectorType(i32, 4), [0] * 4))

        t = builder.fadd(builder.fmul(column([0, 3, 6, 8]), splat(args[2])),
                         builder.fmul(column([1, 4, 7, 8]), splat(args[3])))
        t = builder.fadd(t, builder.fmul(column([2, 5, 9, 8]), splat(args[4])))
        a = ir.Constant(v4, ir.Undefined)
        for i in range(4):
            a = builder.insert_element(a, builder.extract_value(args[5], i), ir.Constant(i32, i))
        a = builder.fadd(a, t)
        out = cgutils.get_null_value(context.get_value_type(signature.return_type))
        for i in range(4):
            out = builder.insert_value(out, builder.extract_element(a, ir.Constant(i32, i)), i)
        return out

    return sig, codegen



@kernel_only
def _row_apply(row_off, col, vals, p, q):
    """Row q of ``H p`` (the three components), summed over the row's blocks in column order, each
    block's product a 4-wide vector (:func:`block_product_add`; 1.13× the scalar loop on the 41 × 41
    lattice, the same sums).

    The block and column indices are unsigned: numba wraps a negative signed index around, and the
    test for it on every load made the product 1.7× slower (41 × 41 lattice, same sums)."""
    acc = (0.0, 0.0, 0.0, 0.0)
    for s in range(uint64(row_off[q]), uint64(row_off[q + 1])):
        c = uint64(col[s])
        acc = block_product_add(vals, s, p[c, 0], p[c, 1], p[c, 2], acc)
    return acc[0], acc[1], acc[2]



@kernel_only
def _matvec_rows(row_off, col, vals, p, mdiag, h2, free, y):
    """The rows of the product (:func:`_matvec`), in order."""
    plain = mdiag.shape[0] == 0
    for q in range(p.shape[0]):
        if plain:  # y = H p
            y[q, 0], y[q, 1], y[q, 2] = _row_apply(row_off, col, vals, p, q)
        elif free[q]:
            a0, a1, a2 = _row_apply(row_off, col, vals, p, q)
            m = mdiag[q]
            y[q, 0] = m * p[q, 0] + h2 * a0
            y[q, 1] = m * p[q, 1] + h2 * a1
            y[q, 2] = m * p[q, 2] + h2 * a2
        else:
            zero_row(y, q)



@kernel_only
def _matvec(A, p, mdiag, h2, free, y):
    """``y = diag(mdiag)·p + h²·H p`` with zero rows where ``free`` is False, or ``y = H p`` when
    ``mdiag`` is empty."""
    _matvec_rows(A.row_off, A.col, A.vals, p, mdiag, h2, free, y)



@kernel_only
def apply_H(p, A, y):
    """``y = H·p`` (dyne/cm × cm), ``A`` a :class:`Matrix`."""
    _matvec(A, p, np.zeros(0), 0.0, np.zeros(0, dtype=np.bool_), y)



@kernel_only
def diagonal_blocks(mdiag, h2, A, Dblk):
    """3×3 diagonal blocks of ``diag(mdiag) + h²·H`` into ``Dblk (N, 3, 3)``."""
    for q in range(mdiag.shape[0]):
        M = A.vals[A.diag[q]]
        for i in range(3):
            for j in range(3):
                Dblk[q, i, j] = h2 * M[i, j]
            Dblk[q, i, i] += mdiag[q]



@kernel_only
def inv3(M, out):
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



@kernel_only
def zero_row(r, q):
    """Set row q of an (N, 3) array to zero (pinned particles drop out of the solve)."""
    r[q, 0] = 0.0
    r[q, 1] = 0.0
    r[q, 2] = 0.0



@kernel_only
def matvec_A(p, mdiag, h2, A, free, y):
    """``y = A p``, ``A = diag(mdiag) + h²H``, zero rows at pinned particles."""
    _matvec(A, p, mdiag, h2, free, y)



@kernel_only
def dot(a, b):
    s = 0.0
    for q in range(a.shape[0]):
        s += a[q, 0] * b[q, 0] + a[q, 1] * b[q, 1] + a[q, 2] * b[q, 2]
    return s



@kernel_only
def dense_matrix(mdiag, h2, A, free, out):
    """Dense ``A`` (3N × 3N) of a small level; identity rows/columns at pinned particles."""
    out[:] = 0.0
    for q in range(mdiag.shape[0]):
        if not free[q]:
            for i in range(3):
                out[3 * q + i, 3 * q + i] = 1.0
            continue
        for s in range(A.row_off[q], A.row_off[q + 1]):
            c = A.col[s]
            if not free[c]:
                continue
            M = A.vals[s]
            for i in range(3):
                for j in range(3):
                    out[3 * q + i, 3 * c + j] = h2 * M[i, j]
        for i in range(3):
            out[3 * q + i, 3 * q + i] += mdiag[q]



@kernel_only
def xpby(z, beta, p):
    """p = z + β p."""
    for q in range(p.shape[0]):
        for i in range(3):
            p[q, i] = z[q, i] + beta * p[q, i]



@kernel_only
def residual(b, x, mdiag, h2, H, free, r):
    """``r = b − A x`` (zero at pinned particles)."""
    matvec_A(x, mdiag, h2, H, free, r)
    for q in range(b.shape[0]):
        if free[q]:
            for i in range(3):
                r[q, i] = b[q, i] - r[q, i]



@kernel_only
def implicit_rhs(f, v, h, H, free, rhs):
    """``rhs = h (f − h H v)``, zero at pinned particles."""
    apply_H(v, H, rhs)
    for q in range(f.shape[0]):
        for i in range(3):
            rhs[q, i] = h * (f[q, i] - h * rhs[q, i]) if free[q] else 0.0


# ============================================================================ dense Cholesky (coarsest level)
@kernel_only
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



@kernel_only
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
