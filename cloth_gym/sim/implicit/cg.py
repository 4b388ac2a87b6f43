"""Filtered preconditioned conjugate gradients (Baraff–Witkin): CG on ``A·Δv = b`` with pinned
particles and obstacle constraints filtered out of every vector, stopped by a relative tolerance or
by an absolute floor on the mass-weighted error of Δv.
"""

from __future__ import annotations

import math

from .._numba import copy_into, cycles, kernel_only

from ..bundles import P_CG_PRECONDITION, P_CG_PRODUCT, P_FACTOR
from . import precondition as pc
from .bundles import BAND_WARP
from .contact import filter_vec, filtered_row
from .matrix import dot, matvec_A, xpby
from .multigrid import level_matrix



@kernel_only
def below_floor(r, md, floor2):
    """``Σ |r_q|² / m̃_q ≤ floor2`` (False when the floor is 0: off)."""
    if floor2 <= 0.0:
        return False
    return residual_norm2(r, md) <= floor2


@kernel_only
def residual_norm2(r, md):
    """``Σ |r_q|² / m̃_q`` over particles with m̃ > 0, (g·cm/s)²/g: a residual's squared norm
    in the inverse lumped mass."""
    s = 0.0
    for q in range(r.shape[0]):
        if md[q] > 0.0:
            s += (r[q, 0] * r[q, 0] + r[q, 1] * r[q, 1] + r[q, 2] * r[q, 2]) / md[q]
    return s



@kernel_only
def free_mass(md, fr):
    """``Σ m̃_q`` over the free particles, g: the weight of the mass-weighted RMS tests."""
    msum = 0.0
    for q in range(md.shape[0]):
        if fr[q]:
            msum += md[q]
    return msum


@kernel_only
def filter_dot(a, b, free, con, cn):
    """Filter ``a`` in place (:func:`~.contact.filter_vec`) and return ``a·b`` (the filtered ``a``):
    both in one pass over the particles, each row filtered, then added to the sum in particle order
    (the same sum as :func:`~.matrix.dot` after the filter)."""
    s = 0.0
    for q in range(a.shape[0]):
        if not free[q] or con[q] != 0:
            a[q, 0], a[q, 1], a[q, 2] = filtered_row(a[q, 0], a[q, 1], a[q, 2], free[q], con[q], cn[q, 0], cn[q, 1],
                                                     cn[q, 2])
        s += a[q, 0] * b[q, 0] + a[q, 1] * b[q, 1] + a[q, 2] * b[q, 2]
    return s


@kernel_only
def product(p, md, h2, H0, fr, con, cn, Ap, prof):
    """``Ap = S A p`` (the filtered operator); returns ``p·Ap``. Its cycles are added to
    ``prof[P_CG_PRODUCT]``."""
    t0 = cycles()
    matvec_A(p, md, h2, H0, fr, Ap)
    pAp = filter_dot(Ap, p, fr, con, cn)
    prof[P_CG_PRODUCT] += cycles() - t0
    return pAp


@kernel_only
def precondition(family, r, z, h2, precond, omega, lv, ws, fr, con, cn, prof):
    """``z = S P⁻¹ r`` (the filtered preconditioner); returns ``r·z``. Its cycles are added to
    ``prof[P_CG_PRECONDITION]``."""
    t0 = cycles()
    pc.apply(family, r, z, h2, precond, omega, lv, ws)
    rz = filter_dot(z, r, fr, con, cn)
    prof[P_CG_PRECONDITION] += cycles() - t0
    return rz


@kernel_only
def axpy_pair_norm2(x, r, p, Ap, alpha):
    """x += α p;  r −= α Ap; returns ``r·r`` (the updated r), summed in particle order as it goes
    (the same sum as :func:`~.matrix.dot` after the update)."""
    s = 0.0
    for q in range(x.shape[0]):
        for i in range(3):
            x[q, i] += alpha * p[q, i]
            r[q, i] -= alpha * Ap[q, i]
        s += r[q, 0] * r[q, 0] + r[q, 1] * r[q, 1] + r[q, 2] * r[q, 2]
    return s


@kernel_only
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
    then stops). Its cycles are added to ``prof[P_FACTOR]`` (the phase profile), those of the
    products and preconditioner applies to ``prof[P_CG_PRODUCT]`` and ``prof[P_CG_PRECONDITION]``."""
    r, z, p, Ap = cg.r, cg.z, cg.p, cg.Ap
    tol, precond, omega = opts.tol, opts.precond, opts.omega
    H0 = level_matrix(0, lv, ws)
    copy_into(r, rhs)
    filter_vec(r, fr, con, cn)
    bnorm = math.sqrt(dot(r, r))
    if warm and bnorm > 0.0:
        filter_vec(dv, fr, con, cn)
        product(dv, md, h2, H0, fr, con, cn, Ap, prof)  # r = S b − S A Δv (its dot product unused)
        for q in range(r.shape[0]):
            for i in range(3):
                r[q, i] -= Ap[q, i]
        if dot(r, r) >= bnorm * bnorm:  # a guess worse than none (an impact): start from 0
            dv[:] = 0.0
            copy_into(r, rhs)
            filter_vec(r, fr, con, cn)
    else:
        dv[:] = 0.0
    it = 0
    rel = math.sqrt(dot(r, r)) / bnorm if bnorm > 0.0 else 0.0
    floor2 = opts.vtol * opts.vtol * free_mass(md, fr) if opts.vtol > 0.0 else 0.0
    if bnorm > 0.0 and rel > tol and not below_floor(r, md, floor2):
        if precond >= BAND_WARP and stale[0] == 1:
            t0 = cycles()
            stale[0] = 0 if pc.factor(opts.family, ws.Dblk[0:lv.n_off[1]], fr, h2, H0, bslot, ws.band) else 2
            prof[P_FACTOR] += cycles() - t0
            if stale[0] == 2:
                return it, rel
        rz = precondition(opts.family, r, z, h2, precond, omega, lv, ws, fr, con, cn, prof)
        copy_into(p, z)
        while it < opts.max_iter:
            pAp = product(p, md, h2, H0, fr, con, cn, Ap, prof)
            if pAp <= 0.0:
                break
            a = rz / pAp
            rr = axpy_pair_norm2(dv, r, p, Ap, a)
            it += 1
            rel = math.sqrt(rr) / bnorm
            if rel <= tol or below_floor(r, md, floor2):
                break
            rz_new = precondition(opts.family, r, z, h2, precond, omega, lv, ws, fr, con, cn, prof)
            xpby(z, rz_new / rz, p)
            rz = rz_new
    return it, rel


@kernel_only
def exact_momentum(rhs, dv, md, free, con):
    """In free flight (every particle free, no obstacle constraint), add to Δv the uniform velocity
    that makes the solve's momentum balance exact, ``Σ m̃_q Δv_q = Σ b_q`` (g·cm/s): the internal
    forces' matrix H + C/β annihilates a uniform velocity, so the exact solution of
    ``(M̃ + β²H)Δv = b`` satisfies it, and an inexact CG iterate is off by its residual's sum. Only
    the momentum (the centre of mass's motion) changes, by that residual; the cloth's shape does
    not. With a pinned, held or touching particle, momentum is not conserved and nothing is done."""
    n = dv.shape[0]
    for q in range(n):
        if not free[q] or con[q] != 0:
            return
    msum = 0.0
    for q in range(n):
        msum += md[q]
    if msum <= 0.0:
        return
    for i in range(3):
        gap = 0.0
        for q in range(n):
            gap += rhs[q, i] - md[q] * dv[q, i]
        c = gap / msum
        if not math.isfinite(c):  # a non-finite state: leave it where it is, for the check to name
            return
        for q in range(n):
            dv[q, i] += c
