"""Bending: the torque of each triple of particles along a lattice line, KES (measured M(K) per
direction) or Breen's.

One home for the force: the curvature and torque laws, the force on the particles, and the
Gauss–Newton stiffness blocks for the implicit solver (:func:`linearise_bending`). Units: cm,
dyne·cm; angles in radians.
"""

from __future__ import annotations

import math

import numpy as np

from ...units import G
from .._numba import kernel_only
from .common import (PI, _cross, add_corner_blocks, angle_geometry, damp_three_particle_element, kes_poly,
                     reg_root_deriv)


@kernel_only
def kes_curvature(psi, sigma):
    """docs/physics.md, forces: ``K(ψ) = 3/(2σ)·sin(2ψ/3)`` (1/cm); ψ/σ for small ψ, peaks at ψ = 3π/4."""
    return 1.5 / sigma * math.sin(2.0 * psi / 3.0)


@kernel_only
def kes_bend_torque(psi, c0, c1, c2, sigma, x0):
    """Restoring torque (dyne·cm) of the proposed model at bend angle ψ (rad, 0 = straight):
    ``T = M̂(K(ψ))·σ·G``, eqs. (10)–(11)."""
    K = kes_curvature(psi, sigma)
    if K < 0.0:
        K = 0.0
    return kes_poly(K, c0, c1, c2, x0) * sigma * G


@kernel_only
def breen_curvature(theta, sigma):
    """Breen's K(θ) (1/cm) at interior angle θ = π − ψ (docs/physics.md, Breen's model, sign of the paper corrected)."""
    if theta > PI / 4.0:
        return 2.0 / sigma * math.cos(theta / 2.0)
    alpha_k = 2.0 / sigma * math.cos(PI / 8.0)
    beta = 1.0 / sigma * math.sin(PI / 8.0)
    return (PI / 4.0) ** 2 * beta / max(theta, 1e-12) + alpha_k - PI / 4.0 * beta


@kernel_only
def breen_bend_torque(psi, c0, c1, c2, sigma, x0):
    """Breen's restoring torque (dyne·cm), eq. (2): ``(Gσ/2)(M(K) + dM/dK)·sin(θ/2)``, θ = π − ψ."""
    theta = PI - psi
    K = breen_curvature(theta, sigma)
    M = kes_poly(K, c0, c1, c2, x0)
    dM = c0 * reg_root_deriv(K, x0) + c1 + 2.0 * c2 * K
    return 0.5 * G * sigma * (M + dM) * math.sin(theta / 2.0)


@kernel_only
def triple_law(length, width, sigma):
    """(ℓ, w) for a triple's torque law: its curvature is taken over ℓ = ``length``·σ (cm) and its
    torque scaled by w = ``width``/``length``, so that ``w·T(ψ; ℓ)`` is the torque of a strip σ·width
    wide turning ψ over ℓ (the laws' torque is the moment times the length they are given). A triple
    of length 0 (inside a clamp) has no law: ℓ = 0 is returned and the caller skips it."""
    if length <= 0.0:
        return 0.0, 0.0
    return sigma * length, width / length


@kernel_only
def eval_bending(x, triples, bend_dir, width, length, coef, sigma, x0, breen, f):
    """Bend triples (B, 3): ``f = −w·T(ψ)·∂ψ/∂x`` with T of the proposed model (10)–(11) or Breen's
    (2) and w the triple's width (the fabric it stands for, in σ: 1 inside, ½ on the outline);
    the curvature is ψ over the triple's ``length`` (in σ: 1, ½ at a clamp; :func:`triple_law`).

    ``∂ψ/∂x_a = (n × e1)/|e1|²``, ``∂ψ/∂x_c = (n × e2)/|e2|²``, ``∂ψ/∂x_b = −(sum)``,
    ``e1 = x_b − x_a``, ``e2 = x_c − x_b``, ``n = e1 × e2 / |e1 × e2|``.
    Triples with ``|e1 × e2|`` below round-off are skipped (T·∇ψ is undefined there).
    """
    for t in range(triples.shape[0]):
        ell, w = triple_law(length[t], width[t], sigma)
        if ell == 0.0:
            continue
        a = triples[t, 0]
        b = triples[t, 1]
        c = triples[t, 2]
        e10, e11, e12, e20, e21, e22, n0, n1, n2, s, l1, l2 = angle_geometry(x, a, b, c, True)
        if s <= 1e-12 * math.sqrt(l1 * l2):
            continue
        psi = math.atan2(s, e10 * e20 + e11 * e21 + e12 * e22)
        k = bend_dir[t]
        if breen:
            T = breen_bend_torque(psi, coef[k, 0], coef[k, 1], coef[k, 2], ell, x0)
        else:
            T = kes_bend_torque(psi, coef[k, 0], coef[k, 1], coef[k, 2], ell, x0)
        T *= w
        n0 /= s
        n1 /= s
        n2 /= s
        ga0, ga1, ga2 = _cross(n0, n1, n2, e10, e11, e12)
        gc0, gc1, gc2 = _cross(n0, n1, n2, e20, e21, e22)
        sa = T / l1
        sc = T / l2
        f[a, 0] -= sa * ga0
        f[a, 1] -= sa * ga1
        f[a, 2] -= sa * ga2
        f[c, 0] -= sc * gc0
        f[c, 1] -= sc * gc1
        f[c, 2] -= sc * gc2
        f[b, 0] += sa * ga0 + sc * gc0
        f[b, 1] += sa * ga1 + sc * gc1
        f[b, 2] += sa * ga2 + sc * gc2


@kernel_only
def bend_slope(psi, c0, c1, c2, sigma, x0, breen):
    h = 1e-6
    if breen:  # Breen's torque: by central differences
        t = breen_bend_torque(psi, c0, c1, c2, sigma, x0)
        tp = breen_bend_torque(min(psi + h, math.pi), c0, c1, c2, sigma, x0)
        tm = breen_bend_torque(max(psi - h, 0.0), c0, c1, c2, sigma, x0)
        tangent = (tp - tm) / (min(psi + h, math.pi) - max(psi - h, 0.0))
    else:  # T = M̂(K)·σ·G, K = 3/(2σ)·sin(2ψ/3): dT/dψ = G·M̂'(K)·cos(2ψ/3), analytically
        t = kes_bend_torque(psi, c0, c1, c2, sigma, x0)
        K = 1.5 / sigma * math.sin(2.0 * psi / 3.0)
        if K > 1e-9:
            tangent = G * (c0 * reg_root_deriv(K, x0) + c1 + 2.0 * c2 * K) * math.cos(2.0 * psi / 3.0)
        else:  # at the flat state: the one-sided slope T(h)/h (finite also without root regularisation)
            tangent = kes_bend_torque(h, c0, c1, c2, sigma, x0) / h
    secant = t / max(psi, 1e-2)
    return max(tangent, secant, 0.0)


@kernel_only
def _bend_rate_gradient(e10, e11, e12, e20, e21, e22, l1, l2, g):
    """``g`` (6,) ← (g_a, g_c): the gradient of ``|b|``, ``b = ê2 − ê1``, with respect to x_a and
    x_c (``g_b = −(g_a + g_c)``): ``g_a = J_a b̂``, ``g_c = J_c b̂`` (:func:`linearise_bending`'s
    J). Returns False where the triple is straight (``|b|`` below 1e-9: no direction to damp)."""
    u0, u1, u2 = e10 / l1, e11 / l1, e12 / l1
    w0, w1, w2 = e20 / l2, e21 / l2, e22 / l2
    b0, b1, b2 = w0 - u0, w1 - u1, w2 - u2
    nb = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    if nb < 1e-9:
        return False
    b0 /= nb
    b1 /= nb
    b2 /= nb
    ub = u0 * b0 + u1 * b1 + u2 * b2
    wb = w0 * b0 + w1 * b1 + w2 * b2
    g[0] = (b0 - ub * u0) / l1
    g[1] = (b1 - ub * u1) / l1
    g[2] = (b2 - ub * u2) / l1
    g[3] = (b0 - wb * w0) / l2
    g[4] = (b1 - wb * w1) / l2
    g[5] = (b2 - wb * w2) / l2
    return True


@kernel_only
def damp_bending(x, u, triples, bend_dir, width, length, coef, sigma, x0, breen, beta, f):
    """Add the strain-rate damping of the bending triples at positions ``x`` (cm) and velocities
    ``u`` (cm/s) to ``f`` (dyne): ``−β·k·(d|b|/dt)·∇|b|`` per triple, with ``|b| = |ê2 − ê1|`` its
    bend (≈ ψ) and k its stiffness (:func:`bend_slope` times its width). Rigid rotation leaves |b|
    unchanged and is not damped. The force is ``−C·u`` with C the damping matrix that
    :func:`linearise_bending` adds."""
    g = np.empty(6)
    for t in range(triples.shape[0]):
        ell, w = triple_law(length[t], width[t], sigma)
        if ell == 0.0:
            continue
        a = triples[t, 0]
        b = triples[t, 1]
        c = triples[t, 2]
        e10, e11, e12, e20, e21, e22, n0, n1, n2, s, l1, l2 = angle_geometry(x, a, b, c, True)
        l1 = math.sqrt(l1)
        l2 = math.sqrt(l2)
        if l1 < 1e-12 or l2 < 1e-12 or not _bend_rate_gradient(e10, e11, e12, e20, e21, e22, l1, l2, g):
            continue
        psi = math.atan2(s, e10 * e20 + e11 * e21 + e12 * e22)
        d = bend_dir[t]
        k = w * bend_slope(psi, coef[d, 0], coef[d, 1], coef[d, 2], ell, x0, breen)
        damp_three_particle_element(u, a, b, c, g, beta * k, f)


@kernel_only
def linearise_bending(x, triples, bend_dir, width, length, coef, sigma, x0, breen, damp, bmap, vals):
    """Add each triple's Gauss–Newton stiffness ``k·JᵀJ`` to the block matrix ``vals`` (nnz, 3, 3),
    dyne/cm: ``J = [J_a, −(J_a + J_c), J_c]`` is the Jacobian of ``b = ê2 − ê1`` (|b| ≈ ψ for small
    ψ; well defined at the flat state where ∇ψ is not), ``J_a = (I − ê1ê1ᵀ)/|e1|``, ``J_c`` likewise,
    and ``k = w·max(dT/dψ, T/ψ, 0)`` (:func:`bend_slope`, w and the law's length from the triple's
    width and length, :func:`triple_law`). Block (i, j) of the
    triple, at index ``bmap[t, 3i + j]`` of ``vals``, is ``k·J_i J_j``, from the three products
    ``J_aJ_a = (I − ê1ê1ᵀ)/|e1|²``, ``J_cJ_c = (I − ê2ê2ᵀ)/|e2|²`` and
    ``J_aJ_c = (I − ê1ê1ᵀ − ê2ê2ᵀ + (ê1·ê2)·ê1ê2ᵀ)/(|e1||e2|)`` (projectors). ``damp`` = β/h adds
    the strain-rate damping matrix over h, ``damp·k·(Jᵀb̂)(Jᵀb̂)ᵀ`` (:func:`damp_bending`)."""
    X = np.empty((3, 3))  # k J_a J_a
    Y = np.empty((3, 3))  # k J_c J_c
    Z = np.empty((3, 3))  # k J_a J_c (its transpose is k J_c J_a)
    g = np.zeros(6)
    for t in range(triples.shape[0]):
        ell, w = triple_law(length[t], width[t], sigma)
        if ell == 0.0:
            continue
        e10, e11, e12, e20, e21, e22, n0, n1, n2, s, l1, l2 = angle_geometry(x, triples[t, 0], triples[t, 1],
                                                                              triples[t, 2], True)
        l1 = math.sqrt(l1)
        l2 = math.sqrt(l2)
        if l1 < 1e-12 or l2 < 1e-12:
            continue
        psi = math.atan2(s, e10 * e20 + e11 * e21 + e12 * e22)
        d = bend_dir[t]
        k = w * bend_slope(psi, coef[d, 0], coef[d, 1], coef[d, 2], ell, x0, breen)
        if k == 0.0:
            continue
        kd = k * damp if damp > 0.0 and _bend_rate_gradient(e10, e11, e12, e20, e21, e22, l1, l2, g) else 0.0
        u = (e10 / l1, e11 / l1, e12 / l1)
        w = (e20 / l2, e21 / l2, e22 / l2)
        uw = u[0] * w[0] + u[1] * w[1] + u[2] * w[2]
        ka = k / (l1 * l1)
        kc = k / (l2 * l2)
        kz = k / (l1 * l2)
        for i in range(3):
            for j in range(3):
                dij = 1.0 if i == j else 0.0
                X[i, j] = ka * (dij - u[i] * u[j]) + kd * g[i] * g[j]
                Y[i, j] = kc * (dij - w[i] * w[j]) + kd * g[3 + i] * g[3 + j]
                Z[i, j] = kz * (dij - u[i] * u[j] - w[i] * w[j] + uw * u[i] * w[j]) + kd * g[i] * g[3 + j]
        add_corner_blocks(vals, bmap[t], X, Y, Z)
