"""Measurements on a state: strains, energies, penetration of obstacles (CGS)."""

from __future__ import annotations

import functools
import math

import numpy as np

from ._numba import kernel_only, njit_brief
from .model import WARP, WEFT, Model, State
from .obstacles import moved_obstacles, signed_distance


@kernel_only
def _strain_of(q, edges, rest, e):
    """Engineering strain of edge ``e``, percent (``100·(r − σ)/σ``)."""
    a = edges[e, 0]
    b = edges[e, 1]
    d0 = q[b, 0] - q[a, 0]
    d1 = q[b, 1] - q[a, 1]
    d2 = q[b, 2] - q[a, 2]
    return 100.0 * (math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) - rest[e]) / rest[e]


@njit_brief
def _edge_strain(q, edges, rest, out):
    for e in range(edges.shape[0]):
        out[e] = _strain_of(q, edges, rest, e)


@njit_brief
def _max_edge_strain(q, edges, rest):
    best = -np.inf
    for e in range(edges.shape[0]):
        s = _strain_of(q, edges, rest, e)
        if not s <= best:  # NaN stays (as numpy's max)
            if s != s:
                return s
            best = s
    return best


@njit_brief
def first_non_finite(q, qd):
    """The first particle whose position (cm) or velocity (cm/s) has a NaN or infinite component;
    −1 when every one is finite."""
    for p in range(q.shape[0]):
        for i in range(3):
            if not (math.isfinite(q[p, i]) and math.isfinite(qd[p, i])):
                return p
    return -1


@njit_brief
def fastest(qd, inv_mass):
    """(p, s², s²_free): the fastest particle p (the first of equals; −1 without particles), its
    squared speed (cm²/s²), and the largest squared speed of the free particles (``inv_mass`` > 0;
    −1.0 when none is free). A squared speed is (v_x² + v_y²) + v_z², which may differ from numpy's
    ``einsum`` in the last bit; it decides only a divergence and a number of substeps."""
    best, best_sq, free_sq = -1, -1.0, -1.0
    for p in range(qd.shape[0]):
        sq = qd[p, 0] * qd[p, 0] + qd[p, 1] * qd[p, 1] + qd[p, 2] * qd[p, 2]
        if sq > best_sq or best < 0:
            best, best_sq = p, sq
        if inv_mass[p] > 0.0 and sq > free_sq:
            free_sq = sq
    return best, best_sq, free_sq


def edge_strain(model: Model, state: State) -> np.ndarray:
    """(E,) engineering strain of every stretch edge, percent (``100·(r − σ)/σ``)."""
    out = np.empty(model.edge_rest_length.shape[0])
    _edge_strain(np.ascontiguousarray(state.particle_q, dtype=np.float64), model.edge_indices,
                 model.edge_rest_length, out)
    return out


def max_edge_strain(model: Model, state: State) -> float:
    """The largest strain of :func:`edge_strain` (percent) without its (E,) array: the same value
    as its ``max()``, NaN if one is NaN; −inf for a model without edges (where ``max()`` raises)."""
    return _max_edge_strain(np.ascontiguousarray(state.particle_q, dtype=np.float64), model.edge_indices,
                            model.edge_rest_length)


def particle_max_strain(model: Model, state: State) -> np.ndarray:
    """(N,) the largest strain (percent) of the edges at each particle (−inf for one without edges)."""
    eps = edge_strain(model, state)
    out = np.full(model.particle_count, -np.inf)
    for k in (0, 1):
        np.maximum.at(out, model.edge_indices[:, k], eps)
    return out


def strain_summary(model: Model, state: State) -> dict:
    """Max and mean tensile strain (percent) per direction."""
    eps = edge_strain(model, state)
    out = {}
    for name, d in (("warp", WARP), ("weft", WEFT)):
        sel = eps[model.edge_dir == d]
        out[f"max_strain_{name}_percent"] = float(sel.max()) if sel.size else 0.0
        out[f"mean_strain_{name}_percent"] = float(sel.mean()) if sel.size else 0.0
    return out


def kinetic_energy(model: Model, state: State) -> float:
    """Kinetic energy, erg (g·cm²/s²)."""
    return float(0.5 * np.sum(model.particle_mass[:, None] * state.particle_qd ** 2))


def gravity_energy(model: Model, state: State) -> float:
    """Gravitational potential energy relative to the rest configuration, erg."""
    dz = state.particle_q - model.particle_q0
    return float(-np.sum(model.particle_mass * (dz @ model.gravity)))


@functools.lru_cache(maxsize=64)
def _torque_table(law, coef: tuple, sigma: float, x0: float, hi: float, n: int = 6000):
    """(angle grid, cumulative ∫ law) on [0, hi], geometric near 0 where the regularised root is steep.

    Cached per (law, coefficients, σ, x0): built once, not on every energy evaluation."""
    grid = np.concatenate([[0.0], np.geomspace(1e-9, hi, n)])
    t = np.array([law(a, coef[0], coef[1], coef[2], sigma, x0) for a in grid])
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (t[1:] + t[:-1]) * np.diff(grid))])
    return grid, cum


def elastic_energy(model: Model, state: State) -> dict:
    """Elastic energy (erg) per force type: ``{"stretch", "bending", "shear", "total"}``.

    Stretch in closed form (the integral of the pull over the edge length);
    bending and shear as ``∫₀^ψ T`` and ``∫₀^|φ| T`` from tables of the torque
    laws (trapezoid rule on 6000 geometric nodes, relative error < 1e-6).
    Only the forces switched on in ``model.options`` count.
    """
    from .forces import (breen_bend_torque, breen_shear_torque, kes_bend_torque, kes_shear_torque)
    from ..units import G

    o = model.options
    breen = o.model == "breen"
    x = state.particle_q
    out = {"stretch": 0.0, "bending": 0.0, "shear": 0.0}
    if o.stretch and len(model.edge_indices):
        e = model.edge_indices
        L = model.edge_rest_length
        r = np.linalg.norm(x[e[:, 1]] - x[e[:, 0]], axis=1)
        if breen:
            d = r - L
            c0 = o.breen_c0
            en = np.where(d > 0, c0 * d ** 5 / L ** 5, c0 / L ** 2 * (-(2.0 / 3.0) * d ** 6 - L * d ** 5))
        else:
            eps = 100.0 * (r - L) / L
            c = model.stretch_coef[model.edge_dir]
            a = np.abs(eps)
            en = L * G * (L / 100.0) * (c[:, 0] * a * a / 2 + c[:, 1] * a ** 3 / 3)
            en = np.where(eps < 0, model.material.compression_factor * en, en)
        out["stretch"] = float((model.edge_width * en).sum())
    if o.bending and len(model.bend_indices):
        law = breen_bend_torque if breen else kes_bend_torque
        t = model.bend_indices
        e1 = x[t[:, 1]] - x[t[:, 0]]
        e2 = x[t[:, 2]] - x[t[:, 1]]
        psi = np.arctan2(np.linalg.norm(np.cross(e1, e2), axis=1), np.sum(e1 * e2, axis=1))
        total = 0.0
        lengths = model.bend_length
        for d in (0, 1):
            for ell in np.unique(lengths[lengths > 0]):  # 1, and ½ at a clamp (forces.bending.triple_law)
                sel = (model.bend_dir == d) & (lengths == ell)
                if np.any(sel):
                    c = model.bend_coef[d]
                    grid, cum = _torque_table(law, tuple(float(v) for v in c), float(model.sigma * ell),
                                              float(o.sqrt_reg_curvature), np.pi)
                    total += float((model.bend_width[sel] / ell * np.interp(psi[sel], grid, cum)).sum())
        out["bending"] = total
    if o.shear and len(model.shear_indices):
        law = breen_shear_torque if breen else kes_shear_torque
        t = model.shear_indices
        a = x[t[:, 0]] - x[t[:, 1]]
        c = x[t[:, 2]] - x[t[:, 1]]
        phi = np.abs(np.arctan2(np.linalg.norm(np.cross(a, c), axis=1), np.sum(a * c, axis=1)) - np.pi / 2)
        k = model.shear_coef
        grid, cum = _torque_table(law, tuple(float(v) for v in k), float(model.sigma), float(o.sqrt_reg_shear),
                                  np.pi / 2)
        out["shear"] = float(np.interp(phi, grid, cum).sum())
    out["total"] = out["stretch"] + out["bending"] + out["shear"]
    return out


@kernel_only
def _deepest(q, free, types, prm):
    depth = 0.0
    worst = -1
    for p in range(q.shape[0]):
        if not free[p]:
            continue
        for k in range(types.shape[0]):
            d = signed_distance(types[k], prm[k], q[p, 0], q[p, 1], q[p, 2])[0]
            if -d > depth:
                depth = -d
                worst = p
    return depth, worst


def obstacle_penetration(model: Model, state: State, free: "np.ndarray | None" = None) -> tuple[float, int]:
    """(depth in cm, particle) of the particle deepest inside an analytic obstacle (plane, box,
    sphere, cylinder, where ``state.obstacle_offset`` has moved them); (0.0, −1) when none is inside.
    ``free``: (N,) bool, the particles to look at (default: all; pass the ungrasped ones to leave
    out particles a gripper places)."""
    types, params, _mu = model.obstacle_arrays
    off = state.obstacle_offset
    prm = moved_obstacles(params, off if off is not None and off.shape == (types.shape[0], 3)
                          else np.zeros((types.shape[0], 3)))
    mask = np.ones(model.particle_count, dtype=np.bool_) if free is None else np.asarray(free, dtype=np.bool_)
    depth, worst = _deepest(np.ascontiguousarray(state.particle_q, dtype=np.float64), mask, types, prm)
    return float(depth), int(worst)
