"""Building a cloth: the shapes (:class:`Rectangle`, :class:`Ribbon`, :class:`Disc`) and
:func:`build_cloth`, which turns a shape, a material and a lattice spacing into an immutable
:class:`~cloth_gym.sim.model.Model` (docs/physics.md, lattice).

Particles sit on a square grid of spacing σ, masked by the shape. Lattice index ``i`` runs along
the **warp** (the cloth's local x), ``j`` along the **weft** (local y). The cloth is placed in the
world by ``origin`` and ``rotation`` (local → world).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Sequence

import numpy as np

from ..errors import ConfigError, ConfigTypeError, SizeError
from ..materials import Material, load_material
from ..validation import integer, real, real_array, vector
from ..units import G
from .model import ForceOptions, Model, read_only

if TYPE_CHECKING:  # a string annotation only: collision imports this module
    from .collision import CollisionOptions

__all__ = ["Rectangle", "Disc", "Ribbon", "build_cloth", "lattice_model", "MAX_PARTICLES", "BYTES_PER_PARTICLE",
           "MIN_SIGMA_CM", "MAX_SHAPE_CM"]

# ----------------------------------------------------------------------------- shapes
#: the longest side a shape may have, cm (a 1 km cloth is a typo, not a scene)
MAX_SHAPE_CM = 1.0e5


@dataclass(frozen=True)
class Rectangle:
    """A rectangle of ``warp_cm`` (along i) by ``weft_cm`` (along j), centred at the origin."""

    warp_cm: float
    weft_cm: float

    def __post_init__(self):
        for name in ("warp_cm", "weft_cm"):
            real(f"{type(self).__name__}.{name}", getattr(self, name), 0.0, MAX_SHAPE_CM, lo_open=True, unit="cm")

    @property
    def area_cm2(self) -> float:
        """The shape's area, cm² (its mass is ``W·area_cm2`` under area lumping)."""
        return float(self.warp_cm * self.weft_cm)

    def particle_count(self, sigma: float) -> int:
        """Particles of the lattice of spacing ``sigma`` cm (without building it)."""
        return (_count(f"{type(self).__name__}.warp_cm", self.warp_cm, sigma)
                * _count(f"{type(self).__name__}.weft_cm", self.weft_cm, sigma))

    def grid(self, sigma: float):
        nx = _count(f"{type(self).__name__}.warp_cm", self.warp_cm, sigma)
        ny = _count(f"{type(self).__name__}.weft_cm", self.weft_cm, sigma)
        u = (np.arange(nx) - (nx - 1) / 2) * sigma
        w = (np.arange(ny) - (ny - 1) / 2) * sigma
        return u, w, np.ones((nx, ny), dtype=bool)


@dataclass(frozen=True)
class Ribbon(Rectangle):
    """A long narrow strip: ``warp_cm`` is its length, ``weft_cm`` its width."""


@dataclass(frozen=True)
class Disc:
    """A disc of ``diameter_cm``, centred at the origin (the drape test's specimen)."""

    diameter_cm: float

    def __post_init__(self):
        real("Disc.diameter_cm", self.diameter_cm, 0.0, MAX_SHAPE_CM, lo_open=True, unit="cm")

    @property
    def area_cm2(self) -> float:
        """The disc's area, cm² (its mass is ``W·area_cm2`` under area lumping)."""
        return float(math.pi * (self.diameter_cm / 2) ** 2)

    def _half_width(self, sigma: float) -> int:
        n = int(math.floor(self.diameter_cm / 2 / sigma + 1e-9))
        if n < 1:
            raise ConfigError("Disc.diameter_cm", f"{self.diameter_cm} cm holds no lattice square at sigma={sigma} cm")
        return n

    def particle_count(self, sigma: float) -> int:
        """Particles of the lattice of spacing ``sigma`` cm, without building it (for a radius of
        more than 500,000 σ, the disc's area over σ²: far above any size guard)."""
        n = self._half_width(sigma)
        if n > 500_000:
            return int(math.pi * (self.diameter_cm / 2 / sigma) ** 2)
        r2 = (self.diameter_cm / 2 / sigma) ** 2 * (1 + 1e-9)
        i = np.arange(-n, n + 1, dtype=float)
        return int(np.sum(2 * np.floor(np.sqrt(np.maximum(r2 - i * i, 0.0))) + 1))

    def grid(self, sigma: float):
        r = self.diameter_cm / 2
        n = self._half_width(sigma)
        u = np.arange(-n, n + 1) * sigma
        mask = (u[:, None] ** 2 + u[None, :] ** 2) <= r * r * (1 + 1e-9)
        return u, u.copy(), mask


def _count(name: str, length: float, sigma: float) -> int:
    n = length / sigma
    k = int(round(n))
    if k < 1 or abs(n - k) > 1e-6 * max(1.0, n):
        raise ConfigError(name, f"{length} cm is not a positive multiple of sigma={sigma} cm")
    return k + 1


# ----------------------------------------------------------------------------- builder
#: the finest lattice spacing build_cloth takes, cm (a micrometre: below it a shape's particle count
#: overflows before the size guard can refuse it)
MIN_SIGMA_CM = 1e-4
#: build_cloth's default size guard, particles
MAX_PARTICLES = 250_000
#: memory a particle takes, bytes, model and implicit solver together (measured with tracemalloc: about
#: 6,200 at the peak of a multigrid step on 41 × 41 and 5,100 on 81 × 81)
BYTES_PER_PARTICLE = 6_200


def build_cloth(
    shape: "Rectangle | Disc | Ribbon",
    material: "Material | str" = "thick_cotton",
    sigma: float = 0.5,
    options: ForceOptions | None = None,
    origin: Sequence[float] = (0.0, 0.0, 0.0),
    rotation: "np.ndarray | None" = None,
    pinned: "Iterable[int] | np.ndarray | None" = None,
    gravity: Sequence[float] = (0.0, 0.0, -G),
    obstacles: Iterable = (),
    contact_thickness: float = 0.1,
    collision: "CollisionOptions | dict | None" = None,
    max_particles: int = MAX_PARTICLES,
) -> Model:
    """Build the lattice (docs/physics.md, lattice) for ``shape`` and finalise it into a :class:`Model`.

    Parameters
    ----------
    shape
        :class:`Rectangle`, :class:`Ribbon` or :class:`Disc` (lengths in cm).
    material
        a :class:`~cloth_gym.materials.Material` or a shipped name / YAML path.
    sigma
        lattice spacing σ, cm (``MIN_SIGMA_CM`` = 1e-4 ≤ σ ≤ 50).
    options
        :class:`ForceOptions` (default: proposed KES model, all forces on).
    origin
        world position (cm) of the shape's centre.
    rotation
        (3, 3) rotation matrix, local (warp, weft, normal) → world. Default identity.
    pinned
        particle indices (or (N,) bool mask) to hold fixed.
    gravity
        gravitational acceleration, cm/s².
    obstacles
        static :class:`~cloth_gym.sim.obstacles.Plane`, ``Box``, ``Sphere``, ``Cylinder``
        and :class:`~cloth_gym.sim.collision.MeshObstacle` (triangle meshes).
    contact_thickness
        distance (cm) kept between particles and obstacle surfaces.
    collision
        :class:`~cloth_gym.sim.collision.CollisionOptions` (or a dict of them):
        self-collision and the collision response. Default: no self-collision.
    max_particles
        the size guard: a lattice with more particles is refused at once with a
        :class:`~cloth_gym.errors.SizeError` that gives the count and an estimate of the memory it
        would take (``BYTES_PER_PARTICLE`` each), instead of running out of memory or building for
        minutes. Default ``MAX_PARTICLES`` (250,000: a 500 × 500 lattice, about 1.5 GiB).
    """
    sigma = real("sigma", sigma, MIN_SIGMA_CM, 50.0, unit="cm (lattice spacing)")
    if not isinstance(shape, (Rectangle, Disc)):
        raise ConfigTypeError("shape", f"expected a Rectangle, Ribbon or Disc instance, got {shape!r}")
    if options is not None and not isinstance(options, ForceOptions):
        raise ConfigTypeError("options", f"expected ForceOptions or None, got {type(options).__name__}")
    _check_size(shape, sigma, integer("max_particles", max_particles, 1, 10**9))
    options = options or ForceOptions()
    material = load_material(material)
    R = np.eye(3) if rotation is None else real_array("rotation", rotation, (3, 3))
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) <= 0:
        raise ConfigError("rotation", f"must be a proper 3x3 rotation matrix, got {rotation!r}")
    org = vector("origin", origin, 3, unit="cm")
    grav = vector("gravity", gravity, 3, unit="cm/s^2")
    contact_thickness = real("contact_thickness", contact_thickness, 0.0, 10.0, unit="cm")
    if isinstance(obstacles, (str, bytes, Mapping)) or not isinstance(obstacles, Iterable):
        raise ConfigTypeError("obstacles", f"expected a list of obstacles (Plane, Box, Sphere, Cylinder, "
                              f"MeshObstacle), got {obstacles!r}")
    obstacles = tuple(obstacles)
    model = lattice_model(shape, material, sigma, options, R, org, grav)
    if obstacles or contact_thickness != 0.1:
        model = model.with_obstacles(obstacles, contact_thickness)
    if collision is not None:
        model = model.with_collision(collision)
    if pinned is not None:
        model = model.with_pinned(list(pinned) if isinstance(pinned, Iterable) and not isinstance(pinned, np.ndarray)
                                  else pinned)
    return model


def _check_size(shape, sigma: float, max_particles: int) -> None:
    """The size guard: :class:`~cloth_gym.errors.SizeError` for a lattice of more than
    ``max_particles`` particles, with the count and the memory it would take."""
    count = shape.particle_count(sigma)
    if count > max_particles:
        need = count * BYTES_PER_PARTICLE
        raise SizeError("sigma", f"{shape} at sigma = {sigma} cm has {count:,} particles, above the limit "
                        f"max_particles = {max_particles:,}; simulating it would take about {need / 2**30:.1f} GiB. "
                        "Use a larger sigma, or raise max_particles", particles=count, memory_bytes=need)


def lattice_model(shape, material: Material, sigma: float, options: ForceOptions, rotation: np.ndarray,
                  origin: np.ndarray, gravity: np.ndarray) -> Model:
    """The :class:`Model` of ``shape``'s lattice, its inputs taken as checked (:func:`build_cloth`
    checks them; the solver builds its coarse multigrid levels with it, at spacings beyond a
    user's range)."""
    R, org, grav = rotation, origin, gravity
    u, w, mask = shape.grid(sigma)
    nx, ny = mask.shape
    grid_index = -np.ones((nx, ny), dtype=np.int32)
    ii, jj = np.nonzero(mask)  # row-major: i outer, j inner
    n = ii.size
    grid_index[ii, jj] = np.arange(n, dtype=np.int32)
    local = np.stack([u[ii], w[jj], np.zeros(n)], axis=1)
    q0 = local @ R.T + org

    edges, edir, bends, bdir, shears, tris = _lattice_elements(grid_index, ii, jj)
    edges = np.array(edges, dtype=np.int32).reshape(-1, 2)
    bends = np.array(bends, dtype=np.int32).reshape(-1, 3)
    area, edge_width, bend_width = _lumping(shape, options, sigma, u, w, mask, grid_index, ii, jj, edges, edir,
                                            bends, bdir)
    mass = material.areal_density * sigma * sigma * area
    inv_mass = 1.0 / mass
    if options.model == "kes":
        bend = np.array([[c.c0, c.c1, c.c2] for c in (material.bending.warp, material.bending.weft)])
    else:  # Breen: isotropic, the mean of warp and weft
        m = material.bending.mean()
        bend = np.array([[m.c0, m.c1, m.c2]] * 2)
    stretch = np.array([[c.c1, c.c2] for c in (material.stretch.warp, material.stretch.weft)])
    shear = material.shear.mean().as_array()

    model = Model(
        material=material,
        options=options,
        sigma=sigma,
        particle_q0=read_only(q0),
        particle_mass=read_only(mass),
        particle_inv_mass=read_only(inv_mass),
        particle_grid=read_only(np.stack([ii, jj], axis=1).astype(np.int32)),
        grid_index=read_only(grid_index),
        edge_indices=read_only(edges),
        edge_dir=read_only(np.array(edir, dtype=np.int32)),
        edge_rest_length=read_only(np.full(len(edges), sigma)),
        edge_width=read_only(edge_width),
        bend_indices=read_only(bends),
        bend_dir=read_only(np.array(bdir, dtype=np.int32)),
        bend_width=read_only(bend_width),
        bend_length=read_only(np.ones(len(bends))),
        shear_indices=read_only(np.array(shears, dtype=np.int32).reshape(-1, 3)),
        tri_indices=read_only(np.array(tris, dtype=np.int32).reshape(-1, 3)),
        stretch_coef=read_only(stretch),
        bend_coef=read_only(bend),
        shear_coef=read_only(shear),
        gravity=read_only(grav),
    )
    return model


def _lattice_elements(grid_index: np.ndarray, ii: np.ndarray, jj: np.ndarray):
    """The elements of a masked lattice (``grid_index``: particle of each node, −1 where masked),
    visiting particles in order: stretch edges to the next node along warp (d = 0) and weft (1) with
    their directions, bending triples of three nodes in line with theirs, shear corners (a, p, c)
    of each right angle at p, and two triangles per lattice square (alternating diagonals; a disc's
    outline keeps the corner triangle of a square missing one node)."""
    nx, ny = grid_index.shape

    def node(i, j):
        if 0 <= i < nx and 0 <= j < ny:
            return grid_index[i, j]
        return -1

    edges, edir, bends, bdir, shears, tris = [], [], [], [], [], []
    for i, j in zip(ii, jj):
        p = grid_index[i, j]
        for d, (di, dj) in enumerate(((1, 0), (0, 1))):
            q = node(i + di, j + dj)
            if q >= 0:
                edges.append((p, q))
                edir.append(d)
                r = node(i + 2 * di, j + 2 * dj)
                if r >= 0:
                    bends.append((p, q, r))
                    bdir.append(d)
        for si in (-1, 1):
            a = node(i + si, j)
            if a < 0:
                continue
            for sj in (-1, 1):
                c = node(i, j + sj)
                if c >= 0:
                    shears.append((a, p, c))
        # lattice square with lower-left corner (i, j); alternate the diagonal
        q10, q11, q01 = node(i + 1, j), node(i + 1, j + 1), node(i, j + 1)
        corners = (p, q10, q11, q01)
        present = [c >= 0 for c in corners]
        if all(present):
            if (i + j) % 2 == 0:
                tris += [(p, q10, q11), (p, q11, q01)]
            else:
                tris += [(p, q10, q01), (q10, q11, q01)]
        elif sum(present) == 3:  # outline of a disc: keep the corner triangle
            tris.append(tuple(c for c in corners if c >= 0))

    return edges, edir, bends, bdir, shears, tris


def _lumping(shape, options: ForceOptions, sigma, u, w, mask, grid_index, ii, jj, edges, edir, bends, bdir):
    """(particle area in lattice cells, edge widths, bending widths) of the mass lumping: ``"area"``
    gives each particle its share of the shape's area and each element the width of the strip it
    stands for; ``"uniform"`` ones."""
    n = ii.size
    if options.mass_lumping == "area":
        if isinstance(shape, Disc):
            area = _disc_cell_areas(shape.diameter_cm / 2 / sigma, u[ii] / sigma, w[jj] / sigma)
        else:
            area = _square_areas(mask, grid_index, n)
        lattice = np.stack([ii, jj], axis=1)
        half = _half_squares(mask)
        edge_width = _strip_width(half, lattice[edges[:, 0]], np.array(edir))
        bdir_arr = np.array(bdir, dtype=np.int32)
        bend_width = 0.5 * (_strip_width(half, lattice[bends[:, 0]], bdir_arr)
                            + _strip_width(half, lattice[bends[:, 1]], bdir_arr))
    else:
        area, edge_width, bend_width = np.ones(n), np.ones(len(edges)), np.ones(len(bends))
    return area, edge_width, bend_width


def _disc_cell_areas(radius: float, iu: np.ndarray, iw: np.ndarray, samples: int = 16) -> np.ndarray:
    """Area shares (σ²) of a disc's particles: the part of each particle's σ × σ cell inside the
    disc (``radius`` and the particles' coordinates ``iu``, ``iw`` in units of σ), sampled on a
    ``samples²`` grid per cell, scaled so that the shares sum to the disc's area π·radius² (the
    slivers of the outline that no particle's cell reaches are shared out in proportion)."""
    off = (np.arange(samples) + 0.5) / samples - 0.5
    inside = np.zeros(len(iu))
    for du in off:  # one row of samples at a time: memory O(N·samples)
        pu = (iu + du)[:, None]
        pw = iw[:, None] + off[None, :]
        inside += np.count_nonzero(pu * pu + pw * pw <= radius * radius, axis=1)
    area = inside / samples ** 2
    return area * (math.pi * radius * radius / area.sum())


def _square_corners(mask):
    """(nx, ny) int: how many corners of each lattice square are in the cloth, the square (i, j)
    having its lower-left corner at node (i, j)."""
    nx, ny = mask.shape
    m = np.zeros((nx + 1, ny + 1), dtype=bool)
    m[:nx, :ny] = mask
    return m[:-1, :-1].astype(int) + m[1:, :-1] + m[1:, 1:] + m[:-1, 1:]


def _square_areas(mask, grid_index, n):
    """Area shares (σ²) of the particles: each lattice square present (all four corners in the
    cloth) gives a quarter of its area to each corner; a square with three corners (on an outline)
    is the triangle of half its area and gives a third of that to each of its corners. A node no
    square covers (a spur of a coarse multigrid level's outline) keeps an eighth of a cell, so that
    no particle is massless."""
    nx, ny = mask.shape
    corners = _square_corners(mask)
    share = np.where(corners == 4, 0.25, np.where(corners == 3, 1.0 / 6.0, 0.0))
    m = np.zeros((nx + 1, ny + 1), dtype=bool)
    m[:nx, :ny] = mask
    area = np.zeros(n)
    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):  # each square's corners
        s = share * m[di:di + nx, dj:dj + ny]
        ci, cj = np.nonzero(s)
        np.add.at(area, grid_index[ci + di, cj + dj], s[ci, cj])
    return np.maximum(area, 0.125)


def _half_squares(mask):
    """(nx + 2, ny + 2): the fabric (in σ²) within σ/2 of one side of each lattice square, padded by
    one square of nothing on every side: ½ for a square present, ¼ for an outline triangle."""
    corners = _square_corners(mask)
    half = np.zeros((mask.shape[0] + 2, mask.shape[1] + 2))
    half[1:-1, 1:-1] = np.where(corners == 4, 0.5, np.where(corners == 3, 0.25, 0.0))
    return half


def _strip_width(half, start, direction):
    """Width (in σ) of the strip of fabric along the lattice segment from node ``start`` (M, 2) one
    step in ``direction`` (M,), 0 warp or 1 weft: half of each square beside it (squares (i, j) and
    (i, j − 1) for a warp segment, (i, j) and (i − 1, j) for a weft one)."""
    i, j = start[:, 0] + 1, start[:, 1] + 1  # into the padded array
    warp = direction == 0
    return half[i, j] + np.where(warp, half[i, j - 1], half[i - 1, j])
