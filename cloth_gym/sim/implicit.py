"""Implicit (backward Euler) integration, Baraff & Witkin 1998 (docs/physics.md, integrators).

One linearised Newton step per time step h:

    (M + h·(D + C) + h²·H) Δv = h·(f(x, v) − h·H·v),   v ← v + Δv,   x ← x + h·v

where ``H ≈ −∂f/∂x`` is a positive semi-definite approximation of the
stiffness, ``C`` the strain-rate damping matrix (``−C·v`` is the material's damping force:
β times the material part of each element's stiffness, ``Material.strain_damping``; with the
paper's absolute damping instead, ``C = λ·M``), and ``D`` the diagonal linearisation of air drag
(``2·C_air·σ²·|n·u|`` per particle, g/s). ``H + C/h`` is assembled once per Newton pass as one
block-sparse matrix
(:class:`~cloth_gym.sim.implicit_kernels.Matrix`, a 3×3 block per pair of particles sharing an
element), each force adding its blocks from its own module (:mod:`cloth_gym.sim.forces`):

* stretch: the exact edge Jacobian ``p'(r)·d̂d̂ᵀ + (p/r)·(I − d̂d̂ᵀ)`` with the
  transverse term clamped at 0 in compression (p < 0), which keeps H PSD;
* bending: ``k·JᵀJ`` with ``b = ê2 − ê1`` (|b| ≈ ψ for small ψ), ``J = ∂b/∂x``
  — the Gauss–Newton term of ``½k|b|²``, well defined at the flat state where
  ∇ψ is not — with ``k = max(dT/dψ, T/ψ, 0)`` (the tangent for bending in the
  plane of the triple, the secant for turning that plane);
* shear: Gauss–Newton ``k·∇γ∇γᵀ`` with ``k = max(dT/dφ, 0)``.

The linear system is solved by preconditioned conjugate gradients; pinned
particles are filtered out (their rows and columns removed, Δv = 0).
Preconditioners (``preconditioner=``):

* ``"jacobi"``: 3×3 block diagonal;
* ``"lines"``: exact block-tridiagonal solves along warp lines and along weft
  lines, averaged, ``½(L_warp⁻¹ + L_weft⁻¹)``, each line's matrix its principal submatrix of A
  with the couplings two steps along it bounded onto the diagonal: it captures the stiff stretch
  coupling (alone, stretch gives a condition number of ~3) but not shear, whose near-rigid
  rotation modes need coarse-grid information, so it pays only for small steps;
* ``"band"`` (what ``"auto"`` picks for small lattices: 11 × 11, ribbons): the whole matrix,
  penalty included, factored by a banded Cholesky in the order of the shorter lattice lines, but
  for the blocks beyond the band (the two ends of a bending triple across lines), each replaced
  by a bound on its particles' diagonal blocks that keeps it SPD
  (:func:`~cloth_gym.sim.implicit_kernels.band_assemble`). Exact without bending (one CG
  iteration); its cost, ``3N·(3w + 3)²`` for lines of w − 1 particles, limits it to small lattices;
* ``"multigrid"`` (what ``"auto"`` picks from 1000 particles, but for small steps below 4000):
  a geometric V-cycle on the lattice, coarsened by
  2 in each direction, with the coarse operators *rediscretised* (the same
  KES model on a 2σ lattice whose positions are injected from the fine one),
  bilinear interpolation, full-weighting restriction, one damped line-smoother
  sweep before and after, and a dense solve at the coarsest level.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, SimulationDiverged
from ..units import G
from ..validation import flag, integer, one_of, real
from . import implicit_kernels as kk
from .bundles import DIVERGE_REASONS, N_PHASES, Guard, Status
from .implicit_kernels import Carry, Levels, Precond, SolveOptions, Work
from .integrators import (check_advance, check_call, check_dt, check_steps, check_strain_guard, effective_mass,
                          make_world, phase_profile, strain_guard)
from .model import Control, Model, State, lattice_model
from .obstacles import moved_obstacles, resting_contacts

__all__ = ["ImplicitEuler", "ImplicitStepInfo"]

_SMOOTH_DAMPING = 0.7  # ω of the damped line smoother (its spectrum reaches ~2.6 undamped)
AUTO_MULTIGRID_PARTICLES = 1000  # preconditioner="auto": multigrid from this many particles, lines below
# ... except for small steps on mid-sized lattices, where lines need few enough iterations to win:
# "auto" keeps lines below AUTO_LINES_PARTICLES while the stiffness number h²·k/m stays below
# AUTO_LINES_STIFFNESS (k the stiffest edge's tangent at rest, m the lightest particle). Measured,
# CPU s per simulated s, 41×41 cotton tablecloth, t = 0.02–0.52 s, lines / multigrid: 1 ms (number
# 228) 10.5 / 13.8, 2 ms (913) 7.6 / 8.9, 3 ms (2055) 6.6 / 7.7, 5 ms (5700) 5.8 / 5.3, 10 ms 2.5 /
# 2.3; 81×81 at 1 ms (913): 90 / 73 (lines' iterations grow with the lattice's width).
AUTO_LINES_STIFFNESS = 3000.0
AUTO_LINES_PARTICLES = 4000
AUTO_BAND_WORK = 1.0e6  # preconditioner="auto": the band factor while 3N·(band width)² stays below this
_MAX_COARSEST_DOFS = 400  # the coarsest level is solved densely (Cholesky): keep it small


def _lattice_lines(model: Model, d: int):
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


def _stencil(model: Model, lines: tuple) -> dict:
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
        out[name] = np.searchsorted(keys, r * n + c).reshape(el.shape[0], -1).astype(np.int64)
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


class _Level:
    """One lattice level: its model, its lattice lines, its matrix stencil, and the links to the
    next coarser level."""

    def __init__(self, model: Model):
        self.model = model
        self.n = model.particle_count
        self.lw = _lattice_lines(model, 0)
        self.lf = _lattice_lines(model, 1)
        self.stencil = _stencil(model, (self.lw, self.lf))
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


class _Hierarchy:
    """The levels concatenated (rows of level l at ``off[l]:off[l+1]``): the kernels'
    :class:`~cloth_gym.sim.implicit_kernels.Levels` (static) and
    :class:`~cloth_gym.sim.implicit_kernels.Work` (scratch) bundles."""

    def __init__(self, levels: list[_Level]):
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


def band_layout(level: _Level) -> tuple[int, int]:
    """(:class:`~cloth_gym.sim.implicit_kernels.Precond` code, half-width in particles) of the band
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


def _coarsen(fine: _Level) -> _Level | None:
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
    coarse = _Level(cm)
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


@dataclass(frozen=True)
class ImplicitStepInfo:
    """What one ``step`` did: substeps, substep length (s), CG iterations (max, mean) and worst residual."""

    substeps: int
    dt_sub: float
    cg_iterations_max: int
    cg_iterations_mean: float
    residual_max: float


class ImplicitEuler:
    """Backward Euler, one linearised Newton step per (sub)step, PCG solve (module docstring).

    Parameters
    ----------
    max_dt
        accuracy option, s: ``step(dt)`` uses ``ceil(dt / max_dt)`` equal
        substeps. Stability does not limit it; accuracy and numerical damping do.
    tol
        CG relative residual tolerance ``|r|/|b|``.
    vtol
        absolute floor of the CG stopping test, cm/s (0, the default: off). CG also stops once
        the residual guarantees a mass-weighted RMS error of Δv of at most ``vtol`` (the bound of
        :func:`~cloth_gym.sim.implicit_kernels.filtered_pcg`). The relative test alone solves a
        cloth at rest, whose filtered right-hand side is almost zero, to ``tol`` relative to that
        nothing: CornerLift's cloth lying on its table took 10–15 iterations per step for it, and
        takes 0–1 with ``vtol = 1e-3`` (a velocity error of 10 µm/s).
    max_iter
        CG iteration cap per step (the step goes on with the last iterate;
        ``last_stats`` and the step info report the residual reached).
    preconditioner
        ``"auto"`` (default: ``"multigrid"`` for lattices of at least
        ``AUTO_MULTIGRID_PARTICLES`` = 1000 particles, but ``"lines"`` below ``AUTO_LINES_PARTICLES``
        = 4000 for substeps whose stiffness number h²k/m is below ``AUTO_LINES_STIFFNESS`` = 3000
        (the 41×41 cotton cloth up to about 3.6 ms); below 1000, ``"band"`` while its factorisation
        work ``3N·(3w + 3)²`` is at most ``AUTO_BAND_WORK`` = 1e6 (11 × 11 and narrow ribbons),
        else ``"lines"``: the V-cycle's fixed cost outweighs its saved iterations there; CPU s per
        simulated s on the tablecloth at Δt = 10 ms: 121 particles lines 0.12 / multigrid 0.24,
        441: 0.70 / 0.94, 1681: 6.7 / 3.9. The band factor pays where lines need many
        iterations: CornerLift's expert-driven steps run 1.75× faster with it, RibbonDrop's
        1.3–1.8×; where they need few, it does not: DrapeOntoTable at 5 ms keeps lines),
        ``"band"``, ``"multigrid"``, ``"lines"`` or ``"jacobi"``.
    max_speed, max_strain_percent
        explosion thresholds (as :class:`SymplecticEuler`): speed (cm/s) and edge strain (%); the
        strain's default, None, is the model's guard (100 % for the KES model, none for Breen's).
    scheme
        ``"euler"`` (backward Euler, first order, strongly damping) or ``"bdf2"``
        (second order, same linear system with β = 2h/3; the previous state is kept in
        ``State.solver``, and a state without a history for its current step and Δt
        starts with one backward-Euler step).
    newton_iters
        Newton passes per step. 1 is Baraff–Witkin's single linearised step
        (first-order accurate on the nonlinear cloth whatever the scheme); more passes
        re-evaluate forces and stiffness at the new estimate (each costs about one step).
    strain_limit_percent
        ``None`` (default, off) or a strain (percent, > 0): after each step,
        Gauss–Seidel sweeps pull every lattice edge longer than ``(1 + limit/100)·L`` back to
        that length, then remove the separating velocity along edges at the limit (Provot 1995; see
        :func:`~cloth_gym.sim.substep.limit_strain`). It only removes the linearised
        step's error on rotating edges (impacts, folds at large Δt); set it above the strains
        the material really reaches (cotton under gravity: < 1 %).
    sleep_speed
        cm/s (0, the default: off). Sleeping, as rigid-body engines deactivate bodies at
        rest (Bullet, PhysX): a call that finds the cloth *asleep* only advances the time. The
        cloth falls asleep (its velocities set to 0) at the end of the second call in a row that
        moved no particle faster than ``sleep_speed`` on average over the call, under quiet inputs:
        no kinematic particle, no wind, no moving obstacle. Two calls, not one: across the
        turning point of a swing one call can end where it began, two in a row cannot unless the
        acceleration is below 2·sleep_speed/dt (a mode of angular frequency ω is then frozen at an
        amplitude below 2·sleep_speed/(dt·ω²)). Positions, not velocities, decide: contact and
        collision impulses can leave a resting particle with a velocity that moves it nowhere
        (measured: 0.5 cm/s on a folded corner lying on the floor). It stays asleep while the
        inputs stay quiet and its positions and (zero) velocities are untouched; anything else
        wakes it (a grasp, a release with a velocity, a reset). CornerLift's cloth lying on its
        table between grasps then costs no solve.
    slow_dt, slow_speed
        s (0, the default: off) and cm/s (1.0). Coarser substeps for a slow cloth:
        a :meth:`step` under quiet inputs (as for sleeping) that follows a quiet call on the same,
        untouched state in which no particle moved faster than ``slow_speed`` on average takes
        substeps of up to ``slow_dt`` instead of ``max_dt`` (``slow`` says whether the last call
        did). ``max_dt`` is set for the manipulated cloth, whose grasps, folds and impacts need it;
        a cloth settling on its own after a release does not: for DrapeOntoTable's cloth, slower
        than 1 cm/s after a release, one 50 ms control step is 0.088 mm RMS from 1 ms substeps
        with 5 ms substeps and 0.094 mm with 25 ms (186 states of 10 random-action episodes),
        against 0.97 mm for the held cloth at 5 ms. Any faster call, grasp or outside edit returns
        to ``max_dt`` at once. ``advance`` (the scenes) does not use it.
    warm_start
        each step's solve starts from the previous step's velocity change (True, the
        default) instead of from zero: Δv changes little from one small step to the next (in free
        fall not at all), so CG starts closer to the solution; a guess that leaves a residual larger
        than zero would is dropped (an impact). The guess is kept in ``State.solver`` between calls.
    friction_resolve
        solve a step again where its first solve left particles on an obstacle
        sliding more slowly than their friction dampers assumed, with those dampers raised (True,
        the default; :func:`~cloth_gym.sim.implicit_kernels.refine_friction`). Off, a cloth whose
        internal forces cancel brakes too little: stretched by 1 % and sliding at 30 cm/s on a
        table (μ = 0.3, Δt = 10 ms) it slides 1.78 cm where Coulomb's law says 1.39 (on: 1.33); the
        41×41 tablecloth drop at Δt = 1 ms costs 23 % less CPU without it, at the same distance
        from the reference (``docs/solver_core.md``).
    max_travel
        None (default) or a number of lattice spacings: a call whose fastest free particle
        (its speed at the start of the call plus what gravity adds over the call) would move
        farther than this in one substep takes more, shorter substeps. A cloth that hits the floor
        at 3 m/s on a 1 cm lattice tears in 5 ms substeps (edges past 100 % strain in one step);
        with substeps of a quarter of σ of travel its edges stay within a few percent.
    strain_iters
        at most this many limiter sweeps per step (it stops when all edges comply;
        at the impact of the 41×41 tablecloth at Δt = 20 ms, 100 sweeps leave 1.5 % against a
        1 % limit and 1,000 reach it; later steps need a few).
    """

    def __init__(self, max_dt: float = 5e-3, tol: float = 1e-4, max_iter: int = 200, vtol: float = 0.0,
                 preconditioner: str = "auto", max_speed: float = 1.0e5,
                 max_strain_percent: float | None = None, scheme: str = "euler", newton_iters: int = 1,
                 strain_limit_percent: float | None = None, strain_iters: int = 100, sleep_speed: float = 0.0,
                 slow_dt: float = 0.0, slow_speed: float = 1.0, warm_start: bool = True,
                 friction_resolve: bool = True, max_travel: float | None = None):
        max_dt = real("max_dt", max_dt, 0.0, 10.0, lo_open=True, unit="s")
        tol = real("tol", tol, 0.0, 1.0, lo_open=True, hi_open=True)
        vtol = real("vtol", vtol, 0.0, 1e3, hi_open=True, unit="cm/s")
        max_iter = integer("max_iter", max_iter, 1, 100_000)
        max_speed = real("max_speed", max_speed, 0.0, 3e10, lo_open=True, unit="cm/s")
        max_strain_percent = check_strain_guard(max_strain_percent)
        newton_iters = integer("newton_iters", newton_iters, 1, 10)
        one_of("scheme", scheme, ("euler", "bdf2"))
        one_of("preconditioner", preconditioner, ("auto", "band", "multigrid", "lines", "jacobi"))
        if strain_limit_percent is not None:
            strain_limit_percent = real("strain_limit_percent", strain_limit_percent, 0.0,
                                        1e6 if max_strain_percent is None else max_strain_percent,
                                        lo_open=True, hi_open=True, unit="% (None: off; below max_strain_percent)")
        sleep_speed = real("sleep_speed", sleep_speed, 0.0, 1e3, hi_open=True, unit="cm/s (0: off)")
        slow_dt = real("slow_dt", slow_dt, 0.0, 1.0, unit="s (0: off)")
        slow_speed = real("slow_speed", slow_speed, 0.0, 1e3, hi_open=True, unit="cm/s")
        warm_start = flag("warm_start", warm_start)
        friction_resolve = flag("friction_resolve", friction_resolve)
        strain_iters = integer("strain_iters", strain_iters, 1, 1000)
        if max_travel is not None:
            max_travel = real("max_travel", max_travel, 0.0, 100.0, lo_open=True, unit="lattice spacings (None: off)")
        self.max_travel = None if max_travel is None else float(max_travel)
        self.strain_limit_percent = None if strain_limit_percent is None else float(strain_limit_percent)
        self.strain_iters = strain_iters
        self.max_dt = float(max_dt)
        self.tol = float(tol)
        self.vtol = float(vtol)
        self.max_iter = int(max_iter)
        self.preconditioner = preconditioner
        self.max_speed = float(max_speed)
        self.max_strain_percent = max_strain_percent
        self.scheme = scheme
        self.newton_iters = newton_iters
        self._no_history = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(1, dtype=np.int64))
        # derived from the model alone (its lattice levels and packed arrays), rebuilt for another model;
        # everything carried from call to call lives in the state (State.solver)
        self._levels: tuple[Model, _Level, dict] | None = None
        self.last_stats = np.zeros((0, 2))
        self.sleep_speed = float(sleep_speed)
        self.slow_dt = float(slow_dt)
        self.slow_speed = float(slow_speed)
        self.slow = False  # did the last call take slow_dt substeps?
        self.warm_start = warm_start
        self.friction_resolve = friction_resolve
        self.asleep = False  # did the last call find the cloth asleep?
        self._profile: tuple[np.ndarray, float] | None = None

    @property
    def last_profile(self) -> dict[str, float] | None:
        """Where the last ``step``/``advance`` call spent its time: seconds per
        :class:`~cloth_gym.sim.bundles.Phase` — ``forces``; ``prepare`` (air drag's linearisation,
        lumped mass, obstacle contacts); ``assembly`` (the stiffness blocks and the preconditioner's
        set-up); ``rhs``; ``factor`` (the band preconditioner's factorisation, wherever it
        happens); ``solve`` (the first PCG solve); ``friction`` (the friction re-solve); ``newton``
        (further Newton passes); ``obstacles`` (analytic obstacles, the strain limiter);
        ``collision`` (the collision pass); ``checks`` (the divergence check) — plus ``other``,
        ``call`` and ``total`` (:func:`~cloth_gym.sim.integrators.phase_profile`). Read from the
        CPU's cycle counter around each phase, which costs a few nanoseconds per phase; all zero
        for a call that found the cloth asleep; None before a call."""
        return None if self._profile is None else phase_profile(*self._profile)

    # ------------------------------------------------------------------ API
    def substeps_for(self, model: Model, dt: float) -> int:
        """Number of equal substeps ``step`` uses for a step of ``dt`` seconds."""
        dt = check_dt("dt", dt)
        return max(1, check_steps("dt", math.ceil(dt / self.max_dt * (1 - 1e-12))))

    def step(self, model: Model, state: State, control: Control | None, dt: float) -> ImplicitStepInfo:
        """Advance ``state`` in place by ``dt`` seconds (in substeps of at most ``max_dt``)."""
        check_call(model, state, control)
        n = self.substeps_for(model, dt)
        quiet, last = self._continuation(model, state, control)
        self.slow = self.slow_dt > self.max_dt and last and state.solver.quiet_slow
        if self.slow:
            n = max(1, int(math.ceil(dt / self.slow_dt * (1 - 1e-12))))
        if self.max_travel is not None:
            n = max(n, self._travel_substeps(model, state, dt))
        return self._run(model, state, control, n, dt / n, quiet, last)

    def _travel_substeps(self, model: Model, state: State, dt: float) -> int:
        """Substeps that keep the fastest free particle within ``max_travel`` lattice spacings per
        substep: its speed at the start of the call plus what gravity adds over ``dt``."""
        free = model.particle_inv_mass > 0
        if not free.any():
            return 1
        qd = state.particle_qd[free]
        speed = math.sqrt(float(np.max(np.einsum("ij,ij->i", qd, qd)))) + float(np.linalg.norm(model.gravity)) * dt
        return check_steps("dt", max(1, math.ceil(speed * dt / (self.max_travel * model.sigma))))

    def advance(self, model: Model, state: State, control: Control | None, duration: float, dt: float) -> int:
        """Advance by ``duration`` seconds in steps of at most ``dt``; returns the number of substeps."""
        duration, dt = check_advance(duration, dt)
        check_call(model, state, control)
        if duration == 0:
            return 0
        n_outer = max(1, int(math.ceil(duration / dt - 1e-9)))
        h_outer = duration / n_outer
        n_sub = self.substeps_for(model, h_outer)
        check_steps("dt", n_outer * n_sub)
        self._run(model, state, control, n_outer * n_sub, h_outer / n_sub, *self._continuation(model, state, control))
        return n_outer * n_sub

    def preconditioner_for(self, model: Model, dt: float | None = None) -> str:
        """The preconditioner used on ``model`` for substeps of ``dt`` s (default ``max_dt``):
        ``"auto"`` resolved by the lattice and the step — the band factor while its cost
        ``3N·(3w + 3)²`` stays below ``AUTO_BAND_WORK``, multigrid from
        ``AUTO_MULTIGRID_PARTICLES`` particles unless the step is small enough for lines
        (``AUTO_LINES_STIFFNESS``, ``AUTO_LINES_PARTICLES``), lines between."""
        return self._choose(_Level(model), self.max_dt if dt is None else dt)[0]

    def _choose(self, level: _Level, h: float) -> tuple[str, tuple[int, int] | None]:
        """:meth:`preconditioner_for` of a level's model at substep ``h``, with the band layout when
        it is the band."""
        if self.preconditioner not in ("auto", "band"):
            return self.preconditioner, None
        if self.preconditioner == "auto" and level.n >= AUTO_MULTIGRID_PARTICLES:
            m = level.model
            number = h * h * float(m.edge_stiffness.max()) / effective_mass(m)
            if level.n < AUTO_LINES_PARTICLES and number < AUTO_LINES_STIFFNESS:
                return "lines", None
            return "multigrid", None
        layout = level.band
        if self.preconditioner == "band" or 3 * level.n * (3 * layout[1] + 3) ** 2 <= AUTO_BAND_WORK:
            return "band", layout
        return "lines", None

    # ------------------------------------------------------------------ internals
    def _hierarchy(self, model: Model, h: float) -> _Hierarchy:
        """The levels (and their scratch) for ``model`` at substep ``h``, built once per model and
        preconditioner (the model itself is the key: an id could be reused)."""
        if self._levels is None or self._levels[0] is not model:
            self._levels = (model, _Level(model), {})
        fine, built = self._levels[1], self._levels[2]
        choice, band = self._choose(fine, h)
        if choice in built:
            return built[choice]
        levels = [fine]
        if choice == "multigrid":
            while True:
                c = _coarsen(levels[-1])
                if c is None:
                    break
                levels.append(c)
            if 3 * levels[-1].n > _MAX_COARSEST_DOFS:
                # no small coarsest level (a long narrow ribbon): lines preconditioner alone
                levels = levels[:1]
        hier = _Hierarchy(levels)
        if band is not None:
            hier.enable_band(*band)
        built[choice] = hier
        return hier

    def _contacts_of(self, model, state):
        """Per-particle obstacle touched in the last step (−1: none), from the state's memory when it
        was written at the state's current step; else the contacts the positions are in (a cloth
        laid on a table rests on it from its first step)."""
        mem = state.solver
        n = model.particle_count
        if mem.contacts is None or mem.contacts_step != state.step or mem.contacts.shape != (n,):
            mem.contacts = -np.ones(n, dtype=np.int64)
            types, params, _ = model.obstacle_arrays
            if types.shape[0]:
                off = state.obstacle_offset
                prm = params if off is None or off.shape != (types.shape[0], 3) else moved_obstacles(params, off)
                resting_contacts(state.particle_q, types, prm, float(model.contact_thickness), mem.contacts)
        return mem.contacts

    def _bdf2_history(self, model, state, h):
        """(x₋₁, v₋₁, ok) for BDF2, from the state's memory while it continues the step it was
        written at with the same h; otherwise fresh arrays with ok = 0 (a backward-Euler start)."""
        mem = state.solver
        n = model.particle_count
        if self.scheme != "bdf2":  # unused by backward Euler: one set of placeholders, not three arrays per call
            if self._no_history[0].shape[0] != n:
                self._no_history = (np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(1, dtype=np.int64))
            return self._no_history
        if (mem.bdf2_x is not None and mem.bdf2_step == state.step and mem.bdf2_h == h
                and mem.bdf2_x.shape == (n, 3)):
            return mem.bdf2_x, mem.bdf2_v, np.ones(1, dtype=np.int64)
        return np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(1, dtype=np.int64)

    def _warm_guess(self, model, state, h):
        """(Δv, ok) the first solve of this call starts from: the last step's velocity change from the
        state's memory (scaled to this call's h) when it was written at the current step."""
        mem = state.solver
        n = model.particle_count
        if (self.warm_start and mem.warm_dv is not None and mem.warm_step == state.step
                and mem.warm_dv.shape == (n, 3)):
            return mem.warm_dv * (h / mem.warm_h), np.ones(1, dtype=np.int64)
        return np.zeros((n, 3)), np.zeros(1, dtype=np.int64)

    def _quiet(self, control) -> bool:
        """Inputs that cannot wake a cloth at rest: no kinematic particle, no wind, no moving obstacle."""
        return control is None or not ((control.kinematic is not None and np.any(control.kinematic))
                                       or np.any(np.asarray(control.wind) != 0.0)
                                       or (control.obstacle_velocity is not None
                                           and np.any(np.asarray(control.obstacle_velocity) != 0.0)))

    def _continuation(self, model, state, control) -> tuple[bool, bool]:
        """(quiet, last): are the inputs quiet (when sleeping or slow substeps could use them), and
        does this call continue the quiet call recorded in the state's memory (no step since,
        positions untouched)."""
        quiet = (self.sleep_speed > 0.0 or self.slow_dt > 0.0) and self._quiet(control)
        mem = state.solver
        last = (quiet and mem.quiet_q is not None and mem.quiet_step == state.step
                and np.array_equal(mem.quiet_q, state.particle_q))
        return quiet, last

    def _run(self, model, state, control, n, h, quiet, last) -> ImplicitStepInfo:
        mem = state.solver
        self.asleep = False
        # the last call on this state was slow enough to sleep, and nothing moved the cloth since
        slow_before = last and mem.quiet_sleepy
        if slow_before and mem.asleep and not np.any(state.particle_qd):  # asleep, velocities untouched
            contacts_valid = mem.contacts is not None and mem.contacts_step == state.step
            state.step += n
            state.time += n * h
            mem.quiet_step = state.step
            mem.quiet_slow, mem.quiet_sleepy, mem.asleep = False, True, True
            mem.bdf2_x = mem.bdf2_v = None
            if contacts_valid:
                mem.contacts_step = state.step
            self.last_stats = np.zeros((n, 2))
            self.asleep = True
            self._profile = (np.zeros(N_PHASES + 1, dtype=np.int64), 0.0)
            return ImplicitStepInfo(n, h, 0, 0.0, 0.0)
        mem.quiet_q = None
        x_start = state.particle_q.copy() if quiet else None
        wind = np.zeros(3) if control is None else np.asarray(control.wind, dtype=float)
        hier = self._hierarchy(model, h)
        precond = Precond.JACOBI if self.preconditioner == "jacobi" else (hier.band_code or Precond.LINES)
        stats = np.zeros((n, 2))
        hx, hv, ok = self._bdf2_history(model, state, h)
        world = make_world(model, state, control, self._contacts_of(model, state))
        opts = SolveOptions(self.tol, self.vtol, self.max_iter, int(precond), _SMOOTH_DAMPING, self.scheme == "bdf2",
                            self.newton_iters, self.warm_start, self.friction_resolve)
        warm_dv, warm_ok = self._warm_guess(model, state, h)
        max_strain = strain_guard(model, self.max_strain_percent)
        if self.strain_limit_percent is not None and self.strain_limit_percent >= max_strain:
            raise ConfigError("strain_limit_percent", f"{self.strain_limit_percent:g} % must be below the strain guard "
                              f"{max_strain:g} % (max_strain_percent, or the model's: the limiter would never act "
                              f"before the step diverges)")
        guard = Guard(self.max_speed, max_strain,
                      0.0 if self.strain_limit_percent is None else self.strain_limit_percent / 100.0,
                      self.strain_iters)
        inv_mass = model.particle_inv_mass if control is None else control.inv_mass(model)
        carry = Carry(hx, hv, ok, warm_dv, warm_ok)
        prof = np.zeros(N_PHASES + 1, dtype=np.int64)
        t = time.perf_counter()
        status, s, p, value = kk.run_implicit(n, h, state.particle_q, state.particle_qd, inv_mass, wind, stats, opts,
                                              guard, carry, model.force_data, world, hier.levels_data, hier.work,
                                              prof)
        self._profile = (prof, time.perf_counter() - t)
        status = Status(status)
        done = n if status == Status.OK else s + 1
        state.step += done
        state.time += done * h
        if status == Status.OK and self.scheme == "bdf2" and ok[0] == 1:
            mem.bdf2_x, mem.bdf2_v, mem.bdf2_h, mem.bdf2_step = hx, hv, h, state.step
        else:
            mem.bdf2_x = mem.bdf2_v = None
        mem.contacts_step = state.step if status == Status.OK else -1
        if status == Status.OK and self.warm_start and warm_ok[0] == 1:
            mem.warm_dv, mem.warm_h, mem.warm_step = warm_dv, h, state.step
        else:
            mem.warm_dv = None
        self.last_stats = stats[:done]
        if quiet and status == Status.OK:
            d = state.particle_q - x_start
            d2max = float(np.einsum("ij,ij->i", d, d).max(initial=0.0))
            below_slow = self.slow_dt > 0.0 and d2max < (self.slow_speed * n * h) ** 2
            below_sleep = d2max < (self.sleep_speed * n * h) ** 2
            if below_sleep and slow_before:
                # the second slow call in a row: the cloth falls asleep, at rest
                state.particle_qd[:] = 0.0
            if below_slow or below_sleep:
                mem.quiet_q, mem.quiet_step = state.particle_q.copy(), state.step
                mem.quiet_slow, mem.quiet_sleepy = bool(below_slow), bool(below_sleep)
                mem.asleep = bool(below_sleep and slow_before)
        if status == Status.NOT_SPD:  # name the first non-finite particle if there is one
            bad = ~(np.isfinite(state.particle_q).all(axis=1) & np.isfinite(state.particle_qd).all(axis=1))
            if bad.any():
                raise SimulationDiverged(state.step, state.time, int(np.argmax(bad)), "non-finite", math.nan)
            raise SimulationDiverged(state.step, state.time, -1, DIVERGE_REASONS[status], math.nan)
        if status != Status.OK:
            raise SimulationDiverged(state.step, state.time, p, DIVERGE_REASONS[status], value)
        if n == 1:
            return ImplicitStepInfo(1, h, int(stats[0, 0]), float(stats[0, 0]), float(stats[0, 1]))
        return ImplicitStepInfo(n, h, int(stats[:, 0].max()), float(stats[:, 0].mean()), float(stats[:, 1].max()))
