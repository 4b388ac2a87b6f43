"""The lattice levels of the implicit solve: each level's lattice lines and block-sparse stencil
(:class:`Level`; a model's are built once, ``Model.lattice_layout``), the multigrid hierarchy of
coarser levels with its transfer weights (:func:`coarsen`, :func:`build_hierarchy`), and the levels
concatenated into the kernels' :class:`~cloth_gym.sim.implicit.bundles.Levels` and
:class:`~cloth_gym.sim.implicit.bundles.Work` bundles (:class:`Hierarchy`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...units import G
from ..lattice import lattice_model
from ..model import Model
from .bundles import Levels, Precond, Work

__all__ = ["Level", "Hierarchy", "band_layout", "build_hierarchy", "coarsen", "lattice_layout", "lattice_lines",
           "stencil"]

MAX_COARSEST_DOFS = 400  # the coarsest level is solved densely (Cholesky): keep it small


def lattice_lines(model: Model, d: int):
    """Lines of direction d as CSR (offsets, particle order) and each particle's slot."""
    g = model.grid_index
    seqs = [g[:, j] for j in range(g.shape[1])] if d == 0 else [g[i, :] for i in range(g.shape[0])]
    lines = []
    for seq in seqs:
        run = []
        for p in seq:
            if p >= 0:
                run.append(int(p))
            elif run:
                lines.append(run)
                run = []
        if run:
            lines.append(run)
    off = np.zeros(len(lines) + 1, dtype=np.int64)
    off[1:] = np.cumsum([len(l) for l in lines])
    idx = np.array([p for l in lines for p in l], dtype=np.int64)
    slot = np.empty(model.particle_count, dtype=np.int64)
    slot[idx] = np.arange(idx.size)
    return off, idx, slot


@dataclass(frozen=True)
class _MaskShape:
    """A lattice given by its mask (for coarse levels)."""

    u: np.ndarray
    w: np.ndarray
    mask: np.ndarray

    def grid(self, sigma):
        return self.u, self.w, self.mask


def stencil(model: Model, lines: tuple) -> dict:
    """The block-sparse structure of a level's stiffness matrix: a block for every pair of particles
    that share an element (a particle with itself, an edge's two ends, any two of a bending triple
    or a shear corner), rows in particle order, columns ascending; where each element's blocks are;
    and, per lattice line direction, the block coupling each particle to its predecessor on its line."""
    n = model.particle_count
    elems = [model.edge_indices.reshape(-1, 2).astype(np.int64), model.bend_indices.reshape(-1, 3).astype(np.int64),
             model.shear_indices.reshape(-1, 3).astype(np.int64)]

    def pairs(el):  # (k, m·m) row and column of each of an element's blocks, row-major
        m = el.shape[1]
        return np.repeat(el, m, axis=1), np.tile(el, (1, m))

    rows = [np.arange(n, dtype=np.int64)]
    cols = [np.arange(n, dtype=np.int64)]
    for el in elems:
        r, c = pairs(el)
        rows.append(r.ravel())
        cols.append(c.ravel())
    keys = np.unique(np.concatenate(rows) * n + np.concatenate(cols))
    row_off = np.zeros(n + 1, dtype=np.int64)
    row_off[1:] = np.cumsum(np.bincount(keys // n, minlength=n))
    out = {"row_off": row_off, "col": (keys % n).astype(np.int64),
           "diag": np.searchsorted(keys, np.arange(n, dtype=np.int64) * (n + 1))}
    for name, el in zip(("e_map", "b_map", "c_map"), elems):
        r, c = pairs(el)
        out[name] = np.searchsorted(keys, r * n + c).reshape(el.shape[0], el.shape[1] * el.shape[1]).astype(np.int64)
    for d, (off, idx, _slot) in zip("wf", lines):
        for back in (1, 2):  # the block coupling each particle to the one `back` steps before it on its line
            prev = -np.ones(n, dtype=np.int64)
            for k in range(len(off) - 1):
                line = idx[off[k]:off[k + 1]]
                key = line[back:] * n + line[:-back]
                at = np.minimum(np.searchsorted(keys, key), keys.size - 1)
                prev[line[back:]] = np.where(keys[at] == key, at, -1)
            out[f"l{d}_prev" + ("2" if back == 2 else "")] = prev
    return out


def lattice_layout(model: Model) -> tuple:
    """(warp lines, weft lines, stencil) of ``model`` (:func:`lattice_lines`, :func:`stencil`), read
    only: what :attr:`Model.lattice_layout <cloth_gym.sim.model.Model.lattice_layout>` keeps."""
    lw, lf = lattice_lines(model, 0), lattice_lines(model, 1)
    st = stencil(model, (lw, lf))
    for a in (*lw, *lf, *st.values()):
        a.setflags(write=False)
    return lw, lf, st


class Level:
    """One lattice level: its model, its lattice lines, its matrix stencil (shared by the levels of
    one model: ``Model.lattice_layout``), and the links to the next coarser level."""

    def __init__(self, model: Model):
        self.model = model
        self.n = model.particle_count
        self.lw, self.lf, self.stencil = model.lattice_layout
        self.inject = np.zeros(0, dtype=np.int64)  # (n_coarse,) fine index of each coarse node
        self.P_idx = -np.ones((self.n, 4), dtype=np.int64)  # coarse parents of each fine node
        self.P_w = np.zeros((self.n, 4))
        self._band: tuple[int, int] | None = None

    @property
    def band(self) -> tuple[int, int]:
        """:func:`band_layout` of this level (computed once: the integrator asks on every call)."""
        if self._band is None:
            self._band = band_layout(self)
        return self._band


def _offsets(sizes):
    off = np.zeros(len(sizes) + 1, dtype=np.int64)
    off[1:] = np.cumsum(sizes)
    return off


class Hierarchy:
    """The levels concatenated (rows of level l at ``off[l]:off[l+1]``): the kernels'
    :class:`~cloth_gym.sim.implicit.bundles.Levels` (static) and
    :class:`~cloth_gym.sim.implicit.bundles.Work` (scratch) bundles."""

    def __init__(self, levels: list[Level]):
        self.levels = levels
        ms = [lv.model for lv in levels]
        cat = np.concatenate
        ns = [lv.n for lv in levels]
        n_off = _offsets(ns)
        e_off = _offsets([len(m.edge_indices) for m in ms])
        b_off = _offsets([len(m.bend_indices) for m in ms])
        c_off = _offsets([len(m.shear_indices) for m in ms])
        injects = [lv.inject if k < len(levels) - 1 else np.zeros(0, np.int64) for k, lv in enumerate(levels)]
        i_off = _offsets([len(a) for a in injects])
        P_idx = cat([lv.P_idx if k < len(levels) - 1 else -np.ones((lv.n, 4), np.int64)
                     for k, lv in enumerate(levels)])
        P_w = cat([lv.P_w if k < len(levels) - 1 else np.zeros((lv.n, 4)) for k, lv in enumerate(levels)])
        lwo_off = _offsets([len(lv.lw[0]) for lv in levels])
        lfo_off = _offsets([len(lv.lf[0]) for lv in levels])
        N = n_off[-1]
        z_off = _offsets([len(lv.stencil["col"]) for lv in levels])
        nd = 3 * levels[-1].n if len(levels) > 1 else 1
        st = [lv.stencil for lv in levels]
        self.band_code = 0  # the "band" preconditioner: Precond.BAND_WARP or BAND_WEFT, set by enable_band
        self.levels_data = Levels(
            n_levels=len(levels), n_off=n_off, e_off=e_off, b_off=b_off, c_off=c_off, i_off=i_off,
            lwo_off=lwo_off, lfo_off=lfo_off, sigma=np.array([m.sigma for m in ms]),
            inject=cat(injects).astype(np.int64), P_idx=P_idx, P_w=P_w,
            rest=cat([m.edge_rest_length for m in ms]), edges=cat([m.edge_indices for m in ms]).reshape(-1, 2),
            edge_dir=cat([m.edge_dir for m in ms]), edge_width=cat([m.edge_width for m in ms]),
            triples=cat([m.bend_indices for m in ms]).reshape(-1, 3), bend_dir=cat([m.bend_dir for m in ms]),
            bend_width=cat([m.bend_width for m in ms]), bend_length=cat([m.bend_length for m in ms]),
            corners=cat([m.shear_indices for m in ms]).reshape(-1, 3),
            lw_off=cat([lv.lw[0] for lv in levels]), lw_idx=cat([lv.lw[1] for lv in levels]),
            lw_slot=cat([lv.lw[2] for lv in levels]),
            lf_off=cat([lv.lf[0] for lv in levels]), lf_idx=cat([lv.lf[1] for lv in levels]),
            lf_slot=cat([lv.lf[2] for lv in levels]),
            row_off=cat([t["row_off"] for t in st]), col=cat([t["col"] for t in st]), z_off=z_off,
            diag=cat([t["diag"] for t in st]), e_map=cat([t["e_map"] for t in st]).reshape(-1, 4),
            b_map=cat([t["b_map"] for t in st]).reshape(-1, 9), c_map=cat([t["c_map"] for t in st]).reshape(-1, 9),
            lw_prev=cat([t["lw_prev"] for t in st]), lf_prev=cat([t["lf_prev"] for t in st]),
            lw_prev2=cat([t["lw_prev2"] for t in st]), lf_prev2=cat([t["lf_prev2"] for t in st]))
        self.work = Work(
            xl=np.zeros((N, 3)), vals=np.zeros((z_off[-1], 3, 3)), mdiag=np.zeros(N), free=np.ones(N, dtype=np.bool_), Dblk=np.zeros((N, 3, 3)),
            Dinv=np.zeros((N, 3, 3)), lw_piv=np.zeros((N, 3, 3)), lw_low=np.zeros((N, 3, 3)),
            lf_piv=np.zeros((N, 3, 3)), lf_low=np.zeros((N, 3, 3)), lw_add=np.zeros(N), lf_add=np.zeros(N),
            work=np.zeros((N, 3)), rin=np.zeros((N, 3)),
            zl=np.zeros((N, 3)), res=np.zeros((N, 3)), corr=np.zeros((N, 3)), chol=np.zeros((nd, nd)),
            band=np.zeros((0, 1)), cvec=np.zeros(nd), cout=np.zeros(nd), pen=np.zeros((N, 3, 3)))

    def enable_band(self, code: int, w: int) -> None:
        """Size the band factor of :func:`band_layout`'s ``(code, w)`` for a single level,
        and the vectors its solve uses in place of the coarsest level's (unused with one level)."""
        nd = 3 * self.levels[0].n
        self.work = self.work._replace(band=np.zeros((nd, 3 * w + 3)), cvec=np.zeros(nd),
                                       cout=np.zeros(nd))
        self.band_code = code


def band_layout(level: Level) -> tuple[int, int]:
    """(:class:`~cloth_gym.sim.implicit.bundles.Precond` code, half-width in particles) of the band
    preconditioner: particles in the slot order of the lattice lines (BAND_WARP or BAND_WEFT) that
    gives the narrower band over the
    couplings it keeps (stretch edges, every pair of a shear corner, bending triples' a–b and b–c)."""
    m = level.model
    pairs = [m.edge_indices.reshape(-1, 2)]
    cor = m.shear_indices.reshape(-1, 3)
    pairs += [cor[:, [0, 1]], cor[:, [1, 2]], cor[:, [0, 2]]]
    tri = m.bend_indices.reshape(-1, 3)
    pairs += [tri[:, [0, 1]], tri[:, [2, 1]]]
    pairs = np.concatenate([pp.astype(np.int64) for pp in pairs]) if len(pairs) else np.zeros((0, 2), np.int64)
    best = None
    for code, slot in ((int(Precond.BAND_WARP), level.lw[2]), (int(Precond.BAND_WEFT), level.lf[2])):
        w = int(np.abs(slot[pairs[:, 0]] - slot[pairs[:, 1]]).max(initial=1))
        if best is None or w < best[1]:
            best = (code, w)
    return best


def coarsen(fine: Level) -> Level | None:
    """The next coarser level (every other lattice node), or None if too small."""
    fm = fine.model
    mask = fm.grid_index >= 0
    cmask = mask[::2, ::2]
    if cmask.sum() < 9 or min(cmask.shape) < 3:
        return None
    u = np.arange(cmask.shape[0]) * 2 * fm.sigma
    w = np.arange(cmask.shape[1]) * 2 * fm.sigma
    cm = lattice_model(_MaskShape(u, w, cmask), fm.material, 2 * fm.sigma, fm.options, np.eye(3), np.zeros(3),
                       np.array([0.0, 0.0, -G]))  # gravity adds nothing to the coarse operators
    coarse = Level(cm)
    cg = cm.grid_index
    fine.inject = np.array([fm.grid_index[2 * i, 2 * j] for i, j in cm.particle_grid], dtype=np.int64)
    P_idx = -np.ones((fine.n, 4), dtype=np.int64)
    P_w = np.zeros((fine.n, 4))
    for f, (i, j) in enumerate(fm.particle_grid):
        cand_i = [(i // 2, 1.0)] if i % 2 == 0 else [((i - 1) // 2, 0.5), ((i + 1) // 2, 0.5)]
        cand_j = [(j // 2, 1.0)] if j % 2 == 0 else [((j - 1) // 2, 0.5), ((j + 1) // 2, 0.5)]
        parents = []
        for ci, wi in cand_i:
            for cj, wj in cand_j:
                if 0 <= ci < cg.shape[0] and 0 <= cj < cg.shape[1] and cg[ci, cj] >= 0:
                    parents.append((int(cg[ci, cj]), wi * wj))
        total = sum(wt for _, wt in parents)
        for k, (c, wt) in enumerate(parents):
            P_idx[f, k] = c
            P_w[f, k] = wt / total
    fine.P_idx, fine.P_w = P_idx, P_w
    return coarse


def build_hierarchy(fine: Level, multigrid: bool, band: tuple[int, int] | None) -> Hierarchy:
    """The :class:`Hierarchy` of ``fine`` alone, or with its coarser levels for multigrid (every
    level :func:`coarsen` gives, unless the coarsest would hold more than MAX_COARSEST_DOFS unknowns,
    as a long narrow ribbon's does: then the fine level alone, preconditioned by lines); with the
    band factor of :func:`band_layout`'s ``band`` when given."""
    levels = [fine]
    if multigrid:
        while True:
            c = coarsen(levels[-1])
            if c is None:
                break
            levels.append(c)
        if 3 * levels[-1].n > MAX_COARSEST_DOFS:
            levels = levels[:1]
    hier = Hierarchy(levels)
    if band is not None:
        hier.enable_band(*band)
    return hier
