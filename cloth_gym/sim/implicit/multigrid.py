"""The geometric multigrid preconditioner: coarse levels of the lattice (every other node) with
rediscretised operators, bilinear prolongation, full-weighting restriction, one damped line
smoother sweep before and after, a dense Cholesky solve at the coarsest level; and the set-up of
every preconditioner at the start of a step (:func:`mg_setup`; :func:`one_level_setup` and
:func:`band_setup` for a single level) and after the friction re-solve (``refresh_*``).
"""

from __future__ import annotations

import math

from .._numba import copy_into, kernel_only, njit, runtime

from ..forces import STRAIN_DAMPING, linearise_forces
from .bundles import JACOBI, LINES, Matrix
from .contact import contact_penalty, raise_diagonal
from .lines import invert_blocks, line_blocks, set_line_couplings, smooth_apply
from .matrix import cholesky_inplace, cholesky_solve, dense_matrix, diagonal_blocks, residual, zero_row



@kernel_only
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



@kernel_only
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



@kernel_only
def restrict_scalar(a_f, P_idx, P_w, a_c):
    a_c[:] = 0.0
    for f in range(a_f.shape[0]):
        for k in range(P_idx.shape[1]):
            c = P_idx[f, k]
            if c >= 0:
                a_c[c] += P_w[f, k] * a_f[f]



@kernel_only
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



@kernel_only
def add_blocks(a, out):
    for q in range(a.shape[0]):
        for i in range(3):
            for j in range(3):
                out[q, i, j] += a[q, i, j]


# ============================================================================ the whole step, all levels
@kernel_only
def level_matrix(l, lv, ws):
    """The :class:`Matrix` of level ``l`` (views into the concatenated arrays)."""
    za, zb = lv.z_off[l], lv.z_off[l + 1]
    return Matrix(lv.row_off[lv.n_off[l] + l:lv.n_off[l + 1] + l + 1], lv.col[za:zb],
                  lv.diag[lv.n_off[l]:lv.n_off[l + 1]], ws.vals[za:zb])



@njit(inline="always")
def _level_blocks(l, h2, damp, fd, lv, ws, con, cn, assemble):
    """Level ``l``'s H (assembled at ``ws.xl`` when ``assemble``) and its diagonal blocks
    ``ws.Dblk`` with the mass and the contact penalty (level 0: from ``con``, ``cn``; coarser
    levels: the penalty restricted by the caller). Returns the level's :class:`Matrix`."""
    a, b = lv.n_off[l], lv.n_off[l + 1]
    ea, eb = lv.e_off[l], lv.e_off[l + 1]
    ba, bb = lv.b_off[l], lv.b_off[l + 1]
    ca, cb = lv.c_off[l], lv.c_off[l + 1]
    H = level_matrix(l, lv, ws)
    if assemble:
        el = (lv.sigma[l], lv.edges[ea:eb], lv.edge_dir[ea:eb], lv.rest[ea:eb], lv.edge_width[ea:eb],
              lv.triples[ba:bb], lv.bend_dir[ba:bb], lv.bend_width[ba:bb], lv.bend_length[ba:bb],
              lv.corners[ca:cb])
        linearise_forces(ws.xl[a:b], fd, el, damp, (lv.e_map[ea:eb], lv.b_map[ba:bb], lv.c_map[ca:cb]), H.vals)
    diagonal_blocks(ws.mdiag[a:b], h2, H, ws.Dblk[a:b])
    if l == 0:
        contact_penalty(ws.Dblk[a:b], con, cn, ws.pen[a:b])
    add_blocks(ws.pen[a:b], ws.Dblk[a:b])
    return H


@njit(inline="always")
def _smoother_setup(l, h2, H, precond, lv, ws):
    """Level ``l``'s smoother from its blocks: the warp and weft lines factored (``LINES``) or the
    3×3 blocks inverted (``JACOBI``)."""
    a, b = lv.n_off[l], lv.n_off[l + 1]
    free, Dblk = ws.free, ws.Dblk
    if precond == LINES:
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


@njit(inline="always")
def _strain_damping(h2, fd):
    """The strain-rate damping C = β·(material stiffness) enters the matrix M + hC + h²H as
    h²·(C/h): the factor 1/h the assembly applies to C (0 without strain-rate damping)."""
    return fd.damping_time / math.sqrt(h2) if (fd.flags & STRAIN_DAMPING) != 0 else 0.0


@kernel_only
def band_setup(x, h2, fd, lv, ws, con, cn, assemble=True):
    """:func:`mg_setup` for the band preconditioner (one level): H and the diagonal blocks with
    the contact penalty; the band factor itself is built by
    :func:`~cloth_gym.sim.implicit.cg.filtered_pcg` when a solve needs it. Returns True."""
    if assemble:
        copy_into(ws.xl[0:lv.n_off[1]], x)
    _level_blocks(0, h2, _strain_damping(h2, fd), fd, lv, ws, con, cn, assemble)
    return True


@kernel_only
def one_level_setup(x, h2, precond, fd, lv, ws, con, cn, assemble=True):
    """:func:`mg_setup` for lines or block Jacobi on one level. Returns True."""
    if assemble:
        copy_into(ws.xl[0:lv.n_off[1]], x)
    H = _level_blocks(0, h2, _strain_damping(h2, fd), fd, lv, ws, con, cn, assemble)
    _smoother_setup(0, h2, H, precond, lv, ws)
    return True


@kernel_only
def mg_setup(x, h2, precond, fd, lv, ws, con, cn, assemble=True):
    """Assemble H on every level of ``lv`` (coarse positions injected from the fine ones), restrict
    the lumped mass, set up the smoothers (lines or block Jacobi, by ``precond``) and factor the
    coarsest level, into ``ws``. The force laws are those of ``fd`` (a
    :class:`~cloth_gym.sim.bundles.ForceData`), at each level's spacing. Level 0's ``ws.mdiag``
    and ``ws.free`` rows must be set by the caller. Returns False if the coarsest matrix is not
    SPD. With ``assemble=False`` the H of the last call is kept (only the mass diagonal changed:
    the friction re-solve). One level and the band factor have their own set-up
    (:func:`one_level_setup`, :func:`band_setup`).

    Contact constraints (``con``, normals ``cn``) enter the *preconditioner* as a stiff penalty
    ``pen_q = κ·d_q·n nᵀ`` on the diagonal block of each constrained particle (κ =
    :data:`CONTACT_PENALTY`, d_q the block's mean diagonal), restricted to the coarse levels like
    the mass: without it the coarse-grid corrections move particles lying on a table through it,
    the filter throws that away and PCG needs 4–5× more iterations once the cloth lands."""
    n_off, xl, free, mdiag, pen = lv.n_off, ws.xl, ws.free, ws.mdiag, ws.pen
    damp = _strain_damping(h2, fd)
    if assemble:
        copy_into(xl[0:n_off[1]], x)
    for l in range(lv.n_levels):
        a, b = n_off[l], n_off[l + 1]
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
        H = _level_blocks(l, h2, damp, fd, lv, ws, con, cn, assemble)
        _smoother_setup(l, h2, H, precond, lv, ws)
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



@kernel_only
def _smooth_level(l, r, z, scale, precond, lv, ws):
    a, b = lv.n_off[l], lv.n_off[l + 1]
    smooth_apply(r, precond, ws.Dinv[a:b], ws.free[a:b], lv.lw_off[lv.lwo_off[l]:lv.lwo_off[l + 1]],
                 lv.lw_idx[a:b], ws.lw_piv[a:b], ws.lw_low[a:b], lv.lf_off[lv.lfo_off[l]:lv.lfo_off[l + 1]],
                 lv.lf_idx[a:b], ws.lf_piv[a:b], ws.lf_low[a:b], ws.work[a:b], scale, z)



@kernel_only
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



@kernel_only
def mg_precondition(r, z, h2, precond, omega, lv, ws):
    """``z = B r``: one symmetric V-cycle (damped line/Jacobi smoothing by ``precond``, dense
    coarsest solve), or the smoother alone for a single level."""
    n_off, free, rin, zl, res = lv.n_off, ws.free, ws.rin, ws.zl, ws.res
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
    copy_into(z, zl[0:n_off[1]])



@kernel_only
def refresh_band(x, lv, ws, con, cn, md, md_before, stale):
    """The band preconditioner after the friction re-solve raised dampers on the diagonal (a
    sticking particle's h·c is orders of magnitude above its mass: without it PCG stalls): the
    changed diagonal blocks in place (H kept), the factor rebuilt before its next use. Returns True."""
    n = x.shape[0]
    stale[0] = 1
    raise_diagonal(md, md_before, con, cn, ws.Dblk[0:n], ws.pen[0:n])
    return True


@kernel_only
def refresh_one_level(x, precond, lv, ws, con, cn, md, md_before, stale):
    """:func:`refresh_band` for lines or block Jacobi on one level: the changed diagonal blocks in
    place, then the lines (or blocks) refactored. Returns True."""
    n = x.shape[0]
    stale[0] = 1
    raise_diagonal(md, md_before, con, cn, ws.Dblk[0:n], ws.pen[0:n])
    if precond == LINES:
        line_blocks(ws.Dblk[0:n], ws.lw_add[0:n], ws.free[0:n], lv.lw_off[lv.lwo_off[0]:lv.lwo_off[1]],
                    lv.lw_idx[0:n],
                    ws.lw_piv[0:n], ws.lw_low[0:n])
        line_blocks(ws.Dblk[0:n], ws.lf_add[0:n], ws.free[0:n], lv.lf_off[lv.lfo_off[0]:lv.lfo_off[1]],
                    lv.lf_idx[0:n],
                    ws.lf_piv[0:n], ws.lf_low[0:n])
    elif precond == JACOBI:
        invert_blocks(ws.Dblk[0:n], ws.Dinv[0:n])
    return True


@kernel_only
def refresh_multigrid(x, h2, precond, fd, lv, ws, con, cn, md, md_before, stale):
    """:func:`refresh_band` for the V-cycle: every level set up again from the kept H (the
    coarse levels restrict the raised mass diagonal). Returns False if the coarsest matrix is not
    SPD."""
    if lv.n_levels == 1:
        return refresh_one_level(x, precond, lv, ws, con, cn, md, md_before, stale)
    stale[0] = 1
    return mg_setup(x, h2, precond, fd, lv, ws, con, cn, runtime(False))
