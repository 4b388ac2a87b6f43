"""The implicit step's Newton passes (:func:`newton_passes`): further passes after the first
linearised solve, on the nonlinear residual at the current estimate, with an optional backtracking
line search. Used by the step (:mod:`cloth_gym.sim.implicit.step`, stage 7) and by the collision
coupling (:mod:`cloth_gym.sim.implicit.coupling`).

:func:`newton_passes` is resolved by the type of ``SolveOptions.newton`` while numba types its
caller: for :class:`~.bundles.OnePass` it does nothing, so a step taking one linearised pass
compiles none of the passes' code (docs/cli.md, "Where the first run's CPU goes").
"""

from __future__ import annotations

import math

from .._numba import chosen_by_type, copy_into, cycles, kernel_only, njit, runtime
from ..bundles import P_FACTOR, P_NEWTON
from ..forces import eval_forces
from . import precondition as pc
from .bundles import OnePass
from .cg import exact_momentum, filtered_pcg, free_mass, residual_norm2
from .contact import filter_vec, friction_force


@chosen_by_type
def newton_passes(newton, x, v, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, prof, rel):
    """Newton passes 2 … ``newton.passes`` (``newton``: ``opts.newton``): the residual
    ``−g(Δv) = β·f(x_k, v_k) − M·Δv`` (plus ⅓M(v − v₋₁) for BDF2, and friction at v_k) at the
    current estimate ``(x_k, v_k)``, filtered as the solve sees it (:func:`newton_residual`).
    Converged, and no further pass, once the correction δ that would follow has a mass-weighted
    RMS ``√(Σ m̃_q|δ_q|² / Σ m̃_q)`` within ``opts.newton_tol`` (cm/s), and with
    ``opts.newton_tol_max`` every ``|δ_q|`` within that: known before solving when the residual's
    ``Σ|g_q|²/m̃_q`` is small enough (A ≥ M̃ bounds δ by it: a quiet or rigidly carried cloth stops
    before its second assembly), else after the correction is solved (H assembled at the estimate,
    solved from 0) and added. With ``opts.line_search`` a correction that is not yet small is
    taken as ``α·δ``, α halved from 1 (at most LINE_SEARCH_HALVINGS times) until the residual's
    ``Σ|g_q|²/m̃_q`` falls by the factor ``1 − α/2`` (:func:`line_search`). Returns (ok,
    iterations, relative residual of the last solve, correction solves taken). For
    :class:`~.bundles.OnePass` (True, 0, ``rel``, 0), decided while numba types the caller.
    Compiled kernels only."""
    if getattr(newton, "instance_class", None) is OnePass:
        return lambda newton, x, v, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, prof, rel: (
            True, 0, rel, 0)
    return _newton_passes  # compiled once, linked into each caller (the step, the collision coupling)


def _newton_passes(newton, x, v, wind, heff, use2, opts, fd, world, contacts, lv, ws, sw, prof, rel):
    t0 = cycles()
    factored = prof[P_FACTOR]
    n = x.shape[0]
    fr = sw.free
    h2 = heff * heff
    it = 0
    passes = 0  # correction solves taken
    from_zero = not runtime(True)
    floor2 = opts.newton_tol * opts.newton_tol * free_mass(sw.md, fr) if opts.newton_tol > 0.0 else 0.0
    # the per-particle test: Σ|g|²/m̃ ≤ min m̃ · tol_max² bounds every |δ_q| by tol_max before solving
    max2 = opts.newton_tol_max * opts.newton_tol_max
    floor2_max = max2 * min_free_mass(sw.md, fr) if max2 > 0.0 else math.inf
    phi, ready = 0.0, False  # the residual at sw.dv, and whether sw.rhs and sw.tmp hold it
    for _ in range(1, newton.passes):
        if not ready:
            phi = newton_residual(x, v, sw.dv, wind, heff, use2, fd, world, contacts, sw)
        ready = False
        if floor2 > 0.0 and phi <= min(floor2, floor2_max):
            break
        sw.stale[0] = 1  # the band factor, if used, is rebuilt on demand
        if not pc.setup(opts.family, sw.xk, h2, opts.precond, fd, lv, ws, sw.con, sw.cn, runtime(True)):
            return False, it, rel, passes
        copy_into(sw.dv_k, sw.dv)
        it2, rel = filtered_pcg(from_zero, sw.rhs, sw.dv, sw.cg, opts, h2, fr, sw.con, sw.cn, sw.md, lv, ws,
                                sw.stale, sw.bslot, prof)
        if opts.momentum_exact:
            exact_momentum(sw.rhs, sw.dv, sw.md, fr, sw.con)
        it += it2
        passes += 1
        small = below_floor_velocity(sw.dv, sw.md, floor2)  # the correction itself within newton_tol
        if small and max2 > 0.0:
            small = largest_square(sw.dv) <= max2
        if small or not opts.line_search:
            for q in range(n):
                for i in range(3):
                    sw.dv[q, i] += sw.dv_k[q, i]
            if small:
                break
        else:
            phi = line_search(x, v, wind, heff, use2, fd, world, contacts, sw, phi)
            ready = True
    prof[P_NEWTON] += cycles() - t0 - (prof[P_FACTOR] - factored)
    return True, it, rel, passes


#: the line search's largest number of step halvings (α ≥ 1/16)
LINE_SEARCH_HALVINGS = 4


@njit(inline="always")
def line_search(x, v, wind, heff, use2, fd, world, contacts, sw, phi0):
    """Backtracking on the Newton correction: ``sw.dv`` holds δ and ``sw.dv_k`` the estimate it
    corrects; leaves ``sw.dv = dv_k + α·δ`` for the first α = 1, ½, … whose residual
    ``φ(α) = Σ|g_q|²/m̃_q`` is at most ``(1 − α/2)·phi0`` (Armijo's test on ½‖g‖², slope −2φ₀ along
    a Newton direction, with constant ¼), or the smallest α tried, and returns its φ. Its residual
    is left in ``sw.rhs`` for the next pass."""
    n = x.shape[0]
    copy_into(sw.delta, sw.dv)
    alpha = 1.0
    phi = phi0
    for k in range(LINE_SEARCH_HALVINGS + 1):
        for q in range(n):
            for i in range(3):
                sw.dv[q, i] = sw.dv_k[q, i] + alpha * sw.delta[q, i]
        phi = newton_residual(x, v, sw.dv, wind, heff, use2, fd, world, contacts, sw)
        if phi <= (1.0 - 0.5 * alpha) * phi0 or k == LINE_SEARCH_HALVINGS:
            break
        alpha *= 0.5
    return phi


@kernel_only
def newton_residual(x, v, dv, wind, heff, use2, fd, world, contacts, sw):
    """The Newton residual at the estimate ``Δv = dv``: the estimate ``(x_k, v_k)`` into ``sw.xk``,
    ``sw.vk``, ``−g(Δv) = β·(f + f_friction)(x_k, v_k) − M·Δv`` (BDF2: plus ⅓M(v − v₋₁)) into
    ``sw.rhs`` (0 at pinned particles), the same filtered as the solve sees it (constraint reactions
    out) into ``sw.tmp``; returns the filtered residual's ``Σ|g_q|²/m̃_q``."""
    n = x.shape[0]
    fr = sw.free
    for q in range(n):
        for i in range(3):
            sw.vk[q, i] = v[q, i] + (dv[q, i] if fr[q] else 0.0)
            sw.xk[q, i] = x[q, i] + (sw.dxh[q, i] if use2 else 0.0) + heff * sw.vk[q, i]
    eval_forces(sw.xk, sw.vk, wind, fd, sw.normals, sw.f)
    if contacts:
        friction_force(sw.vk, sw.con, sw.cn, sw.cfric, world.touching, world.vel, sw.ffric)
    for q in range(n):
        for i in range(3):
            if fr[q]:
                sw.rhs[q, i] = heff * (sw.f[q, i] + sw.ffric[q, i]) - fd.mass[q] * dv[q, i]
                if use2:
                    sw.rhs[q, i] += fd.mass[q] * (v[q, i] - sw.hist_v_old[q, i]) / 3.0
            else:
                sw.rhs[q, i] = 0.0
    copy_into(sw.tmp, sw.rhs)
    filter_vec(sw.tmp, fr, sw.con, sw.cn)
    return residual_norm2(sw.tmp, sw.md)


@kernel_only
def below_floor_velocity(dv, md, floor2):
    """``Σ m̃_q |Δv_q|² ≤ floor2`` (False when the floor is 0: off): a velocity correction whose
    mass-weighted RMS is within the Newton tolerance."""
    if floor2 <= 0.0:
        return False
    s = 0.0
    for q in range(dv.shape[0]):
        s += md[q] * (dv[q, 0] * dv[q, 0] + dv[q, 1] * dv[q, 1] + dv[q, 2] * dv[q, 2])
    return s <= floor2


@kernel_only
def min_free_mass(md, fr):
    """The smallest lumped mass (g) of a free particle (inf if none)."""
    m = math.inf
    for q in range(md.shape[0]):
        if fr[q] and md[q] < m:
            m = md[q]
    return m


@kernel_only
def largest_square(dv):
    """``max_q |Δv_q|²``, (cm/s)²."""
    b = 0.0
    for q in range(dv.shape[0]):
        b = max(b, dv[q, 0] * dv[q, 0] + dv[q, 1] * dv[q, 1] + dv[q, 2] * dv[q, 2])
    return b
