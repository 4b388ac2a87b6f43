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
from .._numba import njit
from .common import PI, _cross, add_corner_blocks, angle_geometry, kes_poly, reg_root_deriv


@njit
def kes_curvature(psi, sigma):
    """docs/physics.md, forces: ``K(ψ) = 3/(2σ)·sin(2ψ/3)`` (1/cm); ψ/σ for small ψ, peaks at ψ = 3π/4."""
    return 1.5 / sigma * math.sin(2.0 * psi / 3.0)


@njit
def kes_bend_torque(psi, c0, c1, c2, sigma, x0):
    """Restoring torque (dyne·cm) of the proposed model at bend angle ψ (rad, 0 = straight):
    ``T = M̂(K(ψ))·σ·G``, eqs. (10)–(11)."""
    K = kes_curvature(psi, sigma)
    if K < 0.0:
        K = 0.0
    return kes_poly(K, c0, c1, c2, x0) * sigma * G


@njit
def breen_curvature(theta, sigma):
    """Breen's K(θ) (1/cm) at interior angle θ = π − ψ (docs/physics.md, Breen's model, sign of the paper corrected)."""
    if theta > PI / 4.0:
        return 2.0 / sigma * math.cos(theta / 2.0)
    alpha_k = 2.0 / sigma * math.cos(PI / 8.0)
    beta = 1.0 / sigma * math.sin(PI / 8.0)
    return (PI / 4.0) ** 2 * beta / max(theta, 1e-12) + alpha_k - PI / 4.0 * beta


@njit
def breen_bend_torque(psi, c0, c1, c2, sigma, x0):
    """Breen's restoring torque (dyne·cm), eq. (2): ``(Gσ/2)(M(K) + dM/dK)·sin(θ/2)``, θ = π − ψ."""
    theta = PI - psi
    K = breen_curvature(theta, sigma)
    M = kes_poly(K, c0, c1, c2, x0)
    dM = c0 * reg_root_deriv(K, x0) + c1 + 2.0 * c2 * K
    return 0.5 * G * sigma * (M + dM) * math.sin(theta / 2.0)


@njit
def eval_bending(x, triples, bend_dir, coef, sigma, x0, breen, f):
    """Bend triples (B, 3): ``f = −T(ψ)·∂ψ/∂x`` with T of the proposed model (10)–(11) or Breen's (2).

    ``∂ψ/∂x_a = (n × e1)/|e1|²``, ``∂ψ/∂x_c = (n × e2)/|e2|²``, ``∂ψ/∂x_b = −(sum)``,
    ``e1 = x_b − x_a``, ``e2 = x_c − x_b``, ``n = e1 × e2 / |e1 × e2|``.
    Triples with ``|e1 × e2|`` below round-off are skipped (T·∇ψ is undefined there).
    """
    for t in range(triples.shape[0]):
        a = triples[t, 0]
        b = triples[t, 1]
        c = triples[t, 2]
        e10, e11, e12, e20, e21, e22, n0, n1, n2, s, l1, l2 = angle_geometry(x, a, b, c, True)
        if s <= 1e-12 * math.sqrt(l1 * l2):
            continue
        psi = math.atan2(s, e10 * e20 + e11 * e21 + e12 * e22)
        k = bend_dir[t]
        if breen:
            T = breen_bend_torque(psi, coef[k, 0], coef[k, 1], coef[k, 2], sigma, x0)
        else:
            T = kes_bend_torque(psi, coef[k, 0], coef[k, 1], coef[k, 2], sigma, x0)
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


@njit
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


@njit
def linearise_bending(x, triples, bend_dir, coef, sigma, x0, breen, bmap, vals):
    """Add each triple's Gauss–Newton stiffness ``k·JᵀJ`` to the block matrix ``vals`` (nnz, 3, 3),
    dyne/cm: ``J = [J_a, −(J_a + J_c), J_c]`` is the Jacobian of ``b = ê2 − ê1`` (|b| ≈ ψ for small
    ψ; well defined at the flat state where ∇ψ is not), ``J_a = (I − ê1ê1ᵀ)/|e1|``, ``J_c`` likewise,
    and ``k = max(dT/dψ, T/ψ, 0)`` (:func:`bend_slope`). Block (i, j) of the triple, at index
    ``bmap[t, 3i + j]`` of ``vals``, is ``k·J_i J_j``, from the three products
    ``J_aJ_a = (I − ê1ê1ᵀ)/|e1|²``, ``J_cJ_c = (I − ê2ê2ᵀ)/|e2|²`` and
    ``J_aJ_c = (I − ê1ê1ᵀ − ê2ê2ᵀ + (ê1·ê2)·ê1ê2ᵀ)/(|e1||e2|)`` (projectors)."""
    X = np.empty((3, 3))  # k J_a J_a
    Y = np.empty((3, 3))  # k J_c J_c
    Z = np.empty((3, 3))  # k J_a J_c (its transpose is k J_c J_a)
    for t in range(triples.shape[0]):
        e10, e11, e12, e20, e21, e22, n0, n1, n2, s, l1, l2 = angle_geometry(x, triples[t, 0], triples[t, 1],
                                                                              triples[t, 2], True)
        l1 = math.sqrt(l1)
        l2 = math.sqrt(l2)
        if l1 < 1e-12 or l2 < 1e-12:
            continue
        psi = math.atan2(s, e10 * e20 + e11 * e21 + e12 * e22)
        d = bend_dir[t]
        k = bend_slope(psi, coef[d, 0], coef[d, 1], coef[d, 2], sigma, x0, breen)
        if k == 0.0:
            continue
        u = (e10 / l1, e11 / l1, e12 / l1)
        w = (e20 / l2, e21 / l2, e22 / l2)
        uw = u[0] * w[0] + u[1] * w[1] + u[2] * w[2]
        ka = k / (l1 * l1)
        kc = k / (l2 * l2)
        kz = k / (l1 * l2)
        for i in range(3):
            for j in range(3):
                dij = 1.0 if i == j else 0.0
                X[i, j] = ka * (dij - u[i] * u[j])
                Y[i, j] = kc * (dij - w[i] * w[j])
                Z[i, j] = kz * (dij - u[i] * u[j] - w[i] * w[j] + uw * u[i] * w[j])
        add_corner_blocks(vals, bmap[t], X, Y, Z)
