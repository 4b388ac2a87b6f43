"""Numba kernels of the implicit integrator (see :mod:`cloth_gym.sim.implicit`).

Assembly of the stiffness approximation H per force type, the matrix-free
operator ``A = diag(m̃) + h²H``, block-Jacobi and line smoothers, and the
grid-transfer and vector kernels of the PCG / multigrid solve. Every kernel
works on one lattice level; the kernels take the typed bundles defined here
(:class:`Matrix`, :class:`Levels`, :class:`Work`, :class:`SolveOptions`,
:class:`CGWork`, :class:`Carry`) and those of :mod:`cloth_gym.sim.bundles`.
"""

from __future__ import annotations

import math
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from ._numba import cycles, njit, runtime
from .bundles import (N_PHASES, NOT_SPD, OK, P_ASSEMBLY, P_FACTOR, P_FORCES, P_FRICTION, P_NEWTON, P_PREPARE,
                      P_RHS, P_SOLVE)
from .collision_kernels import COLLISION_PASS_BITS
from .forces import (AIR, DAMPING, STRAIN_DAMPING, air_linearisation, eval_forces, eval_forces_at,
                     eval_strain_damping, linearise_forces, lumped_mass)
from .obstacles import signed_distance
from .substep import finish_substep, needs_previous_positions


class Precond(IntEnum):
    """The preconditioner code of :class:`SolveOptions` (multigrid: LINES with more than one level)."""

    JACOBI = 0  # 3×3 block diagonal
    LINES = 1  # block-tridiagonal solves along warp and weft lines (the multigrid smoother too)
    BAND_WARP = 2  # banded Cholesky, particles in warp-line order
    BAND_WEFT = 3  # banded Cholesky, particles in weft-line order


JACOBI, LINES, BAND_WARP, BAND_WEFT = (int(c) for c in Precond)


class Matrix(NamedTuple):
    """The linearised stiffness H (dyne/cm) of one lattice level as a block-sparse matrix (block
    CSR on the lattice's stencil): row q's blocks are ``vals[row_off[q]:row_off[q+1]]`` (3×3 each),
    in the columns ``col[...]`` (ascending); ``diag[q]`` indexes block (q, q). Every force adds its
    blocks to ``vals`` (:func:`~cloth_gym.sim.forces.linearise_forces`); everything the solver does
    with H — products, diagonal blocks, line couplings, the band and dense factors — reads this."""

    row_off: np.ndarray
    col: np.ndarray
    diag: np.ndarray
    vals: np.ndarray


class Levels(NamedTuple):
    """The lattice levels of the multigrid hierarchy (one level without multigrid), concatenated:
    level l's particle rows are ``n_off[l]:n_off[l+1]`` of every particle-sized array, its edges
    rows ``e_off[l]:e_off[l+1]``, its bending triples ``b_off``, shear corners ``c_off``, injected
    nodes ``i_off``, warp and weft line offsets ``lwo_off`` and ``lfo_off``. Indices inside a level
    are local. Static: built once per model (:class:`~cloth_gym.sim.implicit._Hierarchy`)."""

    n_levels: int
    n_off: np.ndarray
    e_off: np.ndarray
    b_off: np.ndarray
    c_off: np.ndarray
    i_off: np.ndarray
    lwo_off: np.ndarray
    lfo_off: np.ndarray
    sigma: np.ndarray  # (L,) lattice spacing of each level, cm
    inject: np.ndarray  # fine index of each coarse node
    P_idx: np.ndarray  # (N, 4) coarse parents of each fine node (−1: none)
    P_w: np.ndarray  # (N, 4) their bilinear weights
    rest: np.ndarray
    edges: np.ndarray
    edge_dir: np.ndarray
    edge_width: np.ndarray
    triples: np.ndarray
    bend_dir: np.ndarray
    bend_width: np.ndarray
    bend_length: np.ndarray
    corners: np.ndarray
    lw_off: np.ndarray  # warp lines (CSR offsets, particles in line order, each particle's slot)
    lw_idx: np.ndarray
    lw_slot: np.ndarray
    lf_off: np.ndarray  # weft lines
    lf_idx: np.ndarray
    lf_slot: np.ndarray
    row_off: np.ndarray  # the block matrices' rows: level l's at n_off[l] + l : n_off[l+1] + l + 1
    col: np.ndarray  # their columns, level l's blocks at z_off[l]:z_off[l+1] (level-local indices)
    z_off: np.ndarray
    diag: np.ndarray  # (N,) each particle's diagonal block
    e_map: np.ndarray  # (E, 4) the blocks (a,a), (a,b), (b,a), (b,b) of each edge
    b_map: np.ndarray  # (B, 9) the 3×3 blocks of each bending triple
    c_map: np.ndarray  # (S, 9) the 3×3 blocks of each shear corner
    lw_prev: np.ndarray  # (N,) block coupling each particle to its predecessor on its warp line (−1: first)
    lf_prev: np.ndarray  # (N,) the same on its weft line
    lw_prev2: np.ndarray  # (N,) block coupling each particle to the one two steps back on its warp line (−1: none)
    lf_prev2: np.ndarray  # (N,) the same on its weft line


class Work(NamedTuple):
    """Scratch of the solve on every level, overwritten each step (nothing in it outlives a step):
    positions, the stiffness matrices' blocks, lumped mass and free flags, diagonal blocks and their inverses, the
    line factors, the V-cycle's vectors, the dense coarsest (or band) factor and the contact
    penalty blocks."""

    xl: np.ndarray
    vals: np.ndarray  # the blocks of every level's Matrix
    mdiag: np.ndarray
    free: np.ndarray
    Dblk: np.ndarray
    Dinv: np.ndarray
    lw_piv: np.ndarray
    lw_low: np.ndarray
    lf_piv: np.ndarray
    lf_low: np.ndarray
    lw_add: np.ndarray  # (N,) the line matrices' diagonal raise, by slot (set_line_couplings)
    lf_add: np.ndarray
    work: np.ndarray
    rin: np.ndarray
    zl: np.ndarray
    res: np.ndarray
    corr: np.ndarray
    chol: np.ndarray  # the coarsest level's dense factor (float64)
    band: np.ndarray  # the band preconditioner's factor ((0, 1) when unused; band_cholesky)
    cvec: np.ndarray
    cout: np.ndarray
    pen: np.ndarray


class SolveOptions(NamedTuple):
    """The implicit solve's settings (:class:`~cloth_gym.sim.implicit.ImplicitEuler`): CG relative
    tolerance, absolute floor (cm/s), iteration cap, :class:`Precond` code, the line smoother's
    damping ω, BDF2 or backward Euler, Newton passes per step, whether each step's solve starts
    from the previous step's velocity change, and whether a step is solved again with raised friction
    dampers where the first solve left particles sliding more slowly than their dampers assumed
    (:func:`refine_friction`)."""

    tol: float
    vtol: float
    max_iter: int
    precond: int
    omega: float
    bdf2: bool
    n_newton: int
    warm_start: bool
    friction_resolve: bool


class CGWork(NamedTuple):
    """PCG's vectors (N, 3): residual, preconditioned residual, search direction, A·p."""

    r: np.ndarray
    z: np.ndarray
    p: np.ndarray
    Ap: np.ndarray


class Carry(NamedTuple):
    """What a run carries from step to step, and through ``State.solver`` from call to call: BDF2's
    previous positions ``x`` (cm) and velocities ``v`` (cm/s), set when ``ok[0] == 1`` (else the next
    step is backward Euler, which sets them); and the last step's velocity change ``dv`` (cm/s),
    set when ``dv_ok[0] == 1``, the first guess of the next step's solve (``SolveOptions.warm_start``)."""

    x: np.ndarray
    v: np.ndarray
    ok: np.ndarray
    dv: np.ndarray
    dv_ok: np.ndarray


# ============================================================================ operator
# The product gathers row by row (each row's sum in column order), so it can run in parallel rows
# without changing a bit. It does not: numba segfaults when a cached function that calls a
# parallel=True one is loaded from its on-disk cache, and on the 41×41 tablecloth 2 OpenMP
# threads cut the wall time of a 1 ms step by 16 % while raising its CPU time by 67 % (the threads
# spin between the many short parallel regions of a CG iteration; docs/benchmark.md).


@njit
def _row_apply(row_off, col, vals, p, q):
    """Row q of ``H p`` (the three components), summed over the row's blocks in column order."""
    a0 = 0.0
    a1 = 0.0
    a2 = 0.0
    for s in range(row_off[q], row_off[q + 1]):
        c = col[s]
        p0 = p[c, 0]
        p1 = p[c, 1]
        p2 = p[c, 2]
        a0 += vals[s, 0, 0] * p0 + vals[s, 0, 1] * p1 + vals[s, 0, 2] * p2
        a1 += vals[s, 1, 0] * p0 + vals[s, 1, 1] * p1 + vals[s, 1, 2] * p2
        a2 += vals[s, 2, 0] * p0 + vals[s, 2, 1] * p1 + vals[s, 2, 2] * p2
    return a0, a1, a2


@njit
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


@njit
def _matvec(A, p, mdiag, h2, free, y):
    """``y = diag(mdiag)·p + h²·H p`` with zero rows where ``free`` is False, or ``y = H p`` when
    ``mdiag`` is empty."""
    _matvec_rows(A.row_off, A.col, A.vals, p, mdiag, h2, free, y)


@njit
def apply_H(p, A, y):
    """``y = H·p`` (dyne/cm × cm), ``A`` a :class:`Matrix`."""
    _matvec(A, p, np.zeros(0), 0.0, np.zeros(0, dtype=np.bool_), y)


@njit
def diagonal_blocks(mdiag, h2, A, Dblk):
    """3×3 diagonal blocks of ``diag(mdiag) + h²·H`` into ``Dblk (N, 3, 3)``."""
    for q in range(mdiag.shape[0]):
        M = A.vals[A.diag[q]]
        for i in range(3):
            for j in range(3):
                Dblk[q, i, j] = h2 * M[i, j]
            Dblk[q, i, i] += mdiag[q]


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
def _matvec_A(p, mdiag, h2, A, free, y):
    """``y = A p``, ``A = diag(mdiag) + h²H``, zero rows at pinned particles."""
    _matvec(A, p, mdiag, h2, free, y)


@njit
def _dot(a, b):
    s = 0.0
    for q in range(a.shape[0]):
        s += a[q, 0] * b[q, 0] + a[q, 1] * b[q, 1] + a[q, 2] * b[q, 2]
    return s


# ---------------------------------------------------------------- line preconditioner
@njit
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
            piv[:, :] = Dblk[q]
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
            _inv3(piv, diag_out[s])


@njit
def _block_norm(vals, s):
    """Frobenius norm of block s (an upper bound of its spectral norm)."""
    c = 0.0
    for i in range(3):
        for j in range(3):
            c += vals[s, i, j] * vals[s, i, j]
    return math.sqrt(c)


@njit
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
            c = h2 * _block_norm(A.vals, s)
            add_out[slot_of[q]] += c
            add_out[slot_of[A.col[s]]] += c


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
def residual(b, x, mdiag, h2, H, free, r):
    """``r = b − A x`` (zero at pinned particles)."""
    _matvec_A(x, mdiag, h2, H, free, r)
    for q in range(b.shape[0]):
        if free[q]:
            for i in range(3):
                r[q, i] = b[q, i] - r[q, i]


@njit
def implicit_rhs(f, v, h, H, free, rhs):
    """``rhs = h (f − h H v)``, zero at pinned particles."""
    apply_H(v, H, rhs)
    for q in range(f.shape[0]):
        for i in range(3):
            rhs[q, i] = h * (f[q, i] - h * rhs[q, i]) if free[q] else 0.0




# ============================================================================ contact constraints
# Regularisation speed of Coulomb friction (cm/s): below it friction acts as a viscous damper of
# coefficient μ|f_n|/V_EPS, so a particle under a tangential load below μ|f_n| creeps at most this fast.
FRICTION_V_EPS = 1e-2
FRICTION_PASSES = 1  # at most this many re-solves per step with raised friction dampers (refine_friction)
FRICTION_REFINE_SPEED = 0.5  # cm/s: refine_friction leaves particles sliding slower than this at the end of the solve
FRICTION_REFINE_RATIO = 2.0  # refine_friction raises a damper that brakes with less than 1/this of μ|f_n|


@njit
def contact_constraints(x, v, f, world, mass, h, cn, con, cfric, md, free, fmax):
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
    :func:`refine_friction`. ``world``: a :class:`~cloth_gym.sim.bundles.World` (its obstacles where
    they are now, ``world.touching`` the contact record of the last step).
    """
    touching, types, params, friction, ob_vel = (world.touching, world.obstacles.types, world.prm,
                                                 world.obstacles.friction, world.vel)
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
            bound = h2 * _block_norm(A.vals, s)
            for p in (q, c):
                o = 3 * slot[p]
                for i in range(3):
                    Ab[o + i, 0] += bound


@njit
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


@njit
def band_factor(Dblk, free, h2, A, slot, Ab):
    """:func:`band_assemble` then :func:`band_cholesky` into ``Ab``; False if the matrix is not SPD
    (non-finite or indefinite)."""
    band_assemble(Dblk, free, h2, A, slot, Ab)
    return band_cholesky(Ab)


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
@njit
def level_matrix(l, lv, ws):
    """The :class:`Matrix` of level ``l`` (views into the concatenated arrays)."""
    za, zb = lv.z_off[l], lv.z_off[l + 1]
    return Matrix(lv.row_off[lv.n_off[l] + l:lv.n_off[l + 1] + l + 1], lv.col[za:zb],
                  lv.diag[lv.n_off[l]:lv.n_off[l + 1]], ws.vals[za:zb])


@njit
def mg_setup(x, h2, precond, fd, lv, ws, con, cn, assemble=True):
    """Assemble H on every level of ``lv`` (coarse positions injected from the fine ones), restrict
    the lumped mass, set up the smoothers and factor the coarsest level, into ``ws``. The force laws
    are those of ``fd`` (a :class:`~cloth_gym.sim.bundles.ForceData`), at each level's spacing.
    Level 0's ``ws.mdiag`` and ``ws.free`` rows must be set by the caller. Returns False if the
    coarsest matrix is not SPD. With ``assemble=False`` the H of the last call is kept (only the
    mass diagonal changed: the friction re-solve).

    Contact constraints (``con``, normals ``cn``) enter the *preconditioner* as a stiff penalty
    ``pen_q = κ·d_q·n nᵀ`` on the diagonal block of each constrained particle (κ =
    :data:`CONTACT_PENALTY`, d_q the block's mean diagonal), restricted to the coarse levels like
    the mass: without it the coarse-grid corrections move particles lying on a table through it,
    the filter throws that away and PCG needs 4–5× more iterations once the cloth lands."""
    n_off, xl, free, mdiag, pen, Dblk = lv.n_off, ws.xl, ws.free, ws.mdiag, ws.pen, ws.Dblk
    n0 = n_off[1]
    # the strain-rate damping C = β·(material stiffness) enters the matrix M + hC + h²H as h²·(C/h)
    damp = fd.damping_time / math.sqrt(h2) if (fd.flags & STRAIN_DAMPING) != 0 else 0.0
    if assemble:
        xl[0:n0] = x
    for l in range(lv.n_levels):
        a, b = n_off[l], n_off[l + 1]
        ea, eb = lv.e_off[l], lv.e_off[l + 1]
        ba, bb = lv.b_off[l], lv.b_off[l + 1]
        ca, cb = lv.c_off[l], lv.c_off[l + 1]
        if l > 0:
            pa, pb = n_off[l - 1], n_off[l]
            inj = lv.inject[lv.i_off[l - 1]:lv.i_off[l]]
            for c in range(b - a):
                if assemble:
                    for i in range(3):
                        xl[a + c, i] = xl[pa + inj[c], i]
                free[a + c] = free[pa + inj[c]]
            restrict_scalar(mdiag[pa:pb], lv.P_idx[pa:pb], lv.P_w[pa:pb], mdiag[a:b])
            restrict_blocks(pen[pa:pb], lv.P_idx[pa:pb], lv.P_w[pa:pb], pen[a:b])
        x_l = xl[a:b]
        H = level_matrix(l, lv, ws)
        if assemble:
            el = (lv.sigma[l], lv.edges[ea:eb], lv.edge_dir[ea:eb], lv.rest[ea:eb], lv.edge_width[ea:eb],
                  lv.triples[ba:bb], lv.bend_dir[ba:bb], lv.bend_width[ba:bb], lv.bend_length[ba:bb],
                  lv.corners[ca:cb])
            linearise_forces(x_l, fd, el, damp, (lv.e_map[ea:eb], lv.b_map[ba:bb], lv.c_map[ca:cb]), H.vals)
        diagonal_blocks(mdiag[a:b], h2, H, Dblk[a:b])
        if l == 0:
            contact_penalty(Dblk[a:b], con, cn, pen[a:b])
        add_blocks(pen[a:b], Dblk[a:b])
        if precond >= BAND_WARP:
            pass  # the band factor (one level only) is built by filtered_pcg, when a solve needs it
        elif precond == LINES:
            wo = lv.lw_off[lv.lwo_off[l]:lv.lwo_off[l + 1]]
            fo = lv.lf_off[lv.lfo_off[l]:lv.lfo_off[l + 1]]
            set_line_couplings(h2, H, free[a:b], lv.lw_prev[a:b], lv.lw_prev2[a:b], lv.lw_slot[a:b], ws.lw_low[a:b],
                               ws.lw_add[a:b])
            line_blocks(Dblk[a:b], ws.lw_add[a:b], free[a:b], wo, lv.lw_idx[a:b], ws.lw_piv[a:b], ws.lw_low[a:b])
            set_line_couplings(h2, H, free[a:b], lv.lf_prev[a:b], lv.lf_prev2[a:b], lv.lf_slot[a:b], ws.lf_low[a:b],
                               ws.lf_add[a:b])
            line_blocks(Dblk[a:b], ws.lf_add[a:b], free[a:b], fo, lv.lf_idx[a:b], ws.lf_piv[a:b], ws.lf_low[a:b])
        else:
            invert_blocks(Dblk[a:b], ws.Dinv[a:b])
    if lv.n_levels > 1:
        l = lv.n_levels - 1
        a, b = n_off[l], n_off[l + 1]
        chol = ws.chol
        dense_matrix(mdiag[a:b], h2, level_matrix(l, lv, ws), free[a:b], chol)
        for q in range(b - a):
            if free[a + q]:
                for i in range(3):
                    for j in range(3):
                        chol[3 * q + i, 3 * q + j] += pen[a + q, i, j]
        return cholesky_inplace(chol)
    return True


@njit
def _smooth_level(l, r, z, scale, precond, lv, ws):
    a, b = lv.n_off[l], lv.n_off[l + 1]
    smooth_apply(r, precond, ws.Dinv[a:b], ws.free[a:b], lv.lw_off[lv.lwo_off[l]:lv.lwo_off[l + 1]],
                 lv.lw_idx[a:b], ws.lw_piv[a:b], ws.lw_low[a:b], lv.lf_off[lv.lfo_off[l]:lv.lfo_off[l + 1]],
                 lv.lf_idx[a:b], ws.lf_piv[a:b], ws.lf_low[a:b], ws.work[a:b], scale, z)


@njit
def _residual_level(l, rl, zl, out, h2, lv, ws):
    """``out = rl − (A_l + pen_l) zl`` on level l (the operator the preconditioner approximates)."""
    a, b = lv.n_off[l], lv.n_off[l + 1]
    residual(rl, zl, ws.mdiag[a:b], h2, level_matrix(l, lv, ws), ws.free[a:b], out)
    pq = ws.pen[a:b]
    fq = ws.free[a:b]
    for q in range(b - a):
        if fq[q] and pq[q, 0, 0] + pq[q, 1, 1] + pq[q, 2, 2] != 0.0:
            for i in range(3):
                out[q, i] -= pq[q, i, 0] * zl[q, 0] + pq[q, i, 1] * zl[q, 1] + pq[q, i, 2] * zl[q, 2]


@njit
def mg_precondition(r, z, h2, precond, omega, lv, ws):
    """``z = B r``: one symmetric V-cycle (damped line/Jacobi smoothing, dense coarsest solve), the
    smoother alone for a single level, or the band factor's solve."""
    n_off, free, rin, zl, res = lv.n_off, ws.free, ws.rin, ws.zl, ws.res
    if precond >= BAND_WARP:
        band_apply(ws.band, lv.lw_idx[0:n_off[1]] if precond == BAND_WARP else lv.lf_idx[0:n_off[1]], free, r, z,
                   ws.cvec)
        return
    if lv.n_levels == 1:
        _smooth_level(0, r, z, 1.0, precond, lv, ws)
        return
    rin[0:n_off[1]] = r
    for l in range(lv.n_levels - 1):
        a, b = n_off[l], n_off[l + 1]
        c = n_off[l + 2]
        _smooth_level(l, rin[a:b], zl[a:b], omega, precond, lv, ws)
        _residual_level(l, rin[a:b], zl[a:b], res[a:b], h2, lv, ws)
        restrict(res[a:b], lv.P_idx[a:b], lv.P_w[a:b], free[b:c], rin[b:c])
    last = lv.n_levels - 1
    a, b = n_off[last], n_off[last + 1]
    cvec, cout = ws.cvec, ws.cout
    for q in range(b - a):
        for i in range(3):
            cvec[3 * q + i] = rin[a + q, i] if free[a + q] else 0.0
    cholesky_solve(ws.chol, cvec, cout)
    for q in range(b - a):
        for i in range(3):
            zl[a + q, i] = cout[3 * q + i] if free[a + q] else 0.0
    for l in range(lv.n_levels - 2, -1, -1):
        a, b = n_off[l], n_off[l + 1]
        c = n_off[l + 2]
        prolong_add(zl[b:c], lv.P_idx[a:b], lv.P_w[a:b], free[a:b], zl[a:b])
        _residual_level(l, rin[a:b], zl[a:b], res[a:b], h2, lv, ws)
        _smooth_level(l, res[a:b], ws.corr[a:b], omega, precond, lv, ws)
        for q in range(a, b):
            for i in range(3):
                zl[q, i] += ws.corr[q, i]
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
def filtered_pcg(warm, rhs, dv, cg, opts, h2, fr, con, cn, md, lv, ws, stale, bslot, prof):
    """Filtered PCG (Baraff–Witkin): solve ``S A S Δv = S b``; returns (iterations, |r|/|b|).

    ``cg``: a :class:`CGWork`; ``opts``: :class:`SolveOptions`; ``lv``, ``ws``: the levels and their
    scratch (level 0 is the system solved; the others serve the V-cycle).

    It starts from Δv = 0, or with ``warm`` from the filtered ``dv`` it is given (the previous
    step's Δv; the friction re-solve starts from the first solve's), unless that guess leaves a
    residual no smaller than ``|S b|``; the tolerance is relative to ``|S b|`` either way.

    ``opts.vtol`` (cm/s, 0: off) is an absolute floor: it also stops once ``‖r‖_{M̃⁻¹} ≤ vtol·√(Σ m̃)``
    (M̃ = diag(``md``), the lumped mass with the dampers). As A ≥ M̃ (H is positive
    semi-definite), the error e of Δv then has a mass-weighted RMS ``√(Σ m̃|e|² / Σ m̃) ≤ vtol``:
    a cloth at rest, whose filtered right-hand side is tiny, is not solved to ``tol`` relative to
    nothing.

    The band preconditioner is factored here, from the level-0 blocks ``ws.Dblk`` in slot order
    ``bslot``, when ``stale[0] == 1`` and the solve iterates at all (a cloth at rest needs none:
    it costs no factorisation); ``stale[0]`` becomes 0, or 2 if the matrix was not SPD (the solve
    then stops). Its cycles are added to ``prof[P_FACTOR]`` (the phase profile)."""
    r, z, p, Ap = cg.r, cg.z, cg.p, cg.Ap
    tol, precond, omega = opts.tol, opts.precond, opts.omega
    H0 = level_matrix(0, lv, ws)
    r[:] = rhs
    filter_vec(r, fr, con, cn)
    bnorm = math.sqrt(_dot(r, r))
    if warm and bnorm > 0.0:
        filter_vec(dv, fr, con, cn)
        _matvec_A(dv, md, h2, H0, fr, Ap)
        filter_vec(Ap, fr, con, cn)
        for q in range(r.shape[0]):
            for i in range(3):
                r[q, i] -= Ap[q, i]
        if _dot(r, r) >= bnorm * bnorm:  # a guess worse than none (an impact): start from 0
            dv[:] = 0.0
            r[:] = rhs
            filter_vec(r, fr, con, cn)
    else:
        dv[:] = 0.0
    it = 0
    rel = math.sqrt(_dot(r, r)) / bnorm if bnorm > 0.0 else 0.0
    floor2 = 0.0
    if opts.vtol > 0.0:
        msum = 0.0
        for q in range(md.shape[0]):
            if fr[q]:
                msum += md[q]
        floor2 = opts.vtol * opts.vtol * msum
    if bnorm > 0.0 and rel > tol and not _below_floor(r, md, floor2):
        if precond >= BAND_WARP and stale[0] == 1:
            t0 = cycles()
            stale[0] = 0 if band_factor(ws.Dblk[0:lv.n_off[1]], fr, h2, H0, bslot, ws.band) else 2
            prof[P_FACTOR] += cycles() - t0
            if stale[0] == 2:
                return it, rel
        mg_precondition(r, z, h2, precond, omega, lv, ws)
        filter_vec(z, fr, con, cn)
        p[:] = z
        rz = _dot(r, z)
        while it < opts.max_iter:
            _matvec_A(p, md, h2, H0, fr, Ap)
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
            mg_precondition(r, z, h2, precond, omega, lv, ws)
            filter_vec(z, fr, con, cn)
            rz_new = _dot(r, z)
            xpby(z, rz_new / rz, p)
            rz = rz_new
    return it, rel


@njit
def _refresh_preconditioner(x, h2, opts, fd, lv, ws, con, cn, md, md_before, stale):
    """The preconditioner again after the friction re-solve raised dampers on the diagonal (a
    sticking particle's h·c is orders of magnitude above its mass: without it PCG stalls); H is
    kept. One level: the changed diagonal blocks in place, then the lines (or blocks) refactored.
    Returns False if a coarse matrix is not SPD."""
    n = x.shape[0]
    stale[0] = 1  # the band factor, if used, is rebuilt on demand
    if lv.n_levels == 1:
        raise_diagonal(md, md_before, con, cn, ws.Dblk[0:n], ws.pen[0:n])
        if opts.precond == LINES:
            line_blocks(ws.Dblk[0:n], ws.lw_add[0:n], ws.free[0:n], lv.lw_off[lv.lwo_off[0]:lv.lwo_off[1]],
                        lv.lw_idx[0:n],
                        ws.lw_piv[0:n], ws.lw_low[0:n])
            line_blocks(ws.Dblk[0:n], ws.lf_add[0:n], ws.free[0:n], lv.lf_off[lv.lfo_off[0]:lv.lfo_off[1]],
                        lv.lf_idx[0:n],
                        ws.lf_piv[0:n], ws.lf_low[0:n])
        elif opts.precond == JACOBI:
            invert_blocks(ws.Dblk[0:n], ws.Dinv[0:n])
        return True
    return mg_setup(x, h2, opts.precond, fd, lv, ws, con, cn, runtime(False))


@njit
def run_implicit(n_steps, h, x, v, inv_mass, wind, stats, opts, guard, carry, fd, world, lv, ws, prof):
    """``n_steps`` backward-Euler (or BDF2) steps of ``h`` s (see :mod:`cloth_gym.sim.implicit`).

    ``x``, ``v`` (N, 3): positions (cm) and velocities (cm/s), advanced in place; ``inv_mass`` (N,)
    1/g, 0 for pinned and kinematic particles; ``wind`` (3,) cm/s. ``stats`` (n_steps, 2) gets (CG
    iterations, relative residual) per step. ``opts``: :class:`SolveOptions`; ``guard``:
    :class:`~cloth_gym.sim.bundles.Guard`; ``carry``: :class:`Carry` (with ``opts.bdf2`` the steps
    are BDF2 once its history is set; the first step is backward Euler, which sets it); ``fd``:
    :class:`~cloth_gym.sim.bundles.ForceData`; ``world``: :class:`~cloth_gym.sim.bundles.World`;
    ``lv``, ``ws``: :class:`Levels` and their :class:`Work`.

    ``prof`` (N_PHASES + 1,) int64: the phase profile, cycle counts per
    :class:`~cloth_gym.sim.bundles.Phase` and of the whole call, added to.

    Returns (status, step, particle, value): a :class:`~cloth_gym.sim.bundles.Status` code
    (NOT_SPD: the coarsest-level or band matrix was not positive definite), the step it happened
    at, and the particle and value it concerns."""
    start = cycles()
    out = _implicit_steps(n_steps, h, x, v, inv_mass, wind, stats, opts, guard, carry, fd, world, lv, ws, prof)
    prof[N_PHASES] += cycles() - start
    return out


@njit
def _implicit_steps(n_steps, h, x, v, inv_mass, wind, stats, opts, guard, carry, fd, world, lv, ws, prof):
    """The body of :func:`run_implicit`."""
    n = x.shape[0]
    f = np.empty((n, 3))
    normals = np.empty((n, 3))
    drag = np.zeros(n)
    rhs = np.empty((n, 3))
    dv = np.empty((n, 3))
    cg = CGWork(np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)))
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
    bslot = lv.lw_slot[0:n] if opts.precond == BAND_WARP else lv.lf_slot[0:n]
    con = np.zeros(n, dtype=np.int8)
    cn = np.zeros((n, 3))
    fr = ws.free[0:n]
    for q in range(n):
        fr[q] = inv_mass[q] > 0.0
    use_air = (fd.flags & AIR) != 0
    use_damping = (fd.flags & DAMPING) != 0
    contacts = world.obstacles.types.shape[0] > 0
    keep_prev = needs_previous_positions(world)
    vt_pairs = np.zeros((0, 2), dtype=np.int64)  # self-collision pair lists, kept across steps
    ee_pairs = np.zeros((0, 2), dtype=np.int64)
    ref_x = np.full((n if (world.collision.flags & COLLISION_PASS_BITS) != 0 else 0, 3), np.inf)
    H0 = level_matrix(0, lv, ws)
    md = ws.mdiag[0:n]
    hist_x, hist_v, hist_ok = carry.x, carry.v, carry.ok
    strain_damping = (fd.flags & STRAIN_DAMPING) != 0
    resolve_warm = runtime(True)  # the friction re-solve starts from the first solve's Δv, a Newton pass from 0
    for s in range(n_steps):
        # the strain-rate damping −C·v is left out of f: the assembled matrix is H + C/β, whose
        # product −β²(H + C/β)·v in the right-hand side applies it (and C's implicit part)
        t0 = cycles()
        eval_forces_at(x, v, wind, fd, normals, f, runtime(False))
        t1 = cycles()
        prof[P_FORCES] += t1 - t0
        # BDF2: (M + βC + β²H)Δv = β f − β²H v − βC v + ⅓M(v − v₋₁) − (β/3)H(x − x₋₁),  β = 2h/3;
        #       x₊₁ = x + ⅓(x − x₋₁) + β v₊₁.   Backward Euler: β = h and no history terms.
        use2 = opts.bdf2 and hist_ok[0] == 1
        heff = 2.0 * h / 3.0 if use2 else h
        h2 = heff * heff
        if use_air:
            air_linearisation(x, v, fd.tris, wind, fd.c_air, fd.area, normals, drag)
        lumped_mass(fd.mass, fd.damping_rate, use_damping, drag, heff, md)
        if contacts:
            contact_constraints(x, v, f, world, fd.mass, heff, cn, con, cfric, md, fr, fmax)
        t2 = cycles()
        prof[P_PREPARE] += t2 - t1
        stale[0] = 1  # the band factor, if used, is rebuilt on demand
        if not mg_setup(x, h2, opts.precond, fd, lv, ws, con, cn, runtime(True)):
            return NOT_SPD, s, -1, math.nan
        t3 = cycles()
        prof[P_ASSEMBLY] += t3 - t2
        implicit_rhs(f, v, heff, H0, fr, rhs)
        if use2:
            for q in range(n):
                for i in range(3):
                    dxh[q, i] = (x[q, i] - hist_x[q, i]) / 3.0
            apply_H(dxh, H0, tmp)  # (H + C/β)·dxh; the history term takes H·dxh alone
            if strain_damping:
                dv_k[:] = 0.0
                eval_strain_damping(x, dxh, fd, dv_k)  # −C·dxh
                for q in range(n):
                    for i in range(3):
                        tmp[q, i] += dv_k[q, i] / heff
            for q in range(n):
                if fr[q]:
                    for i in range(3):
                        rhs[q, i] += fd.mass[q] * (v[q, i] - hist_v[q, i]) / 3.0 - heff * tmp[q, i]
        if use2:
            hist_v_old[:] = hist_v
        if opts.bdf2:
            hist_x[:] = x
            hist_v[:] = v
            hist_ok[0] = 1
        # ---- Newton: the first pass is the Baraff–Witkin linearised step; further passes
        # re-evaluate forces and H at the current estimate and solve for the correction
        warm = opts.warm_start and carry.dv_ok[0] == 1
        if warm:
            dv[:] = carry.dv
        t4 = cycles()
        prof[P_RHS] += t4 - t3
        factored = prof[P_FACTOR]
        it, rel = filtered_pcg(warm, rhs, dv, cg, opts, h2, fr, con, cn, md, lv, ws, stale, bslot, prof)
        t5 = cycles()
        prof[P_SOLVE] += t5 - t4 - (prof[P_FACTOR] - factored)
        factored = prof[P_FACTOR]
        for _ in range(FRICTION_PASSES if contacts and opts.friction_resolve else 0):
            md_before[:] = md
            if not refine_friction(v, dv, con, cn, cfric, fmax, world.touching, world.vel, heff, md, rhs):
                break
            if not _refresh_preconditioner(x, h2, opts, fd, lv, ws, con, cn, md, md_before, stale):
                return NOT_SPD, s, -1, math.nan
            it2, rel = filtered_pcg(resolve_warm, rhs, dv, cg, opts, h2, fr, con, cn, md, lv, ws, stale, bslot,
                                    prof)
            it += it2
        t6 = cycles()
        if contacts and opts.friction_resolve:
            prof[P_FRICTION] += t6 - t5 - (prof[P_FACTOR] - factored)
            factored = prof[P_FACTOR]
        for newton in range(1, opts.n_newton):
            for q in range(n):
                for i in range(3):
                    vk[q, i] = v[q, i] + (dv[q, i] if fr[q] else 0.0)
                    xk[q, i] = x[q, i] + (dxh[q, i] if use2 else 0.0) + heff * vk[q, i]
            eval_forces(xk, vk, wind, fd, normals, f)
            stale[0] = 1  # the band factor, if used, is rebuilt on demand
            if not mg_setup(xk, h2, opts.precond, fd, lv, ws, con, cn, runtime(True)):
                return NOT_SPD, s, -1, math.nan
            # −g(Δv) = β f(x_k, v_k) − M Δv (+ ⅓M(v − v₋₁) for BDF2), plus friction at v_k
            if contacts:
                friction_force(vk, con, cn, cfric, world.touching, world.vel, ffric)
            for q in range(n):
                for i in range(3):
                    if fr[q]:
                        rhs[q, i] = heff * (f[q, i] + ffric[q, i]) - fd.mass[q] * dv[q, i]
                        if use2:
                            rhs[q, i] += fd.mass[q] * (v[q, i] - hist_v_old[q, i]) / 3.0
                    else:
                        rhs[q, i] = 0.0
            dv_k[:] = dv
            it2, rel = filtered_pcg(not resolve_warm, rhs, dv, cg, opts, h2, fr, con, cn, md, lv, ws, stale, bslot,
                                    prof)
            it += it2
            for q in range(n):
                for i in range(3):
                    dv[q, i] += dv_k[q, i]
        if opts.n_newton > 1:
            prof[P_NEWTON] += cycles() - t6 - (prof[P_FACTOR] - factored)
        if stale[0] == 2:  # the band matrix was not SPD (non-finite state)
            return NOT_SPD, s, -1, math.nan
        stats[s, 0] = it
        stats[s, 1] = rel
        if opts.warm_start:
            carry.dv[:] = dv
            carry.dv_ok[0] = 1
        # ---- update (kinetic friction already in the solve), then the shared end of a substep
        if keep_prev:
            x_prev[:] = x
        for q in range(n):  # pinned particles keep their prescribed velocity
            if fr[q]:
                for i in range(3):
                    v[q, i] += dv[q, i]
        for q in range(n):
            for i in range(3):
                x[q, i] += (dxh[q, i] if use2 else 0.0) + heff * v[q, i]
        status, pp, value, vt_pairs, ee_pairs = finish_substep(x, v, x_prev, inv_mass, heff, fd, world, guard,
                                                               vt_pairs, ee_pairs, ref_x, prof)
        if status != OK:
            return status, s, pp, value
    return OK, n_steps, -1, 0.0
