"""Rigid obstacles with exact analytic distance tests (docs/physics.md, collision).

Shapes: :class:`Plane` (floor), :class:`Box` (table; axis-aligned),
:class:`Sphere`, :class:`Cylinder` (drape-test pedestal; axis along z). Each
has infinite mass and a Coulomb friction coefficient (``None``: the cloth
material's μ). Obstacles may translate: ``Control.obstacle_velocity`` (K, 3)
cm/s moves them, and ``State.obstacle_offset`` (K, 3) cm holds how far they
have moved from where the model put them (in the order of the model's analytic
obstacles). Contact then uses velocities relative to the obstacle.

Response, per particle after each (sub)step (:func:`collide_particles`):

* detection is continuous against the swept segment ``x_prev → x``: a particle
  that entered a shape during the step (even one that went through a thin box)
  is put back at its entry point; one that ends within the contact thickness
  of the surface is pushed out to the thickness along the surface normal;
* the normal velocity ``v_n < 0`` becomes ``−e·v_n`` (e: the material's
  restitution; below 1 cm/s, e = 0 so resting contact does not jitter);
* Coulomb friction on the tangential velocity: ``|Δv_t| ≤ μ·|Δv_n|``, where
  ``Δv_n`` includes the velocity that gravity and the cloth forces would push
  into the surface over the step (so a resting cloth feels its weight).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import ConfigError, ConfigTypeError
from ..validation import real, vector
from ._numba import kernel_only, njit_brief

__all__ = ["Plane", "Box", "Sphere", "Cylinder", "pack_obstacles", "collide_particles", "signed_distance",
           "moved_obstacles", "advance_obstacles", "resting_contacts", "keep_outside",
           "deepest_inside"]

PLANE, BOX, SPHERE, CYLINDER = 0, 1, 2, 3


def _vec(name, v, n=3):
    return vector(name, v, n, unit="cm")


def _positive(name, v):
    return real(name, v, 0.0, 1e7, lo_open=True, unit="cm")


def _mu(friction, name="friction"):
    if friction is None:
        return -1.0
    return real(name, friction, 0.0, 10.0, unit="(None: the material's)")


@dataclass(frozen=True)
class Plane:
    """Half-space ``n·(x − point) < 0`` is solid. ``normal`` need not be unit."""

    point: Sequence[float] = (0.0, 0.0, 0.0)
    normal: Sequence[float] = (0.0, 0.0, 1.0)
    friction: float | None = None

    def __post_init__(self):
        self.pack()  # checked when made, not when first simulated

    def pack(self):
        n = _vec("Plane.normal", self.normal)
        if not np.any(n):
            raise ConfigError("Plane.normal", f"must not be zero, got {self.normal!r}")
        n = n / np.max(np.abs(n))  # scaled first: the norm of a huge normal would overflow
        n = n / np.linalg.norm(n)
        return PLANE, np.concatenate([_vec("Plane.point", self.point), n, [0, 0, 0]]), _mu(self.friction, "Plane.friction")


@dataclass(frozen=True)
class Box:
    """Axis-aligned box: ``center`` (cm) and ``half_extents`` (cm). A table top is a flat box."""

    center: Sequence[float]
    half_extents: Sequence[float]
    friction: float | None = None

    def __post_init__(self):
        self.pack()

    def pack(self):
        he = _vec("Box.half_extents", self.half_extents)
        if np.any(he <= 0):
            raise ConfigError("Box.half_extents", f"must be > 0 cm, got {self.half_extents!r}")
        return BOX, np.concatenate([_vec("Box.center", self.center), he, [0, 0, 0]]), _mu(self.friction, "Box.friction")


@dataclass(frozen=True)
class Sphere:
    """Solid sphere: ``center`` and ``radius`` (cm)."""

    center: Sequence[float]
    radius: float
    friction: float | None = None

    def __post_init__(self):
        self.pack()

    def pack(self):
        return SPHERE, np.concatenate([_vec("Sphere.center", self.center),
                                       [_positive("Sphere.radius", self.radius)], np.zeros(5)]), \
            _mu(self.friction, "Sphere.friction")


@dataclass(frozen=True)
class Cylinder:
    """Solid cylinder with vertical axis: centre of its top face ``top_center``, ``radius``, ``height`` (cm)."""

    top_center: Sequence[float]
    radius: float
    height: float
    friction: float | None = None

    def __post_init__(self):
        self.pack()

    def pack(self):
        return CYLINDER, np.concatenate([_vec("Cylinder.top_center", self.top_center),
                                         [_positive("Cylinder.radius", self.radius),
                                          _positive("Cylinder.height", self.height)], np.zeros(4)]), \
            _mu(self.friction, "Cylinder.friction")


def pack_obstacles(obstacles, default_friction: float):
    """Arrays for the kernels: types (K,) int64, params (K, 9), friction (K,)."""
    from .collision import MeshObstacle

    types, params, mu = [], [], []
    for ob in obstacles:
        if isinstance(ob, MeshObstacle):  # handled by the collision pass
            continue
        if not isinstance(ob, (Plane, Box, Sphere, Cylinder)):
            raise ConfigTypeError("obstacles", f"expected Plane, Box, Sphere, Cylinder or MeshObstacle instances, "
                                  f"got {ob!r}")
        t, p, m = ob.pack()
        types.append(t)
        params.append(p)
        mu.append(default_friction if m < 0 else m)
    return (np.array(types, dtype=np.int64), np.array(params, dtype=float).reshape(-1, 9),
            np.array(mu, dtype=float))


@njit_brief
def moved_obstacles(params, offset):
    """A copy of the obstacle parameters with each obstacle's reference point (the first three
    entries: plane point, box/sphere centre, cylinder top centre) moved by ``offset`` (K, 3) cm."""
    prm = params.copy()
    for k in range(params.shape[0]):
        for i in range(3):
            prm[k, i] = params[k, i] + offset[k, i]
    return prm


@kernel_only
def any_moving(vel):
    """Does any obstacle move: a non-zero entry in ``vel`` (K, 3), cm/s?"""
    for k in range(vel.shape[0]):
        for i in range(3):
            if vel[k, i] != 0.0:
                return True
    return False


@kernel_only
def advance_obstacles(params, offset, vel, dt, prm):
    """Translate the obstacles by ``vel·dt``: ``offset`` (K, 3) cm and the moved ``prm`` in place."""
    for k in range(params.shape[0]):
        for i in range(3):
            offset[k, i] += vel[k, i] * dt
            prm[k, i] = params[k, i] + offset[k, i]


@kernel_only
def signed_distance(t, prm, x0, x1, x2):
    """(d, n0, n1, n2): signed distance (cm, < 0 inside) of a point to obstacle ``t`` and the outward normal."""
    if t == PLANE:
        d = (x0 - prm[0]) * prm[3] + (x1 - prm[1]) * prm[4] + (x2 - prm[2]) * prm[5]
        return d, prm[3], prm[4], prm[5]
    if t == SPHERE:
        r0 = x0 - prm[0]
        r1 = x1 - prm[1]
        r2 = x2 - prm[2]
        L = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        if L == 0.0:
            return -prm[3], 0.0, 0.0, 1.0
        return L - prm[3], r0 / L, r1 / L, r2 / L
    if t == BOX:
        q0 = abs(x0 - prm[0]) - prm[3]
        q1 = abs(x1 - prm[1]) - prm[4]
        q2 = abs(x2 - prm[2]) - prm[5]
        s0 = 1.0 if x0 >= prm[0] else -1.0
        s1 = 1.0 if x1 >= prm[1] else -1.0
        s2 = 1.0 if x2 >= prm[2] else -1.0
        if q0 <= 0.0 and q1 <= 0.0 and q2 <= 0.0:  # inside: nearest face
            if q0 >= q1 and q0 >= q2:
                return q0, s0, 0.0, 0.0
            if q1 >= q2:
                return q1, 0.0, s1, 0.0
            return q2, 0.0, 0.0, s2
        o0 = max(q0, 0.0) * s0
        o1 = max(q1, 0.0) * s1
        o2 = max(q2, 0.0) * s2
        L = math.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
        return L, o0 / L, o1 / L, o2 / L
    # CYLINDER, axis z, top face at prm[2], bottom at prm[2] - height
    r0 = x0 - prm[0]
    r1 = x1 - prm[1]
    rr = math.sqrt(r0 * r0 + r1 * r1)
    dr = rr - prm[3]
    mid = prm[2] - 0.5 * prm[4]
    dz = abs(x2 - mid) - 0.5 * prm[4]
    sz = 1.0 if x2 >= mid else -1.0
    u0 = r0 / rr if rr > 0 else 1.0
    u1 = r1 / rr if rr > 0 else 0.0
    if dr <= 0.0 and dz <= 0.0:
        if dr >= dz:
            return dr, u0, u1, 0.0
        return dz, 0.0, 0.0, sz
    a = max(dr, 0.0)
    b = max(dz, 0.0)
    L = math.sqrt(a * a + b * b)
    return L, u0 * a / L, u1 * a / L, sz * b / L


@kernel_only
def _distance_along(t, prm, p0, p1, p2, q0, q1, q2, s):
    """Signed distance (cm) to obstacle ``t`` of the point at fraction ``s`` of the segment p → q."""
    return signed_distance(t, prm, p0 + s * (q0 - p0), p1 + s * (q1 - p1), p2 + s * (q2 - p2))[0]


#: golden-section iterations of the tunnelling search in :func:`_tunnel_entry` (bracket shrinks 0.618 each)
_TUNNEL_ITERS = 60
#: samples along a step's path in :func:`_entry` (the path is cut into this many pieces)
_ENTRY_SAMPLES = 8
#: cm: :func:`_entry` skips the samples of a path whose Lipschitz bound clears the level by more than
#: this (far beyond round-off at cloth scales), so where it skips, sampling would have found nothing
_CLEAR_MARGIN = 1e-9


@kernel_only
def _secant_bound(has_a, fa0, fa1, has_b, fb1, fb2):
    """A lower bound of a convex function on one sampling interval [s_j, s_{j+1}] from the secants
    of its neighbours, extended over it: A through (s_{j−1}, ``fa0``), (s_j, ``fa1``) and B through
    (s_{j+1}, ``fb1``), (s_{j+2}, ``fb2``) (each where ``has_``); a line's least value on the interval
    is at one of its ends. −inf when neither exists."""
    lb = -math.inf
    if has_a:
        lb = max(lb, min(fa1, 2.0 * fa1 - fa0))
    if has_b:
        lb = max(lb, min(fb1, 2.0 * fb1 - fb2))
    return lb


@kernel_only
def _entry(t, prm, level, p0, p1, p2, q0, q1, q2):
    """Fraction s ∈ [0, 1] where the segment p → q first comes within ``level`` of the obstacle
    (signed distance ≤ level), or −1 if it never does or already starts there.

    Exact for every shape here, however thin and however long the step: each shape is convex, so
    its signed distance f(s) along a segment is a convex function of s, and the set where
    f ≤ level is one interval. The segment is sampled (8 pieces); a sample within ``level``
    brackets the first crossing. If none is, the segment can still pass through the shape between
    two samples (a step longer than the shape is thick) unless a bound rules it out: f is
    1-Lipschitz (``min f ≥ (f(0) + f(1) − |q − p|)/2``: every particle away from the obstacles), and
    convex, so its minimum lies next to the smallest sample, above the neighbouring secants
    extended (:func:`_secant_bound`: a particle sliding along a table, and every path near a plane,
    where the bound is exact). :func:`_tunnel_entry` searches what is left. The crossing is then
    bisected 40 times: exact to round-off. (The search is a call of its own: most paths never
    need it.) Most paths stay clear of a given obstacle by far, and the Lipschitz bound from the
    two ends alone says so before any sample is taken."""
    f0 = signed_distance(t, prm, p0, p1, p2)[0]
    if f0 <= level:
        return -1.0
    length = math.sqrt((q0 - p0) ** 2 + (q1 - p1) ** 2 + (q2 - p2) ** 2)
    if 0.5 * (f0 + signed_distance(t, prm, q0, q1, q2)[0] - length) > level + _CLEAR_MARGIN:
        return -1.0
    n = _ENTRY_SAMPLES
    prev = 0.0
    hit = -1.0
    # the smallest sample f_k and its neighbours f_{k−2}, f_{k−1}, f_{k+1}, f_{k+2}, kept as sampled
    k = 0
    fmin = f0
    fm2 = fm1 = fp1 = fp2 = f0
    last2 = last1 = f0
    fi = f0
    for i in range(1, n + 1):
        s = i / n
        fi = _distance_along(t, prm, p0, p1, p2, q0, q1, q2, s)
        if fi <= level:
            hit = s
            break
        prev = s
        if fi < fmin:
            k = i
            fmin = fi
            fm1 = last1
            fm2 = last2
        elif i == k + 1:
            fp1 = fi
        elif i == k + 2:
            fp2 = fi
        last2 = last1
        last1 = fi
    if hit < 0.0:
        if 0.5 * (f0 + fi - length) > level:
            return -1.0
        bound = math.inf
        if k >= 1:  # [s_{k−1}, s_k]
            bound = min(bound, _secant_bound(k >= 2, fm2, fm1, k + 1 <= n, fmin, fp1))
        if k <= n - 1:  # [s_k, s_{k+1}]
            bound = min(bound, _secant_bound(k >= 1, fm1, fmin, k + 2 <= n, fp1, fp2))
        if bound > level:
            return -1.0
        prev, hit = _tunnel_entry(t, prm, level, p0, p1, p2, q0, q1, q2, length)
        if hit < 0.0:
            return -1.0
    lo = prev
    hi = hit
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if _distance_along(t, prm, p0, p1, p2, q0, q1, q2, mid) > level:
            lo = mid
        else:
            hi = mid
    return lo


@kernel_only
def _tunnel_entry(t, prm, level, p0, p1, p2, q0, q1, q2, length):
    """(a, s) for a segment of ``length`` cm whose samples in :func:`_entry` all lie outside
    ``level`` and whose bounds did not rule a crossing out: a point s within ``level`` and a point a
    before it with everything up to a outside (the bracket of the first crossing), or (0, −1) when
    the segment never comes within ``level``. A golden-section search for the minimum of the convex
    distance, stopped as soon as the Lipschitz bound over its bracket puts the level out of reach."""
    golden = 0.5 * (math.sqrt(5.0) - 1.0)
    a = 0.0
    b = 1.0
    c = b - golden * (b - a)
    d = a + golden * (b - a)
    fc = _distance_along(t, prm, p0, p1, p2, q0, q1, q2, c)
    fd = _distance_along(t, prm, p0, p1, p2, q0, q1, q2, d)
    for _ in range(_TUNNEL_ITERS):
        if fc <= level or fd <= level:
            break
        if max(fc, fd) - (b - a) * length > level:  # no point of [a, b] comes within level
            break
        if fc < fd:
            b = d
            d = c
            fd = fc
            c = b - golden * (b - a)
            fc = _distance_along(t, prm, p0, p1, p2, q0, q1, q2, c)
        else:
            a = c
            c = d
            fc = fd
            d = a + golden * (b - a)
            fd = _distance_along(t, prm, p0, p1, p2, q0, q1, q2, d)
    if fc <= level:
        return a, c  # f > level on [0, a]: the first crossing lies in (a, c]
    if fd <= level:
        return a, d
    return 0.0, -1.0


@kernel_only
def collide_particles(x, v, x_prev, inv_mass, types, params, friction, restitution, thickness, out_contacts,
                      ob_vel, dt):
    """Resolve particle–obstacle contact in place (module docstring). Returns the number of contacts.

    ``params`` are the obstacles at the end of the step; an obstacle translating with velocity
    ``ob_vel[k]`` (cm/s) was ``ob_vel[k]·dt`` behind at its start, so detection uses the
    particle's motion relative to it and the response acts on the relative velocity.
    ``out_contacts`` (N,) int: index of the obstacle each particle touches, or −1."""
    count = 0
    for p in range(x.shape[0]):
        out_contacts[p] = -1
        if inv_mass[p] == 0.0:
            continue
        for k in range(types.shape[0]):
            t = types[k]
            prm = params[k]
            w0 = ob_vel[k, 0]
            w1 = ob_vel[k, 1]
            w2 = ob_vel[k, 2]
            # start of the step in the obstacle's frame (it moved by w·dt during the step)
            b0 = x_prev[p, 0] + w0 * dt
            b1 = x_prev[p, 1] + w1 * dt
            b2 = x_prev[p, 2] + w2 * dt
            # first point of the step's path within the contact thickness (continuous detection:
            # catches thin shapes crossed in one step, and picks the face the particle came through)
            s = _entry(t, prm, thickness, b0, b1, b2, x[p, 0], x[p, 1], x[p, 2])
            if s >= 0.0:
                # stop at the entry point, keep the rest of the step's motion tangential to the surface
                r0 = (1.0 - s) * (x[p, 0] - b0)
                r1 = (1.0 - s) * (x[p, 1] - b1)
                r2 = (1.0 - s) * (x[p, 2] - b2)
                e0 = b0 + s * (x[p, 0] - b0)
                e1 = b1 + s * (x[p, 1] - b1)
                e2 = b2 + s * (x[p, 2] - b2)
                d, n0, n1, n2 = signed_distance(t, prm, e0, e1, e2)
                rn = r0 * n0 + r1 * n1 + r2 * n2
                if rn > 0.0:
                    rn = 0.0
                x[p, 0] = e0 + r0 - rn * n0
                x[p, 1] = e1 + r1 - rn * n1
                x[p, 2] = e2 + r2 - rn * n2
            d, n0, n1, n2 = signed_distance(t, prm, x[p, 0], x[p, 1], x[p, 2])
            if s < 0.0 and d > 1.01 * thickness + 1e-9:  # a particle resting at the thickness still touches
                continue
            # push out to the contact thickness (a particle that was already in contact)
            push = max(thickness - d, 0.0)
            x[p, 0] += push * n0
            x[p, 1] += push * n1
            x[p, 2] += push * n2
            u0 = v[p, 0] - w0  # velocity relative to the obstacle
            u1 = v[p, 1] - w1
            u2 = v[p, 2] - w2
            vn = u0 * n0 + u1 * n1 + u2 * n2
            if vn < 0.0:
                e = restitution if -vn > 1.0 else 0.0
                dvn = -(1.0 + e) * vn
                t0 = u0 - vn * n0
                t1 = u1 - vn * n1
                t2 = u2 - vn * n2
                vt = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
                mu = friction[k]
                scale = 0.0
                if vt > 0.0:
                    scale = max(0.0, 1.0 - mu * dvn / vt)
                v[p, 0] = w0 + t0 * scale - e * vn * n0
                v[p, 1] = w1 + t1 * scale - e * vn * n1
                v[p, 2] = w2 + t2 * scale - e * vn * n2
            out_contacts[p] = k
            count += 1
    return count


@kernel_only
def keep_outside(x, v, inv_mass, types, params, ob_vel, out_contacts):
    """Put back every free particle that ended inside an obstacle (signed distance < 0) after the
    passes that follow :func:`collide_particles` (the strain limiter and the collision pass move
    particles without looking at the obstacles): onto the surface along the outward normal, its
    velocity into the surface (relative to the obstacle, ``ob_vel`` cm/s) removed, and
    ``out_contacts[p]`` set to the obstacle; the next step's contact pass lifts it to the contact
    thickness. The obstacles have the last word: a particle squeezed between a layer of cloth and
    the floor stays above the floor. The move is the least that does it: lifting it to the contact
    thickness at once can put it through the cloth lying on it (measured on RibbonDrop's ribbon
    dragged over the floor in a pile, which then tangled and stretched past 1,000 %). Returns the
    number put back."""
    count = 0
    for p in range(x.shape[0]):
        if inv_mass[p] == 0.0:
            continue
        for k in range(types.shape[0]):
            d, n0, n1, n2 = signed_distance(types[k], params[k], x[p, 0], x[p, 1], x[p, 2])
            if d >= 0.0:
                continue
            x[p, 0] -= d * n0
            x[p, 1] -= d * n1
            x[p, 2] -= d * n2
            vn = (v[p, 0] - ob_vel[k, 0]) * n0 + (v[p, 1] - ob_vel[k, 1]) * n1 + (v[p, 2] - ob_vel[k, 2]) * n2
            if vn < 0.0:
                v[p, 0] -= vn * n0
                v[p, 1] -= vn * n1
                v[p, 2] -= vn * n2
            out_contacts[p] = k
            count += 1
    return count


@njit_brief
def deepest_inside(x, inv_mass, types, params):
    """(particle, obstacle, depth cm) of the free particle deepest inside an obstacle (signed
    distance < 0), or (−1, −1, 0.0) when none is inside."""
    best_p = -1
    best_k = -1
    depth = 0.0
    for p in range(x.shape[0]):
        if inv_mass[p] == 0.0:
            continue
        for k in range(types.shape[0]):
            d = signed_distance(types[k], params[k], x[p, 0], x[p, 1], x[p, 2])[0]
            if -d > depth:
                best_p = p
                best_k = k
                depth = -d
    return best_p, best_k, depth


@njit_brief
def resting_contacts(x, types, params, thickness, out_contacts):
    """``out_contacts[p]``: the obstacle particle p rests on (within 1.01 × ``thickness`` cm of its
    surface, as :func:`collide_particles` counts a particle resting at the thickness), else −1.

    The implicit integrator starts a run with no contact record from a previous step; this gives it
    the one the state implies, so a cloth laid on a table is held by the contact constraint from
    its first step instead of falling ``g·h²`` into the table and bouncing off it (at h = 50 ms:
    49 cm/s into the surface, then the material's restitution)."""
    for p in range(x.shape[0]):
        out_contacts[p] = -1
        for k in range(types.shape[0]):
            d, n0, n1, n2 = signed_distance(types[k], params[k], x[p, 0], x[p, 1], x[p, 2])
            if d <= 1.01 * thickness + 1e-9:
                out_contacts[p] = k
                break
