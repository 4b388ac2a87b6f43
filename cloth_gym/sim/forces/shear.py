"""Shear: the torque at each lattice corner resisting the change of the angle between warp and
weft, from the mean measured shear curve (KES) or Breen's law.

One home for the force: the torque laws, the force on the particles, and the Gauss–Newton
stiffness blocks for the implicit solver (:func:`linearise_shear`). Units: cm, dyne·cm; shear
angle in radians (the KES curves take degrees).
"""

from __future__ import annotations

import math

import numpy as np

from ...units import DEG_PER_RAD, G
from .._numba import kernel_only
from .common import (PI, _cross, add_corner_blocks, angle_geometry, damp_three_particle_element, kes_poly,
                     reg_root_deriv)


@kernel_only
def kes_shear_torque(phi, c0, c1, c2, sigma, x0):
    """Shear torque magnitude (dyne·cm) of eq. (15) at shear angle φ (rad, signed):
    ``(G/4)·F̄(|φ|°)·cos φ·σ²``."""
    return _shear_torque(phi, math.cos(phi), c0, c1, c2, sigma, x0, False)


@kernel_only
def breen_shear_torque(phi, c0, c1, c2, sigma, x0):
    """Breen's shear torque magnitude (dyne·cm), eq. (3): ``(G/5)·σ³/4·F(|φ|°)·cos φ``."""
    return _shear_torque(phi, math.cos(phi), c0, c1, c2, sigma, x0, True)


@kernel_only
def _shear_torque(phi, cos_phi, c0, c1, c2, sigma, x0, breen):
    """:func:`kes_shear_torque` (or Breen's) given ``cos φ``, which the lattice loops take from the
    corner's geometry (``|a × c| / (|a||c|)``) rather than from φ."""
    F = kes_poly(abs(phi) * DEG_PER_RAD, c0, c1, c2, x0)
    if breen:
        return 0.2 * G * sigma ** 3 / 4.0 * F * cos_phi
    return 0.25 * G * F * cos_phi * sigma * sigma


@kernel_only
def eval_shear(x, corners, coef, sigma, x0, breen, f):
    """Shear corners (S, 3): ``f = −sign(φ)·T(φ)·∂γ/∂x``, φ = γ − π/2, T of (15) or Breen's (3).

    γ is the angle between ``a = x_a − x_b`` and ``c = x_c − x_b``;
    ``∂γ/∂x_a = −(n × a)/|a|²``, ``∂γ/∂x_c = (n × c)/|c|²``, ``∂γ/∂x_b = −(sum)``, n = a × c / |a × c|.
    """
    c0 = coef[0]
    c1 = coef[1]
    c2 = coef[2]
    for t in range(corners.shape[0]):
        ia = corners[t, 0]
        ib = corners[t, 1]
        ic = corners[t, 2]
        a0, a1, a2, b0, b1, b2, n0, n1, n2, s, la, lc = angle_geometry(x, ia, ib, ic, False)
        r = math.sqrt(la * lc)
        if s <= 1e-12 * r:
            continue
        gamma = math.atan2(s, a0 * b0 + a1 * b1 + a2 * b2)
        phi = gamma - 0.5 * PI
        if phi == 0.0:
            continue
        T = _shear_torque(phi, s / r, c0, c1, c2, sigma, x0, breen)  # cos φ = sin γ
        if phi < 0.0:
            T = -T
        n0 /= s
        n1 /= s
        n2 /= s
        ga0, ga1, ga2 = _cross(n0, n1, n2, a0, a1, a2)
        gc0, gc1, gc2 = _cross(n0, n1, n2, b0, b1, b2)
        # f = −T·∂γ/∂x:  f_a = +T (n×a)/|a|²,  f_c = −T (n×c)/|c|²,  f_b = −(f_a + f_c)
        sa = T / la
        sc = T / lc
        f[ia, 0] += sa * ga0
        f[ia, 1] += sa * ga1
        f[ia, 2] += sa * ga2
        f[ic, 0] -= sc * gc0
        f[ic, 1] -= sc * gc1
        f[ic, 2] -= sc * gc2
        f[ib, 0] += sc * gc0 - sa * ga0
        f[ib, 1] += sc * gc1 - sa * ga1
        f[ib, 2] += sc * gc2 - sa * ga2


@kernel_only
def shear_slope(phi, c0, c1, c2, sigma, x0, breen):
    """``max(dT/d|φ|, 0)`` (dyne·cm per radian) of the shear torque at shear angle φ (rad), analytic:
    T = C·F(|φ|·D)·cos φ (KES: C = Gσ²/4; Breen: C = Gσ³/20), D = 180/π. At |φ| < 1e-7, the
    one-sided slope T(1e-7)/1e-7 (finite also without the root's regularisation)."""
    a = max(abs(phi), 1e-7)
    return _shear_slope(phi, math.cos(a), math.sin(a), c0, c1, c2, sigma, x0, breen)


@kernel_only
def _shear_slope(phi, cos_a, sin_a, c0, c1, c2, sigma, x0, breen):
    """:func:`shear_slope` given the cosine and sine of ``a = max(|φ|, 1e-7)``, which the lattice
    loops take from the corner's geometry."""
    a = max(abs(phi), 1e-7)
    xd = a * DEG_PER_RAD
    F = kes_poly(xd, c0, c1, c2, x0)
    C = 0.05 * G * sigma ** 3 if breen else 0.25 * G * sigma * sigma
    if abs(phi) < 1e-7:
        return max(C * F * cos_a / a, 0.0)
    dF = c0 * reg_root_deriv(xd, x0) + c1 + 2.0 * c2 * xd
    return max(C * (dF * DEG_PER_RAD * cos_a - F * sin_a), 0.0)


@kernel_only
def _shear_gradient(x, ia, ib, ic, g):
    """``g`` (6,) ← (∂γ/∂x_a, ∂γ/∂x_c) of corner (a, b, c) (``∂γ/∂x_b = −(sum)``); returns the
    shear angle φ = γ − π/2 (rad), or NaN where the corner's edges are parallel, with ``cos φ``
    and ``|sin φ|`` from the geometry (``|a × c|/(|a||c|)``, ``|a·c|/(|a||c|)``)."""
    a0, a1, a2, b0, b1, b2, n0, n1, n2, s, la, lc = angle_geometry(x, ia, ib, ic, False)
    r = math.sqrt(la * lc)
    if s <= 1e-12 * r:
        return math.nan, 0.0, 0.0
    dot = a0 * b0 + a1 * b1 + a2 * b2
    phi = math.atan2(s, dot) - 0.5 * math.pi
    n0 /= s
    n1 /= s
    n2 /= s
    ga0, ga1, ga2 = _cross(n0, n1, n2, a0, a1, a2)
    gc0, gc1, gc2 = _cross(n0, n1, n2, b0, b1, b2)
    g[0] = -ga0 / la
    g[1] = -ga1 / la
    g[2] = -ga2 / la
    g[3] = gc0 / lc
    g[4] = gc1 / lc
    g[5] = gc2 / lc
    return phi, s / r, abs(dot) / r


@kernel_only
def damp_shear(x, u, corners, coef, sigma, x0, breen, beta, f):
    """Add the strain-rate damping of the shear corners at positions ``x`` (cm) and velocities
    ``u`` (cm/s) to ``f`` (dyne): ``−β·k·γ̇·∇γ`` per corner, γ̇ = ∇γ·u the rate of its angle and
    k its stiffness (:func:`shear_slope`). Rigid motion leaves γ unchanged. The force is ``−C·u``
    with C the damping matrix that :func:`linearise_shear` adds."""
    g = np.empty(6)
    for t in range(corners.shape[0]):
        a = corners[t, 0]
        b = corners[t, 1]
        c = corners[t, 2]
        phi, cos_a, sin_a = _shear_gradient(x, a, b, c, g)
        if math.isnan(phi):
            continue
        k = _shear_slope(phi, cos_a, sin_a, coef[0], coef[1], coef[2], sigma, x0, breen)
        damp_three_particle_element(u, a, b, c, g, beta * k, f)


@kernel_only
def linearise_shear(x, corners, coef, sigma, x0, breen, damp, cmap, vals):
    """Add each corner's Gauss–Newton stiffness ``k·∇γ∇γᵀ`` to the block matrix ``vals`` (nnz, 3, 3),
    dyne/cm: γ the corner's angle, ``k = max(dT/dφ, 0)`` (:func:`shear_slope`); block (i, j) of the
    corner (a, b, c), at index ``cmap[t, 3i + j]`` of ``vals``, is ``k·g_i g_jᵀ`` with ``g_i = ∂γ/∂x_i``.
    ``damp`` = β/h adds the strain-rate damping matrix over h, ``damp·k·g_i g_jᵀ`` (:func:`damp_shear`)."""
    g = np.zeros(6)  # ∂γ/∂x of a and c; b's is −(a's + c's)
    X = np.empty((3, 3))
    Y = np.empty((3, 3))
    Z = np.empty((3, 3))
    for t in range(corners.shape[0]):
        phi, cos_a, sin_a = _shear_gradient(x, corners[t, 0], corners[t, 1], corners[t, 2], g)
        if math.isnan(phi):
            continue
        k = _shear_slope(phi, cos_a, sin_a, coef[0], coef[1], coef[2], sigma, x0, breen) * (1.0 + damp)
        if k == 0.0:
            continue
        for i in range(3):  # k·g_i g_jᵀ from three outer products (g_b = −(g_a + g_c))
            for j in range(3):
                X[i, j] = k * g[i] * g[j]
                Y[i, j] = k * g[3 + i] * g[3 + j]
                Z[i, j] = k * g[i] * g[3 + j]
        add_corner_blocks(vals, cmap[t], X, Y, Z)
