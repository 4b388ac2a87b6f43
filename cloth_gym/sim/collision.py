"""Collision and repulsion (docs/physics.md, collision; the paper's §4): options, mesh obstacles, packing.

A scene turns on only what it needs, and pays nothing for the rest:

* analytic obstacles (:mod:`cloth_gym.sim.obstacles`: plane, box, sphere,
  cylinder) — exact distance tests, always on when the model has them;
* triangle-mesh obstacles (:class:`MeshObstacle`, any mesh trimesh loads) —
  continuous vertex–triangle detection with the paper's signed volumes and a
  static grid broad phase, on when the model has one;
* self-collision (``CollisionOptions(self_collision=True)``) — continuous
  vertex–triangle and edge–edge detection with a spatial hash rebuilt every
  step, and the rigid-triangle response (docs/physics.md, collision).

The response to a vertex p striking a cloth triangle B treats B as a rigid body
for the instant of impact (paper §4.2–4.4): ``Δv_p = J/m_p``,
``Δv_i = −J/M + (I⁻¹(r_p × (−J))) × r_i``, which conserves linear and angular
momentum. ``response="paper"`` takes the impulse magnitude of eq. (22),
``j = −(1+e)·v_rel⁻/(1/m_p + 1/M)``; ``"exact"`` adds Baraff's rotational term
``n·((I⁻¹(r_p × n)) × r_p)`` to the denominator so that ``v_rel⁺ = −e·v_rel⁻``
holds exactly. ``angular_momentum=False`` gives every particle of B the same
``−J/M`` (the paper's fig. 13 comparison). Edge–edge contacts (not in the
paper; needed for watertight self-contact) use the linear-weight impulse of
Bridson et al. 2002. After the impulse a position correction with the same
distribution keeps the contact ``thickness`` (positions only: no velocity is
added by it).

The kernels are in :mod:`cloth_gym.sim.collision_kernels`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ..errors import ConfigError, ConfigTypeError
from ..validation import flag, integer, is_file, one_of, real
from . import collision_kernels as ck
from .bundles import CollisionData, NoCollisionPass

__all__ = ["CollisionOptions", "MeshObstacle", "collision_args", "triangle_edges"]


@dataclass(frozen=True)
class CollisionOptions:
    """What the collision pass does beyond the obstacles (validated on construction).

    self_collision: cloth–cloth contact (vertex–triangle, and edge–edge when
        ``edge_edge``). Off by default: a scene that cannot fold onto itself
        does not pay for it.
    edge_edge: also test edge pairs (needed for watertight self-contact).
    response: ``"exact"`` (Baraff's magnitude, ``v_rel⁺ = −e·v_rel⁻``) or
        ``"paper"`` (eq. 22).
    angular_momentum: rigid-triangle rotation in the response (the paper's
        model); False: translation only (the paper's fig. 13 comparison).
    thickness: cloth–cloth separation kept, cm; ``None``: the model's
        ``contact_thickness``.
    self_friction: Coulomb μ between cloth layers; ``None``: the material's.
    iterations: sweeps over the contact pairs per step (1–50).
    """

    self_collision: bool = False
    edge_edge: bool = True
    response: Literal["exact", "paper"] = "exact"
    angular_momentum: bool = True
    thickness: float | None = None
    self_friction: float | None = None
    iterations: int = 4

    def __post_init__(self):
        for name in ("self_collision", "edge_edge", "angular_momentum"):
            flag(f"collision.{name}", getattr(self, name))
        one_of("collision.response", self.response, ("exact", "paper"))
        if self.thickness is not None:
            real("collision.thickness", self.thickness, 0.0, 10.0, lo_open=True, unit="cm (None: the model's)")
        if self.self_friction is not None:
            real("collision.self_friction", self.self_friction, 0.0, 10.0, unit="(None: the material's)")
        integer("collision.iterations", self.iterations, 1, 50)

    @classmethod
    def from_dict(cls, d: dict) -> "CollisionOptions":
        if not isinstance(d, dict):
            raise ConfigTypeError("collision", f"expected CollisionOptions or a dict of its fields, got {d!r}")
        known = set(cls.__dataclass_fields__)
        unknown = sorted(map(str, set(d) - known))
        if unknown:
            raise ConfigError("collision", f"unknown keys {sorted(unknown)}; allowed: {sorted(known)}")
        return cls(**d)


@dataclass(frozen=True, eq=False)
class MeshObstacle:
    """A static rigid obstacle given as a closed triangle mesh (cm).

    ``mesh``: a ``trimesh.Trimesh`` (e.g. ``trimesh.creation.icosphere``) or a
    path trimesh can load (OBJ, STL, PLY, ...). ``transform``: optional 4×4
    homogeneous matrix applied to it. Face normals are made to point outward
    (trimesh's ``fix_normals``); the inside is solid. ``friction``: Coulomb μ,
    ``None`` for the cloth material's. ``cell_size``: broad-phase grid cell, cm
    (``None``: the mean edge length, at least 1 cm).
    """

    mesh: object
    friction: float | None = None
    transform: object = None
    cell_size: float | None = None
    vertices: np.ndarray = field(init=False, repr=False)
    faces: np.ndarray = field(init=False, repr=False)
    face_normals: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        import trimesh

        m = self.mesh
        if isinstance(m, (str, Path)):
            if not is_file(m):
                raise ConfigError("MeshObstacle.mesh", f"file not found: {str(m)[:200]}")
            try:
                m = trimesh.load(str(m), force="mesh")
            except Exception as err:  # trimesh raises many types for a file it cannot read
                raise ConfigError("MeshObstacle.mesh", f"trimesh cannot read {self.mesh}: {err}") from None
        if not isinstance(m, trimesh.Trimesh):
            raise ConfigTypeError("MeshObstacle.mesh", f"expected a trimesh.Trimesh or a mesh file path, got "
                                  f"{type(m).__name__}")
        m = m.copy()
        if self.transform is not None:
            try:
                T = np.asarray(self.transform, dtype=float)
            except (TypeError, ValueError):
                raise ConfigTypeError("MeshObstacle.transform", f"must be a finite 4x4 matrix, got "
                                      f"{self.transform!r}") from None
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise ConfigError("MeshObstacle.transform", f"must be a finite 4x4 matrix, got {self.transform!r}")
            m.apply_transform(T)
        m.remove_unreferenced_vertices()
        if len(m.faces) == 0:
            raise ConfigError("MeshObstacle.mesh", "has no faces")
        if not np.all(np.isfinite(m.vertices)):
            raise ConfigError("MeshObstacle.mesh", "has non-finite vertices")
        area = np.asarray(m.area_faces)
        if np.any(area <= 1e-12 * max(float(area.max()), 1e-300)):
            raise ConfigError("MeshObstacle.mesh", f"has {int(np.sum(area <= 1e-12 * max(float(area.max()), 1e-300)))} "
                              "degenerate (zero-area) faces, whose normals are undefined: "
                              "repair it (trimesh: mesh.update_faces(mesh.nondegenerate_faces()))")
        if not m.is_watertight:
            raise ConfigError("MeshObstacle.mesh", "is not closed (watertight): an obstacle is solid and an open "
                              "mesh has no inside; close it (trimesh: mesh.fill_holes()) or model a thin sheet as "
                              "a box")
        trimesh.repair.fix_normals(m)
        if m.is_volume and m.volume < 0:
            m.invert()
        if self.friction is not None:
            real("MeshObstacle.friction", self.friction, 0.0, 10.0, unit="(None: the material's)")
        if self.cell_size is not None:
            real("MeshObstacle.cell_size", self.cell_size, 0.0, 1e7, lo_open=True, unit="cm (None: automatic)")
        object.__setattr__(self, "mesh", m)
        for name, arr in (("vertices", np.asarray(m.vertices, dtype=float)),
                          ("faces", np.asarray(m.faces, dtype=np.int64)),
                          ("face_normals", np.asarray(m.face_normals, dtype=float))):
            arr = arr.copy()
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)


def triangle_edges(tris: np.ndarray) -> np.ndarray:
    """The unique undirected edges (E, 2) of a triangle list (lattice edges and diagonals)."""
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]).astype(np.int64)
    e.sort(axis=1)
    return np.unique(e, axis=0)


def _mesh_grid(meshes, friction_default: float, thickness: float):
    """Concatenate the meshes into one triangle soup and bin its faces in a uniform grid."""
    V, F, N, MU = [], [], [], []
    off = 0
    cells = []
    for m in meshes:
        V.append(m.vertices)
        F.append(m.faces + off)
        N.append(m.face_normals)
        MU.append(np.full(len(m.faces), friction_default if m.friction is None else float(m.friction)))
        off += len(m.vertices)
        edge_len = np.linalg.norm(m.vertices[m.faces[:, 1]] - m.vertices[m.faces[:, 0]], axis=1).mean()
        cells.append(m.cell_size or max(float(edge_len), 1.0))
    mv = np.concatenate(V)
    mf = np.concatenate(F)
    cell = max(min(cells), 2.0 * thickness)
    lo = mv.min(axis=0) - cell
    hi = mv.max(axis=0) + cell
    def grid_dims(c):  # as floats: an int64 product could overflow for a huge mesh
        return np.maximum(np.ceil((hi - lo) / c), 1.0)

    while float(np.prod(grid_dims(cell))) > 4_000_000:  # keep the grid small
        cell *= 1.5
    dims = grid_dims(cell).astype(np.int64)
    tri = mv[mf]
    tlo = np.floor((tri.min(axis=1) - thickness - lo) / cell).astype(np.int64).clip(0, dims - 1)
    thi = np.floor((tri.max(axis=1) + thickness - lo) / cell).astype(np.int64).clip(0, dims - 1)
    buckets: dict[int, list[int]] = {}
    for f in range(len(mf)):
        for i in range(tlo[f, 0], thi[f, 0] + 1):
            for j in range(tlo[f, 1], thi[f, 1] + 1):
                for k in range(tlo[f, 2], thi[f, 2] + 1):
                    buckets.setdefault((i * dims[1] + j) * dims[2] + k, []).append(f)
    ncell = int(np.prod(dims))
    counts = np.zeros(ncell + 1, dtype=np.int64)
    for c, fs in buckets.items():
        counts[c + 1] = len(fs)
    start = np.cumsum(counts)
    items = np.empty(start[-1], dtype=np.int64)
    for c, fs in buckets.items():
        items[start[c]:start[c + 1]] = fs
    return (mv, mf, np.concatenate(N), np.concatenate(MU), lo, 1.0 / cell, dims, start, items,
            np.empty(len(mf), dtype=np.int64))


_EMPTY_MESH = None


def _empty_mesh():
    global _EMPTY_MESH
    if _EMPTY_MESH is None:
        _EMPTY_MESH = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3)), np.zeros(0),
                       np.zeros(3), 1.0, np.ones(3, dtype=np.int64), np.zeros(2, dtype=np.int64),
                       np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    return _EMPTY_MESH


def collision_args(model) -> CollisionData:
    """The :class:`~cloth_gym.sim.bundles.CollisionData` of
    :func:`~cloth_gym.sim.collision_kernels.collision_pass` for ``model``: flags, iterations,
    thickness, μ_self, triangles, triangle edges, point indices, the pair lists' Verlet margin
    (cm), and the mesh-obstacle arrays. A :class:`~cloth_gym.sim.bundles.NoCollisionPass` when
    neither self-collision nor a mesh obstacle asks for the pass."""
    opts: CollisionOptions = model.collision
    meshes = [o for o in model.obstacles if isinstance(o, MeshObstacle)]
    flags = 0
    if opts.self_collision:
        flags |= ck.SELF_VT | (ck.SELF_EE if opts.edge_edge else 0)
    if opts.angular_momentum:
        flags |= ck.ANGULAR
    if opts.response == "exact":
        flags |= ck.EXACT
    thickness = float(model.contact_thickness if opts.thickness is None else opts.thickness)
    mu = float(model.material.friction if opts.self_friction is None else opts.self_friction)
    if meshes:
        flags |= ck.MESH
        mesh = _mesh_grid(meshes, float(model.material.friction), float(model.contact_thickness))
    else:
        mesh = _empty_mesh()
    if opts.self_collision:
        tris = np.ascontiguousarray(model.tri_indices, dtype=np.int64)
        edges = triangle_edges(tris)
        points = np.arange(model.particle_count, dtype=np.int64).reshape(-1, 1)
    else:
        tris = np.zeros((0, 3), dtype=np.int64)
        edges = np.zeros((0, 2), dtype=np.int64)
        points = np.zeros((0, 1), dtype=np.int64)
    margin = 0.5 * float(model.sigma)  # Verlet margin of the self-collision pair lists, cm
    kind = CollisionData if flags & ck.COLLISION_PASS_BITS else NoCollisionPass
    return kind(flags, int(opts.iterations), thickness, mu, tris, edges, points, margin, *mesh)
