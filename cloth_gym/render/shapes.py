"""Triangle meshes of the obstacle shapes, for drawing: ``(vertices (V, 3) cm, faces (F, 3) int64)``.

Only for display: a sphere is an icosphere and a cylinder a prism, so their
silhouettes differ from the analytic shapes the simulator collides with by
less than ``radius·(1 − cos(π/segments))``.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ..sim.obstacles import Box, Cylinder, Plane, Sphere

__all__ = ["plane_mesh", "box_mesh", "icosphere", "sphere_mesh", "cylinder_mesh", "obstacle_mesh"]

PLANE_SIDE_CM = 200.0


def _basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane normal to unit ``n``."""
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(n, a)
    t1 /= np.linalg.norm(t1)
    return t1, np.cross(n, t1)


def plane_mesh(point, normal, side_cm: float = PLANE_SIDE_CM):
    """A square of side ``side_cm`` (cm) centred at ``point`` (cm), normal to ``normal``: 4 vertices, 2 faces."""
    p = np.asarray(point, dtype=float)
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    t1, t2 = _basis(n)
    h = 0.5 * side_cm
    v = np.array([p + h * (s1 * t1 + s2 * t2) for s1, s2 in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    return v, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


def box_mesh(center, half_extents):
    """Axis-aligned box (cm): 8 vertices, 12 faces wound outwards."""
    c = np.asarray(center, dtype=float)
    h = np.asarray(half_extents, dtype=float)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    v = c + corners * h
    # vertex index = 4·(x>0) + 2·(y>0) + (z>0)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = [t for a, b, c_, d in quads for t in ((a, b, c_), (a, c_, d))]
    return v, np.array(f, dtype=np.int64)


def _midpoint(verts: list, mid: dict, a: int, b: int) -> int:
    """Index of the unit-sphere midpoint of edge (a, b), appended to ``verts`` the first time."""
    key = (min(a, b), max(a, b))
    if key not in mid:
        m = verts[a] + verts[b]
        verts.append(m / np.linalg.norm(m))
        mid[key] = len(verts) - 1
    return mid[key]


@functools.lru_cache(maxsize=8)
def icosphere(subdivisions: int = 2):
    """Unit icosphere: an icosahedron with each face split in 4, ``subdivisions`` times
    (2 → 162 vertices, 320 faces). Returned arrays are read-only; copy before editing."""
    t = (1.0 + math.sqrt(5.0)) / 2.0
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    verts = [np.array(p, dtype=float) / np.linalg.norm(p) for p in v]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5),
             (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(subdivisions):
        mid: dict = {}
        new = []
        for a, b, c in faces:
            ab, bc, ca = (_midpoint(verts, mid, a, b), _midpoint(verts, mid, b, c), _midpoint(verts, mid, c, a))
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    V = np.array(verts)
    F = np.array(faces, dtype=np.int64)
    V.flags.writeable = False
    F.flags.writeable = False
    return V, F


def sphere_mesh(center, radius: float, subdivisions: int = 2):
    """Icosphere of ``radius`` (cm) at ``center`` (cm)."""
    v, f = icosphere(subdivisions)
    return np.asarray(center, dtype=float) + radius * v, f.copy()


def cylinder_mesh(top_center, radius: float, height: float, segments: int = 32):
    """Vertical prism of ``segments`` sides approximating a cylinder (cm), with both caps."""
    c = np.asarray(top_center, dtype=float)
    a = 2.0 * np.pi * np.arange(segments) / segments
    ring = np.stack([radius * np.cos(a), radius * np.sin(a), np.zeros(segments)], axis=1)
    top = c + ring
    bot = c + ring - np.array([0.0, 0.0, height])
    v = np.concatenate([top, bot, [c, c - np.array([0.0, 0.0, height])]])
    ct, cb = 2 * segments, 2 * segments + 1
    f = []
    for k in range(segments):
        k2 = (k + 1) % segments
        f += [(k, segments + k, segments + k2), (k, segments + k2, k2), (ct, k, k2), (cb, segments + k2, segments + k)]
    return v, np.array(f, dtype=np.int64)


def obstacle_mesh(ob):
    """(vertices, faces) of an obstacle, or ``None`` for a type it cannot draw.

    Plane → a square of side :data:`PLANE_SIDE_CM` around its point; Box, Sphere,
    Cylinder → the meshes above; any object with ``vertices`` and ``faces``
    attributes (a triangle-mesh obstacle) → those arrays."""
    if hasattr(ob, "vertices") and hasattr(ob, "faces"):
        return np.asarray(ob.vertices, dtype=float), np.asarray(ob.faces, dtype=np.int64)
    if isinstance(ob, Plane):
        return plane_mesh(ob.point, ob.normal)
    if isinstance(ob, Box):
        return box_mesh(ob.center, ob.half_extents)
    if isinstance(ob, Sphere):
        return sphere_mesh(ob.center, ob.radius)
    if isinstance(ob, Cylinder):
        return cylinder_mesh(ob.top_center, ob.radius, ob.height)
    return None
