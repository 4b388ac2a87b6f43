"""Force kernels (numba), one per force type: arrays in, force array out.

Each ``eval_*`` kernel *adds* its force (dyne) into ``f`` (N, 3). The scalar
laws (``*_tension``, ``*_torque``) are separate so tests can check them against
hand values and integrate them into energies. Formulas and sign conventions are
those of SPEC §4 (proposed KES model) and §5 (Breen's baseline).

Conventions: positions ``x`` in cm, velocities in cm/s, forces in dyne,
torques in dyne·cm (per radian of the angle they act on).
"""

from __future__ import annotations

import math

import numpy as np

from ..units import DEG_PER_RAD, G
from ._numba import njit
from .bundles import Force, ForceData

PI = math.pi
# the Force bits as plain ints, for the kernels
GRAVITY, STRETCH, BENDING, SHEAR, AIR, DAMPING, BREEN = (int(b) for b in Force)

# ============================================================================ scalar laws
@njit
def reg_root(x, x0):
    """Regularised square root ``x / sqrt(x + x0)`` (= sqrt(x) for x0 = 0), x ≥ 0."""
    if x0 > 0.0:
        return x / math.sqrt(x + x0)
    return math.sqrt(x)


@njit
def reg_root_deriv(x, x0):
    """d/dx of :func:`reg_root`."""
    if x0 > 0.0:
        r = math.sqrt(x + x0)
        return (x + 2.0 * x0) / (2.0 * r * r * r)
    return 0.5 / math.sqrt(x) if x > 0.0 else math.inf


@njit
def kes_poly(x, c0, c1, c2, x0):
    """``c0·x^½ + c1·x + c2·x²`` with the regularised root, x ≥ 0."""
    return c0 * reg_root(x, x0) + c1 * x + c2 * x * x


@njit
def kes_stretch_tension(eps, c1, c2, alpha, rest):
    """Pull (dyne, > 0 pulls the pair together) of a KES edge at strain ``eps`` (percent), eqs. (7)–(9).

    Tension: ``F̂(ε)·σ·G``; compression: ``−α·F̂(|ε|)·σ·G`` (pushes apart).
    """
    a = abs(eps)
    mag = (c1 * a + c2 * a * a) * rest * G
    if eps < 0.0:
        return -alpha * mag
    return mag


@njit
def breen_stretch_tension(r, rest, c0):
    """Pull (dyne, > 0 pulls together) of Breen's eq. (1) at length ``r`` (cm)."""
    d = r - rest
    if r > rest:
        return 5.0 * c0 * d ** 4 / rest ** 5
    return -c0 * (4.0 * r + rest) * d ** 4 / (rest * rest)


@njit
def kes_stretch_slope(eps, c1, c2, alpha):
    """d(pull)/dr (dyne/cm) of :func:`kes_stretch_tension`: ``100·G·(c1 + 2·c2·|ε|)``, × α in compression."""
    k = 100.0 * G * (c1 + 2.0 * c2 * abs(eps))
    return alpha * k if eps < 0.0 else k


@njit
def breen_stretch_slope(r, rest, c0):
    """d(pull)/dr (dyne/cm) of :func:`breen_stretch_tension`."""
    d = r - rest
    if r > rest:
        return 20.0 * c0 * d ** 3 / rest ** 5
    return -c0 * (4.0 * d ** 4 + 4.0 * (4.0 * r + rest) * d ** 3) / (rest * rest)


@njit
def kes_curvature(psi, sigma):
    """SPEC §4: ``K(ψ) = 3/(2σ)·sin(2ψ/3)`` (1/cm); ψ/σ for small ψ, peaks at ψ = 3π/4."""
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
    """Breen's K(θ) (1/cm) at interior angle θ = π − ψ (SPEC §5, sign of the paper corrected)."""
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
def kes_shear_torque(phi, c0, c1, c2, sigma, x0):
    """Shear torque magnitude (dyne·cm) of eq. (15) at shear angle φ (rad, signed):
    ``(G/4)·F̄(|φ|°)·cos φ·σ²``."""
    deg = abs(phi) * DEG_PER_RAD
    return 0.25 * G * kes_poly(deg, c0, c1, c2, x0) * math.cos(phi) * sigma * sigma


@njit
def breen_shear_torque(phi, c0, c1, c2, sigma, x0):
    """Breen's shear torque magnitude (dyne·cm), eq. (3): ``(G/5)·σ³/4·F(|φ|°)·cos φ``."""
    deg = abs(phi) * DEG_PER_RAD
    return 0.2 * G * sigma ** 3 / 4.0 * kes_poly(deg, c0, c1, c2, x0) * math.cos(phi)


# ============================================================================ small vector helpers
@njit
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit
def edge_vector(x, a, b):
    """(d0, d1, d2, r): ``x_b − x_a`` and its length, cm."""
    d0 = x[b, 0] - x[a, 0]
    d1 = x[b, 1] - x[a, 1]
    d2 = x[b, 2] - x[a, 2]
    return d0, d1, d2, math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


# ============================================================================ element kernels
@njit
def eval_stretch(x, edges, edge_dir, rest, coef, alpha, breen, breen_c0, f):
    """Stretch edges (E, 2): KES law per direction (``coef[dir] = (c1, c2)``), or Breen's (1)."""
    for e in range(edges.shape[0]):
        a = edges[e, 0]
        b = edges[e, 1]
        d0, d1, d2, r = edge_vector(x, a, b)
        if r < 1e-12:
            continue
        L = rest[e]
        if breen:
            pull = breen_stretch_tension(r, L, breen_c0)
        else:
            k = edge_dir[e]
            pull = kes_stretch_tension(100.0 * (r - L) / L, coef[k, 0], coef[k, 1], alpha, L)
        s = pull / r
        f[a, 0] += s * d0
        f[a, 1] += s * d1
        f[a, 2] += s * d2
        f[b, 0] -= s * d0
        f[b, 1] -= s * d1
        f[b, 2] -= s * d2


@njit
def angle_geometry(x, a, b, c, chain):
    """Vectors of the angle at particle b and their cross product.

    ``chain=True`` (bend triple a–b–c): ``u = x_b − x_a``, ``w = x_c − x_b`` (ψ = angle(u, w)).
    ``chain=False`` (shear corner): ``u = x_a − x_b``, ``w = x_c − x_b`` (γ = angle(u, w)).
    Returns (u0, u1, u2, w0, w1, w2, n0, n1, n2, |u × w|, |u|², |w|²), n = u × w (not normalised).
    """
    if chain:
        u0 = x[b, 0] - x[a, 0]
        u1 = x[b, 1] - x[a, 1]
        u2 = x[b, 2] - x[a, 2]
    else:
        u0 = x[a, 0] - x[b, 0]
        u1 = x[a, 1] - x[b, 1]
        u2 = x[a, 2] - x[b, 2]
    w0 = x[c, 0] - x[b, 0]
    w1 = x[c, 1] - x[b, 1]
    w2 = x[c, 2] - x[b, 2]
    n0, n1, n2 = _cross(u0, u1, u2, w0, w1, w2)
    s = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    return (u0, u1, u2, w0, w1, w2, n0, n1, n2, s, u0 * u0 + u1 * u1 + u2 * u2, w0 * w0 + w1 * w1 + w2 * w2)


@njit
def bend_angle(x, a, b, c):
    """Bend angle ψ ∈ [0, π] of triple (a, b, c) and |e1 × e2| (cm²)."""
    e10, e11, e12, e20, e21, e22, n0, n1, n2, s, l1, l2 = angle_geometry(x, a, b, c, True)
    return math.atan2(s, e10 * e20 + e11 * e21 + e12 * e22), s


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
        if s <= 1e-12 * math.sqrt(la * lc):
            continue
        gamma = math.atan2(s, a0 * b0 + a1 * b1 + a2 * b2)
        phi = gamma - 0.5 * PI
        if phi == 0.0:
            continue
        if breen:
            T = breen_shear_torque(phi, c0, c1, c2, sigma, x0)
        else:
            T = kes_shear_torque(phi, c0, c1, c2, sigma, x0)
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


@njit
def vertex_normals(x, tris, out):
    """Area-weighted unit vertex normals (N, 3) from triangles; zero for particles in no triangle."""
    out[:] = 0.0
    for t in range(tris.shape[0]):
        i = tris[t, 0]
        j = tris[t, 1]
        k = tris[t, 2]
        n0, n1, n2 = _cross(x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2],
                            x[k, 0] - x[i, 0], x[k, 1] - x[i, 1], x[k, 2] - x[i, 2])
        for p in (i, j, k):
            out[p, 0] += n0
            out[p, 1] += n1
            out[p, 2] += n2
    for p in range(out.shape[0]):
        s = math.sqrt(out[p, 0] ** 2 + out[p, 1] ** 2 + out[p, 2] ** 2)
        if s > 0.0:
            out[p, 0] /= s
            out[p, 1] /= s
            out[p, 2] /= s


@njit
def eval_air(x, v, tris, wind, c_air, sigma, normals, f):
    """Air drag, eq. (4) with the sign of SPEC §4: ``F = −C_air·σ²·|n·u|·u``, ``u = v − w``.

    ``normals`` (N, 3) is scratch space for the vertex normals.
    """
    vertex_normals(x, tris, normals)
    s2 = c_air * sigma * sigma
    for p in range(x.shape[0]):
        u0 = v[p, 0] - wind[0]
        u1 = v[p, 1] - wind[1]
        u2 = v[p, 2] - wind[2]
        un = abs(normals[p, 0] * u0 + normals[p, 1] * u1 + normals[p, 2] * u2)
        f[p, 0] -= s2 * un * u0
        f[p, 1] -= s2 * un * u1
        f[p, 2] -= s2 * un * u2


@njit
def eval_gravity_damping(v, mass, gravity, damping_rate, use_gravity, use_damping, f):
    """Gravity ``m·g`` and viscous damping ``−c·v`` with ``c = λ·m`` (λ = ``damping_rate``, 1/s)."""
    for p in range(v.shape[0]):
        m = mass[p]
        for k in range(3):
            acc = 0.0
            if use_gravity:
                acc += gravity[k]
            if use_damping:
                acc -= damping_rate * v[p, k]
            f[p, k] += m * acc


# ============================================================================ all forces
@njit
def eval_forces(x, v, wind, fd, normals, f):
    """Total force (5) on every particle into ``f`` (overwritten), dyne; ``fd`` a
    :class:`~cloth_gym.sim.bundles.ForceData`, ``wind`` (3,) cm/s, ``normals`` (N, 3) scratch."""
    f[:] = 0.0
    flags = fd.flags
    breen = (flags & BREEN) != 0
    eval_gravity_damping(v, fd.mass, fd.gravity, fd.damping_rate, (flags & GRAVITY) != 0, (flags & DAMPING) != 0, f)
    if flags & STRETCH:
        eval_stretch(x, fd.edges, fd.edge_dir, fd.rest, fd.stretch_coef, fd.alpha, breen, fd.breen_c0, f)
    if flags & BENDING:
        eval_bending(x, fd.triples, fd.bend_dir, fd.bend_coef, fd.sigma, fd.x0_curv, breen, f)
    if flags & SHEAR:
        eval_shear(x, fd.corners, fd.shear_coef, fd.sigma, fd.x0_shear, breen, f)
    if flags & AIR:
        eval_air(x, v, fd.tris, wind, fd.c_air, fd.sigma, normals, f)


def force_flags(options) -> int:
    """:class:`~cloth_gym.sim.bundles.Force` bits from :class:`~cloth_gym.sim.model.ForceOptions`."""
    bits = [(options.gravity, Force.GRAVITY), (options.stretch, Force.STRETCH), (options.bending, Force.BENDING),
            (options.shear, Force.SHEAR), (options.air, Force.AIR), (options.damping, Force.DAMPING),
            (options.model == "breen", Force.BREEN)]
    return sum(int(bit) for on, bit in bits if on)


def force_data(model) -> ForceData:
    """The model's :class:`~cloth_gym.sim.bundles.ForceData` (read it as ``model.force_data``: built once)."""
    m = model.material
    o = model.options
    return ForceData(
        flags=force_flags(o), mass=model.particle_mass, gravity=model.gravity, damping_rate=float(m.damping),
        alpha=float(m.compression_factor), c_air=float(m.air_drag), sigma=float(model.sigma),
        edges=model.edge_indices, edge_dir=model.edge_dir, rest=model.edge_rest_length,
        stretch_coef=model.stretch_coef, breen_c0=float(o.breen_c0), triples=model.bend_indices,
        bend_dir=model.bend_dir, bend_coef=model.bend_coef, x0_curv=float(o.sqrt_reg_curvature),
        corners=model.shear_indices, shear_coef=model.shear_coef, x0_shear=float(o.sqrt_reg_shear),
        tris=model.tri_indices)


def compute_forces(model, state, control=None, out: np.ndarray | None = None) -> np.ndarray:
    """Total force (dyne, (N, 3)) on each particle of ``state`` (pinned ones included)."""
    n = model.particle_count
    f = np.empty((n, 3)) if out is None else out
    wind = np.zeros(3) if control is None else np.asarray(control.wind, dtype=float)
    eval_forces(state.particle_q, state.particle_qd, wind, model.force_data, np.empty((n, 3)), f)
    return f
