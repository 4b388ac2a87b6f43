"""Implicit (backward Euler) integration, Baraff & Witkin 1998 (SPEC §7).

One linearised Newton step per time step h:

    (M(1 + hλ) + h·D + h²·H) Δv = h·(f(x, v) − h·H·v),   v ← v + Δv,   x ← x + h·v

where ``H ≈ −∂f/∂x`` is a positive semi-definite approximation of the
stiffness, ``λ`` the material's mass-proportional damping rate (1/s) and ``D``
the diagonal linearisation of air drag (``2·C_air·σ²·|n·u|`` per particle,
g/s). ``H`` is the sum of one matrix-free term per force type
(:mod:`cloth_gym.sim.implicit_kernels`):

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
  lines, averaged, ``½(L_warp⁻¹ + L_weft⁻¹)``: it captures the stiff stretch
  coupling (alone, stretch gives a condition number of ~3) but not shear,
  whose near-rigid rotation modes need coarse-grid information;
* ``"multigrid"`` (default): a geometric V-cycle on the lattice, coarsened by
  2 in each direction, with the coarse operators *rediscretised* (the same
  KES model on a 2σ lattice whose positions are injected from the fine one),
  bilinear interpolation, full-weighting restriction, one damped line-smoother
  sweep before and after, and a dense solve at the coarsest level.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, SimulationDiverged
from . import implicit_kernels as kk
from .forces import eval_forces, force_args
from .integrators import _DIVERGE_REASONS, check_state, contact_args
from .obstacles import collide_particles
from .model import Control, Model, State, build_cloth

__all__ = ["ImplicitEuler", "ImplicitStepInfo"]

_SMOOTH_DAMPING = 0.7  # ω of the damped line smoother (its spectrum reaches ~2.6 undamped)


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


class _Level:
    """One lattice level of the solve: topology, assembled H, smoother factors."""

    def __init__(self, model: Model, precond: int):
        self.model = model
        n = model.particle_count
        self.n = n
        self.precond = precond
        self.args = force_args(model)
        self.K = np.zeros((len(model.edge_indices), 3, 3))
        self.B = np.zeros((len(model.bend_indices), 8))
        self.kb = np.zeros(len(model.bend_indices))
        self.Sg = np.zeros((len(model.shear_indices), 9))
        self.ks = np.zeros(len(model.shear_indices))
        self.mdiag = np.zeros(n)
        self.free = np.ones(n, dtype=bool)
        self.Dblk = np.zeros((n, 3, 3))
        self.Dinv = np.zeros((n, 3, 3))
        self.lw = _lattice_lines(model, 0)
        self.lf = _lattice_lines(model, 1)
        self.lw_piv = np.zeros((n, 3, 3))
        self.lw_low = np.zeros((n, 3, 3))
        self.lf_piv = np.zeros((n, 3, 3))
        self.lf_low = np.zeros((n, 3, 3))
        self.work = np.zeros((n, 3))
        self.tmp = [np.zeros((n, 3)) for _ in range(4)]
        # links to the next coarser level
        self.inject: np.ndarray | None = None  # (n_coarse,) fine index of each coarse node
        self.P_idx: np.ndarray | None = None  # (n, 4) coarse parents of each fine node
        self.P_w: np.ndarray | None = None
        self.dense_inv: np.ndarray | None = None

    def assemble(self, x, h):
        m = self.model
        o = m.options
        breen = o.model == "breen"
        if o.stretch:
            kk.assemble_stretch(x, m.edge_indices, m.edge_dir, m.edge_rest_length, m.stretch_coef,
                                float(m.material.compression_factor), breen, float(o.breen_c0), self.K)
        if o.bending:
            kk.assemble_bending(x, m.bend_indices, m.bend_dir, m.bend_coef, m.sigma, float(o.sqrt_reg_curvature),
                                breen, self.B, self.kb)
        if o.shear:
            kk.assemble_shear(x, m.shear_indices, m.shear_coef, m.sigma, float(o.sqrt_reg_shear), breen,
                              self.Sg, self.ks)

    def ops(self):
        m = self.model
        return (m.edge_indices, self.K, m.bend_indices, self.B, self.kb, m.shear_indices, self.Sg, self.ks)

    def setup_smoother(self, h2):
        m = self.model
        kk.diagonal_blocks(self.mdiag, h2, *self.ops(), self.Dblk)
        if self.precond == 1:
            for d, (off, idx, slot), piv, low in ((0, self.lw, self.lw_piv, self.lw_low),
                                                  (1, self.lf, self.lf_piv, self.lf_low)):
                kk.set_line_couplings(h2, m.edge_indices, m.edge_dir, self.K, m.shear_indices, self.Sg, self.ks,
                                      self.free, d, slot, low)
                kk.line_blocks(self.mdiag, h2, self.Dblk, m.edge_indices, m.edge_dir, self.K, self.free,
                               off, idx, d, piv, low)
        else:
            kk.invert_blocks(self.Dblk, self.Dinv)

    def smooth(self, r, z, scale=1.0):
        kk.smooth_apply(r, self.precond, self.Dinv, self.free, self.lw[0], self.lw[1], self.lw_piv, self.lw_low,
                        self.lf[0], self.lf[1], self.lf_piv, self.lf_low, self.work, scale, z)

    def matvec(self, p, y, h2):
        kk._matvec_A(p, self.mdiag, h2, *self.ops(), self.free, y)

    def residual(self, b, x, r, h2):
        kk.residual(b, x, self.mdiag, h2, *self.ops(), self.free, r)


def _coarsen(fine: _Level, precond: int) -> _Level | None:
    """The next coarser level (every other lattice node), or None if too small."""
    fm = fine.model
    mask = fm.grid_index >= 0
    cmask = mask[::2, ::2]
    if cmask.sum() < 9 or min(cmask.shape) < 3:
        return None
    u = np.arange(cmask.shape[0]) * 2 * fm.sigma
    w = np.arange(cmask.shape[1]) * 2 * fm.sigma
    cm = build_cloth(_MaskShape(u, w, cmask), fm.material, sigma=2 * fm.sigma, options=fm.options)
    coarse = _Level(cm, precond)
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
    max_dt: accuracy option, s: ``step(dt)`` uses ``ceil(dt / max_dt)`` equal
        substeps. Stability does not limit it; accuracy and numerical damping do.
    tol: CG relative residual tolerance ``|r|/|b|``.
    max_iter: CG iteration cap per step (the step goes on with the last iterate;
        ``last_stats`` and the step info report the residual reached).
    preconditioner: ``"multigrid"`` (default), ``"lines"`` or ``"jacobi"``.
    max_speed, max_strain_percent: explosion thresholds (as :class:`SymplecticEuler`).
    """

    def __init__(self, max_dt: float = 5e-3, tol: float = 1e-4, max_iter: int = 200,
                 preconditioner: str = "multigrid", max_speed: float = 1.0e5,
                 max_strain_percent: float = 1000.0):
        if not (isinstance(max_dt, (int, float)) and math.isfinite(max_dt) and max_dt > 0):
            raise ConfigError("max_dt", f"must be a finite number > 0 s, got {max_dt!r}")
        if not (isinstance(tol, (int, float)) and 0 < tol < 1):
            raise ConfigError("tol", f"must be in (0, 1), got {tol!r}")
        if not (isinstance(max_iter, int) and max_iter >= 1):
            raise ConfigError("max_iter", f"must be an integer >= 1, got {max_iter!r}")
        if preconditioner not in ("multigrid", "lines", "jacobi"):
            raise ConfigError("preconditioner", f"must be 'multigrid', 'lines' or 'jacobi', got {preconditioner!r}")
        self.max_dt = float(max_dt)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self.preconditioner = preconditioner
        self.max_speed = float(max_speed)
        self.max_strain_percent = float(max_strain_percent)
        self._levels: tuple[int, list[_Level]] | None = None
        self._con = None
        self._cn = None
        self.last_stats = np.zeros((0, 2))

    # ------------------------------------------------------------------ API
    def substeps_for(self, model: Model, dt: float) -> int:
        """Number of equal substeps ``step`` uses for a step of ``dt`` seconds."""
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise ConfigError("dt", f"time step must be a finite number > 0 s, got {dt!r}")
        return max(1, int(math.ceil(dt / self.max_dt * (1 - 1e-12))))

    def step(self, model: Model, state: State, control: Control | None, dt: float) -> ImplicitStepInfo:
        """Advance ``state`` in place by ``dt`` seconds (in substeps of at most ``max_dt``)."""
        n = self.substeps_for(model, dt)
        return self._run(model, state, control, n, dt / n)

    def advance(self, model: Model, state: State, control: Control | None, duration: float, dt: float) -> int:
        """Advance by ``duration`` seconds in steps of at most ``dt``; returns the number of substeps."""
        if not (math.isfinite(duration) and duration >= 0):
            raise ConfigError("duration", f"must be a finite number >= 0 s, got {duration}")
        if duration == 0:
            return 0
        n_outer = int(math.ceil(duration / dt - 1e-9))
        h_outer = duration / n_outer
        n_sub = self.substeps_for(model, h_outer)
        self._run(model, state, control, n_outer * n_sub, h_outer / n_sub)
        return n_outer * n_sub

    # ------------------------------------------------------------------ internals
    def _hierarchy(self, model: Model) -> list[_Level]:
        if self._levels is not None and self._levels[0] == id(model):
            return self._levels[1]
        precond = 0 if self.preconditioner == "jacobi" else 1
        levels = [_Level(model, precond)]
        if self.preconditioner == "multigrid":
            while True:
                c = _coarsen(levels[-1], precond)
                if c is None:
                    break
                levels.append(c)
        self._levels = (id(model), levels)
        return levels

    def _run(self, model, state, control, n, h) -> ImplicitStepInfo:
        wind = np.zeros(3) if control is None else np.asarray(control.wind, dtype=float)
        levels = self._hierarchy(model)
        fine = levels[0]
        fine.free[:] = model.particle_inv_mass > 0
        o = model.options
        x, v = state.particle_q, state.particle_qd
        f = np.empty_like(x)
        normals = np.empty_like(x)
        drag = np.zeros(model.particle_count)
        rhs = np.empty_like(x)
        dv = np.empty_like(x)
        stats = np.zeros((n, 2))
        h2 = h * h
        contacts = contact_args(model)
        has_contacts = len(contacts[0]) > 0
        x_prev = np.empty_like(x)
        touching = self._touching(model)
        self._con = np.zeros(model.particle_count, dtype=np.int8)
        self._cn = np.zeros_like(x)
        impulse = np.empty_like(x)
        for s in range(n):
            eval_forces(x, v, wind, *force_args(model), normals, f)
            if o.air:
                kk.air_linearisation(x, v, model.tri_indices, wind, float(model.material.air_drag), model.sigma,
                                     normals, drag)
            kk.lumped_mass(model.particle_mass, float(model.material.damping), o.damping, drag, h, fine.mdiag)
            fine.assemble(x, h)
            self._setup_levels(levels, x, h2)
            kk.implicit_rhs(f, v, h, *fine.ops(), fine.free, rhs)
            if has_contacts:
                kk.contact_constraints(x, f, touching, contacts[0], contacts[1], self._cn, self._con)
            it, rel = self._pcg(levels, rhs, dv, h2)
            stats[s] = it, rel
            if has_contacts:
                x_prev[:] = x
                fine.residual(rhs, dv, impulse, h2)  # b − AΔv; the constraint impulse is its negative
                impulse *= -1.0
                kk.update_with_friction(x, v, dv, h, fine.free, self._con, self._cn, impulse,
                                        model.particle_mass, contacts[2], touching)
            else:
                kk.update_state(x, v, dv, h, fine.free)
            if has_contacts:
                collide_particles(x, v, x_prev, model.particle_inv_mass, *contacts, h, touching)
            status, p, value = check_state(x, v, model.edge_indices, model.edge_rest_length, self.max_speed,
                                           self.max_strain_percent)
            if status != 0:
                state.step += s + 1
                state.time += (s + 1) * h
                self.last_stats = stats[: s + 1]
                raise SimulationDiverged(state.step, state.time, p, _DIVERGE_REASONS[status], value)
        state.step += n
        state.time += n * h
        self.last_stats = stats
        return ImplicitStepInfo(n, h, int(stats[:, 0].max()), float(stats[:, 0].mean()), float(stats[:, 1].max()))

    def _touching(self, model):
        """Per-particle obstacle contact of the last step (−1: none), kept across calls."""
        t = getattr(self, "_touch", None)
        if t is None or t.shape[0] != model.particle_count or getattr(self, "_touch_model", None) != id(model):
            t = -np.ones(model.particle_count, dtype=np.int64)
            self._touch, self._touch_model = t, id(model)
        return t

    def _filter(self, fine, r):
        if self._con is not None:
            kk.filter_vec(r, fine.free, self._con, self._cn)

    def _setup_levels(self, levels, x, h2):
        levels[0].setup_smoother(h2)
        xf = x
        for fine, coarse in zip(levels[:-1], levels[1:]):
            xc = xf[fine.inject]
            coarse.assemble(xc, None)
            kk.restrict_scalar(fine.mdiag, fine.P_idx, fine.P_w, coarse.mdiag)
            coarse.free[:] = fine.free[fine.inject]
            coarse.setup_smoother(h2)
            xf = xc
        if len(levels) > 1:
            last = levels[-1]
            A = np.empty((3 * last.n, 3 * last.n))
            kk.dense_matrix(last.mdiag, h2, *last.ops(), last.free, A)
            last.dense_inv = np.linalg.inv(A)

    def _vcycle(self, levels, k, r, z, h2):
        """z ≈ A_k⁻¹ r by one V-cycle from level k (symmetric: same smoother before and after)."""
        lv = levels[k]
        if k == len(levels) - 1 and lv.dense_inv is not None:
            z[:] = (lv.dense_inv @ r.reshape(-1)).reshape(-1, 3)
            z[~lv.free] = 0.0
            return
        if k == len(levels) - 1:
            lv.smooth(r, z)
            return
        res, corr = lv.tmp[0], lv.tmp[1]
        lv.smooth(r, z, _SMOOTH_DAMPING)
        lv.residual(r, z, res, h2)
        coarse = levels[k + 1]
        rc, zc = coarse.tmp[2], coarse.tmp[3]
        kk.restrict(res, lv.P_idx, lv.P_w, coarse.free, rc)
        self._vcycle(levels, k + 1, rc, zc, h2)
        kk.prolong_add(zc, lv.P_idx, lv.P_w, lv.free, z)
        lv.residual(r, z, res, h2)
        lv.smooth(res, corr, _SMOOTH_DAMPING)
        z += corr

    def _pcg(self, levels, b, x, h2):
        fine = levels[0]
        x[:] = 0.0
        r = b.copy()
        self._filter(fine, r)
        bnorm = math.sqrt(kk.bdot(r, r))
        if bnorm == 0.0:
            return 0, 0.0
        z = np.empty_like(b)
        Ap = np.empty_like(b)
        inner = (lambda rr, zz: self._vcycle(levels, 0, rr, zz, h2)) if len(levels) > 1 \
            else (lambda rr, zz: fine.smooth(rr, zz))

        def precondition(rr, zz):  # S P S: symmetric on the filtered subspace
            inner(rr, zz)
            self._filter(fine, zz)
        precondition(r, z)
        p = z.copy()
        rz = kk.bdot(r, z)
        it, rel = 0, 1.0
        while it < self.max_iter:
            fine.matvec(p, Ap, h2)
            self._filter(fine, Ap)
            pAp = kk.bdot(p, Ap)
            if pAp <= 0.0:
                break
            alpha = rz / pAp
            kk.axpy_pair(x, r, p, Ap, alpha)
            it += 1
            rel = math.sqrt(kk.bdot(r, r)) / bnorm
            if rel <= self.tol:
                break
            precondition(r, z)
            rz_new = kk.bdot(r, z)
            kk.xpby(z, rz_new / rz, p)
            rz = rz_new
        return it, rel
