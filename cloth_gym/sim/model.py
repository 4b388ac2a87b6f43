"""Static cloth model (topology + parameters), mutable state and control.

Following NVIDIA Warp's ``sim``: :func:`build_cloth` turns a shape, a material
and a spacing into an immutable :class:`Model`; ``model.state()`` creates the
mutable :class:`State`; inputs that change during a run (wind) live in a
:class:`Control`. Arrays are structure-of-arrays with an entity prefix and are
read-only on the model.

Lattice (docs/physics.md, lattice): particles on a square grid of spacing σ, masked by the
shape. Lattice index ``i`` runs along the **warp** (the cloth's local x), ``j``
along the **weft** (local y). The cloth is placed in the world by ``origin``
and ``rotation`` (local → world).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Literal, Sequence

import numpy as np

from ..errors import ConfigError, ConfigTypeError, SizeError
from ..materials import Material, load_material
from ..validation import flag, integer, one_of, real, real_array, vector
from ..units import G

if TYPE_CHECKING:  # a string annotation only: collision imports this module
    from .collision import CollisionOptions

__all__ = [
    "Rectangle", "Disc", "Ribbon", "ForceOptions", "Model", "State", "SolverMemory", "Control", "build_cloth",
    "lattice_model", "MAX_PARTICLES", "BYTES_PER_PARTICLE", "WARP", "WEFT",
]

WARP = 0
WEFT = 1


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


# ----------------------------------------------------------------------------- options
ModelKind = Literal["kes", "breen"]

#: The strain guard of each stretch law, percent (None: none): an edge stretched past it makes an
#: integrator raise :class:`~cloth_gym.errors.SimulationDiverged` (reason ``"strain"``). The KES
#: laws are fitted to KES tensile tests that end at a few percent, and woven fabric tears long
#: before 100 %: a lattice edge at twice its rest length is a numerical failure, not fabric.
#: Breen's quartic springs are nearly slack at small strain and stretch 25–60 % by design, so
#: only the speed and non-finite checks guard them.
STRAIN_GUARD_PERCENT = {"kes": 100.0, "breen": None}
MassLumping = Literal["area", "uniform"]
DampingModel = Literal["strain-rate", "absolute"]


@dataclass(frozen=True)
class ForceOptions:
    """Which forces a scene computes, and the model's numerical constants.

    Attributes
    ----------
    model
        ``"kes"`` (the paper's proposed model, docs/physics.md, forces) or ``"breen"``
        (the baseline, docs/physics.md, Breen's model).
    gravity, stretch, bending, shear, air, damping
        switch each force on/off;
        a scene pays only for what it switches on.
    mass_lumping
        ``"area"`` (default): each particle carries the fabric of the area it stands for
        (``W·σ²`` inside, half on a straight edge, a quarter at a corner) and each stretch edge
        and bending triple the width of fabric it spans (half along the cloth's outline), so a
        shape of L cm is L cm of fabric and mass-dependent results converge at second order in
        σ (docs/physics.md, lattice). ``"uniform"``: every particle ``W·σ²`` and every element
        at full width, as in the paper (a lattice of (L + σ)² of fabric; the v0 envs).
    damping_model
        ``"strain-rate"`` (default): the material's damping acts on the rates of deformation
        only (edge stretch, bending and shear angle rates, ``Material.strain_damping``), so rigid
        translation and rotation are undamped. ``"absolute"``: ``−λ·m·v`` on each particle's
        absolute velocity (``Material.damping``), as in the paper (the v0 envs).
    sqrt_reg_curvature
        x0 of the regularised ``K^½ → K/sqrt(K + x0)``, in
        1/cm. 0.004 keeps the curve within 2 % of the measured one from
        K = 0.1 /cm up (docs/physics.md, forces).
    sqrt_reg_shear
        x0 for ``φ^½``, in degrees (within 2 % from φ = 0.1°).
    breen_c0
        C0 of Breen's stretch law (1), dyne·cm (default 1.0e5; docs/physics.md, Breen's model).
    """

    model: ModelKind = "kes"
    gravity: bool = True
    stretch: bool = True
    bending: bool = True
    shear: bool = True
    air: bool = True
    damping: bool = True
    mass_lumping: MassLumping = "area"
    damping_model: DampingModel = "strain-rate"
    sqrt_reg_curvature: float = 0.004
    sqrt_reg_shear: float = 0.004
    breen_c0: float = 1.0e5

    @classmethod
    def paper(cls, **changes) -> "ForceOptions":
        """The paper's lattice conventions: every particle ``W·σ²`` (``mass_lumping="uniform"``) and
        damping of absolute velocity (``damping_model="absolute"``), other fields as given. The
        scenes of the paper (:mod:`cloth_gym.scenes`) and the v0 envs use them, so that their
        published results are re-run as measured."""
        return cls(**{"mass_lumping": "uniform", "damping_model": "absolute", **changes})

    def __post_init__(self):
        one_of("ForceOptions.model", self.model, ("kes", "breen"))
        one_of("ForceOptions.mass_lumping", self.mass_lumping, ("area", "uniform"))
        one_of("ForceOptions.damping_model", self.damping_model, ("strain-rate", "absolute"))
        for name in ("gravity", "stretch", "bending", "shear", "air", "damping"):
            flag(f"ForceOptions.{name}", getattr(self, name))
        # x0 = 0 is allowed (the exact measured curve), though the flat state is then infinitely stiff
        for name in ("sqrt_reg_curvature", "sqrt_reg_shear", "breen_c0"):
            real(f"ForceOptions.{name}", getattr(self, name), 0.0, 1e12)


# ----------------------------------------------------------------------------- model
def _ro(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class Model:
    """Immutable cloth model. Build it with :func:`build_cloth`.

    Particles (N):
        particle_q0: (N, 3) float64, rest positions in world frame, cm.
        particle_mass: (N,) float64, g (``W`` times the area each particle stands for,
            ``ForceOptions.mass_lumping``).
        particle_inv_mass: (N,) float64, 1/g; 0 for pinned particles.
        particle_grid: (N, 2) int32, lattice indices (i warp, j weft).
    Elements:
        edge_indices: (E, 2) int32, stretch edges; edge_dir: (E,) int32 (0 warp, 1 weft);
        edge_rest_length: (E,) float64, cm; edge_width: (E,) float64, the width of fabric each
            edge stands for, in units of σ (1 inside, ½ along the outline).
        bend_indices: (B, 3) int32, triples (a, b, c) along a lattice line; bend_dir: (B,) int32;
            bend_width: (B,) float64, in units of σ, like ``edge_width``.
        bend_length: (B,) float64, in units of σ: the length of fabric over which a triple's
            turning angle ψ bends (its curvature is ψ over it): 1, but ½ at a clamp (the middle
            particle and one end pinned: the segment between them is held straight, so only the
            half segment on the free side bends) and 0 where all three are pinned.
        shear_indices: (S, 3) int32, corners (a, b, c): a warp and c weft neighbour of b.
        tri_indices: (T, 3) int32, triangles, counter-clockwise in the cloth's local frame.
    Parameters:
        sigma: lattice spacing σ, cm.
        stretch_coef: (2, 2) [dir, (c1, c2)], gf/cm per percent^k (KES units).
        bend_coef: (2, 3) [dir, (c0, c1, c2)], gf·cm/cm (Breen: both rows the warp/weft mean).
        shear_coef: (3,) mean warp/weft shear curve (c0, c1, c2), gf/cm per degree^k.
        gravity: (3,) cm/s².
    grid_index: (nx, ny) int32, particle index of lattice node or -1.
    """

    material: Material
    options: ForceOptions
    sigma: float
    particle_q0: np.ndarray
    particle_mass: np.ndarray
    particle_inv_mass: np.ndarray
    particle_grid: np.ndarray
    grid_index: np.ndarray
    edge_indices: np.ndarray
    edge_dir: np.ndarray
    edge_rest_length: np.ndarray
    edge_width: np.ndarray
    bend_indices: np.ndarray
    bend_dir: np.ndarray
    bend_width: np.ndarray
    bend_length: np.ndarray
    shear_indices: np.ndarray
    tri_indices: np.ndarray
    stretch_coef: np.ndarray
    bend_coef: np.ndarray
    shear_coef: np.ndarray
    gravity: np.ndarray
    obstacles: tuple = ()
    contact_thickness: float = 0.1
    collision: "CollisionOptions" = field(default_factory=lambda: _collision_options())

    @cached_property
    def force_data(self):
        """The forces as the kernels read them: a :class:`~cloth_gym.sim.bundles.ForceData`, built once."""
        from .forces import force_data

        return force_data(self)

    @cached_property
    def collision_arrays(self) -> tuple:
        """The collision pass's :class:`~cloth_gym.sim.bundles.CollisionData` (self-collision, mesh
        obstacles), packed once."""
        from .collision import collision_args

        return collision_args(self)

    def with_collision(self, collision: "CollisionOptions | dict | None" = None, **changes) -> "Model":
        """A copy with these :class:`~cloth_gym.sim.collision.CollisionOptions` (or the current ones
        with ``changes``), e.g. ``model.with_collision(self_collision=True)``."""
        from .collision import CollisionOptions

        base = self.collision if collision is None else collision
        if isinstance(base, dict):
            base = CollisionOptions.from_dict(base)
        if not isinstance(base, CollisionOptions):
            raise ConfigError("collision", f"expected CollisionOptions or a dict, got {type(base).__name__}")
        if changes:
            base = CollisionOptions.from_dict({**dataclasses.asdict(base), **changes})
        return dataclasses.replace(self, collision=base)

    @cached_property
    def obstacle_arrays(self):
        """(types (K,), params (K, 9), friction (K,)) of the obstacles, for the kernels."""
        from .obstacles import pack_obstacles

        return pack_obstacles(self.obstacles, float(self.material.friction))

    @cached_property
    def obstacle_data(self):
        """The analytic obstacles as the kernels read them: a :class:`~cloth_gym.sim.bundles.ObstacleData`."""
        from .bundles import ObstacleData

        types, params, mu = self.obstacle_arrays
        return ObstacleData(types, params, mu, float(self.material.restitution), float(self.contact_thickness))

    def with_obstacles(self, obstacles: Iterable = (), contact_thickness: float | None = None) -> "Model":
        """A copy with these static obstacles (see :mod:`cloth_gym.sim.obstacles`).

        ``contact_thickness``: distance (cm) kept between a particle and an obstacle surface."""
        th = real("contact_thickness", self.contact_thickness if contact_thickness is None else contact_thickness,
                  0.0, 10.0, unit="cm")
        if isinstance(obstacles, (str, bytes, Mapping)) or not isinstance(obstacles, Iterable):
            raise ConfigTypeError("obstacles", f"expected a list of obstacles (Plane, Box, Sphere, Cylinder, "
                                  f"MeshObstacle), got {obstacles!r}")
        m = dataclasses.replace(self, obstacles=tuple(obstacles), contact_thickness=th)
        m.obstacle_arrays  # validate now
        return m

    @cached_property
    def particle_area(self) -> np.ndarray:
        """(N,) float64, cm²: the area of fabric each particle stands for (its mass over W)."""
        return _ro(self.particle_mass / self.material.areal_density)

    @property
    def strain_guard_percent(self) -> float | None:
        """Edge strain (%) past which a state counts as diverged for this model's stretch law
        (:data:`STRAIN_GUARD_PERCENT`: 100 % for the KES model, None (no guard) for Breen's); the
        integrators use it unless given their own ``max_strain_percent``."""
        return STRAIN_GUARD_PERCENT[self.options.model]

    @property
    def particle_count(self) -> int:
        return int(self.particle_q0.shape[0])

    @property
    def pinned(self) -> np.ndarray:
        """(N,) bool, particles held fixed (inverse mass 0)."""
        return self.particle_inv_mass == 0.0

    def state(self) -> "State":
        """A new state at rest in the rest configuration, t = 0."""
        return State(self.particle_q0.copy(), np.zeros_like(self.particle_q0))

    def control(self) -> "Control":
        return Control()

    def with_pinned(self, pinned: "Sequence[int] | np.ndarray") -> "Model":
        """A copy whose pinned particles are ``pinned`` (indices or (N,) bool mask)."""
        try:
            p = np.asarray(pinned)
        except ValueError:
            p = np.asarray(pinned, dtype=object)
        if p.size and p.dtype.kind not in "biu":
            raise ConfigTypeError("pinned", f"expected particle indices (integers) or an (N,) bool mask, got {pinned!r}")
        mask = np.zeros(self.particle_count, dtype=bool)
        if p.dtype == bool:
            if p.shape != (self.particle_count,):
                raise ConfigError("pinned", f"a boolean mask needs shape ({self.particle_count},), got {p.shape}")
            mask = p.copy()
        elif p.size:
            if p.min() < 0 or p.max() >= self.particle_count:
                raise ConfigError("pinned", f"indices must be in [0, {self.particle_count - 1}]")
            mask[p.astype(np.int64)] = True
        inv = np.where(mask, 0.0, 1.0 / self.particle_mass)
        return dataclasses.replace(self, particle_inv_mass=_ro(inv),
                                   bend_length=_ro(clamped_bend_lengths(self.bend_indices, mask)))

    def index(self, i: int, j: int) -> int:
        """Particle index at lattice node (i, j) (negative indices count from the end)."""
        nx, ny = self.grid_index.shape
        p = int(self.grid_index[i % nx, j % ny])
        if p < 0:
            raise ConfigError("index", f"lattice node ({i}, {j}) is outside the cloth")
        return p

    def corners(self) -> np.ndarray:
        """Indices of the four lattice corners (i, j) = (0,0), (-1,0), (-1,-1), (0,-1) where they exist."""
        out = []
        for i, j in ((0, 0), (-1, 0), (-1, -1), (0, -1)):
            nx, ny = self.grid_index.shape
            p = int(self.grid_index[i % nx, j % ny])
            if p >= 0:
                out.append(p)
        return np.array(out, dtype=np.int64)

    @cached_property
    def edge_stiffness(self) -> np.ndarray:
        """(2,) tangent tensile stiffness of a warp / weft edge at rest, dyne/cm.

        ``k = dF/dr = 100·c1·G`` for the KES law (independent of σ, docs/physics.md, integrators).
        """
        return 100.0 * self.stretch_coef[:, 0] * G


@dataclass
class SolverMemory:
    """What an integrator carries from one call to the next on a state (BDF2 history, contacts,
    sleep record, the solver's first guess), kept in the state so that
    a copy of the state continues exactly as the original would, under any integrator object.

    Every record says at which ``State.step`` it was written; an integrator uses it only when the
    state is still at that step (nothing advanced the state since), and otherwise starts afresh.

    bdf2_x, bdf2_v: (N, 3) positions (cm) and velocities (cm/s) one BDF2 step back; ``None``
        when there is no usable history (then BDF2 restarts with one backward-Euler step).
    bdf2_h: the step length (s) that history was taken with; BDF2 needs the same length.
    bdf2_step: ``State.step`` at which the history is valid.
    contacts: (N,) int64, the obstacle each particle touched in the last step (−1: none), or
        ``None`` (then the contacts the positions imply are found at the start of a call).
    contacts_step: ``State.step`` at which ``contacts`` is valid.
    quiet_q: (N, 3) positions (cm) at the end of the last call that ran under quiet inputs and was
        slow enough for sleeping or slow substeps, or ``None``; the next call continues it only if
        the positions are still exactly these.
    quiet_step: ``State.step`` at which ``quiet_q`` was taken.
    quiet_slow, quiet_sleepy: that call was below ``slow_speed`` / ``sleep_speed``.
    asleep: that call left the cloth asleep (velocities set to 0).
    warm_dv: (N, 3) the velocity change (cm/s) of the last implicit step, the first guess of the next
        step's solve, or ``None``; warm_h: that step's length (s); warm_step: ``State.step`` after it.
    """

    bdf2_x: "np.ndarray | None" = None
    bdf2_v: "np.ndarray | None" = None
    bdf2_h: float = 0.0
    bdf2_step: int = -1
    contacts: "np.ndarray | None" = None
    contacts_step: int = -1
    quiet_q: "np.ndarray | None" = None
    quiet_step: int = -1
    quiet_slow: bool = False
    quiet_sleepy: bool = False
    asleep: bool = False
    warm_dv: "np.ndarray | None" = None
    warm_h: float = 0.0
    warm_step: int = -1

    def copy(self) -> "SolverMemory":
        """A deep copy (its arrays copied)."""
        out = dataclasses.replace(self)
        for name in ("bdf2_x", "bdf2_v", "contacts", "quiet_q", "warm_dv"):
            a = getattr(self, name)
            if a is not None:
                setattr(out, name, a.copy())
        return out

    def clear(self) -> None:
        """Forget everything (a state edited from outside, or advanced by an integrator that keeps
        no such memory)."""
        self.bdf2_x = self.bdf2_v = self.contacts = self.quiet_q = self.warm_dv = None
        self.bdf2_step = self.contacts_step = self.quiet_step = self.warm_step = -1
        self.asleep = self.quiet_slow = self.quiet_sleepy = False


@dataclass
class State:
    """Mutable simulation state.

    particle_q: (N, 3) float64 positions, cm.
    particle_qd: (N, 3) float64 velocities, cm/s. For pinned particles this is their
        prescribed (kinematic) velocity: the integrators move them by it and never change it.
    time: simulated time, s.
    step: number of (sub)steps taken.
    obstacle_offset: (K, 3) displacement, cm, of each analytic obstacle from where the model
        put it (moved by ``Control.obstacle_velocity``); ``None`` until one moves.
    solver: the integrators' memory between calls (:class:`SolverMemory`): BDF2 history, contact
        record, sleep record. :meth:`copy` copies it, so a copy continues identically.
    """

    particle_q: np.ndarray
    particle_qd: np.ndarray
    time: float = 0.0
    step: int = 0
    obstacle_offset: "np.ndarray | None" = None
    solver: SolverMemory = field(default_factory=SolverMemory)

    def copy(self) -> "State":
        """A deep copy, solver memory included."""
        off = None if self.obstacle_offset is None else self.obstacle_offset.copy()
        return State(self.particle_q.copy(), self.particle_qd.copy(), self.time, self.step, off, self.solver.copy())


#: the largest wind or obstacle speed a Control may give, cm/s (10 km/s, far beyond any cloth scene; the
#: divergence guard's default is 1 km/s)
MAX_INPUT_SPEED = 1.0e6


@dataclass
class Control:
    """Time-varying inputs.

    wind: (3,) air velocity w of eq. (4), cm/s (each component within ±``MAX_INPUT_SPEED``).
    kinematic: optional (N,) bool mask of particles that are moved, this call, by
        their prescribed velocity in ``state.particle_qd`` instead of by forces
        (particles held by a gripper). Together with the model's pins. ``None``:
        only the pins.
    obstacle_velocity: optional (K, 3) velocity, cm/s, of each analytic obstacle (plane, box,
        sphere, cylinder, in the model's order; mesh obstacles are static): they translate
        with it during the call, ``State.obstacle_offset`` recording where they are.
    """

    wind: np.ndarray = field(default_factory=lambda: np.zeros(3))
    kinematic: "np.ndarray | None" = None
    obstacle_velocity: "np.ndarray | None" = None

    def obstacle_velocities(self, model: "Model") -> np.ndarray:
        """(K, 3) obstacle velocities (cm/s), validated; zeros when not given."""
        k = model.obstacle_arrays[0].shape[0]
        if self.obstacle_velocity is None:
            return np.zeros((k, 3))
        return real_array("Control.obstacle_velocity", self.obstacle_velocity, (k, 3), limit=MAX_INPUT_SPEED,
                          unit="cm/s, one row per analytic obstacle")

    def inv_mass(self, model: "Model") -> np.ndarray:
        """The model's inverse masses (1/g) with the kinematic particles' set to 0 (read-only, as the
        model's own: the kernels are then compiled for one array type, not for two)."""
        if self.kinematic is None:
            return model.particle_inv_mass
        try:
            k = np.asarray(self.kinematic)
        except ValueError:  # ragged
            raise ConfigTypeError("Control.kinematic", f"must be a bool array of shape ({model.particle_count},), "
                                  f"got {self.kinematic!r}") from None
        if k.shape != (model.particle_count,) or k.dtype != np.bool_:
            raise ConfigError("Control.kinematic", f"must be a bool array of shape ({model.particle_count},), "
                              f"got {k.dtype} {k.shape}")
        return _ro(np.where(k, 0.0, model.particle_inv_mass))


def _collision_options():
    from .collision import CollisionOptions

    return CollisionOptions()


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
    max_particles = integer("max_particles", max_particles, 1, 10**9)
    count = shape.particle_count(sigma)
    if count > max_particles:
        need = count * BYTES_PER_PARTICLE
        raise SizeError("sigma", f"{shape} at sigma = {sigma} cm has {count:,} particles, above the limit "
                        f"max_particles = {max_particles:,}; simulating it would take about {need / 2**30:.1f} GiB. "
                        "Use a larger sigma, or raise max_particles", particles=count, memory_bytes=need)
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

    edges = np.array(edges, dtype=np.int32).reshape(-1, 2)
    bends = np.array(bends, dtype=np.int32).reshape(-1, 3)
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
        particle_q0=_ro(q0),
        particle_mass=_ro(mass),
        particle_inv_mass=_ro(inv_mass),
        particle_grid=_ro(np.stack([ii, jj], axis=1).astype(np.int32)),
        grid_index=_ro(grid_index),
        edge_indices=_ro(edges),
        edge_dir=_ro(np.array(edir, dtype=np.int32)),
        edge_rest_length=_ro(np.full(len(edges), sigma)),
        edge_width=_ro(edge_width),
        bend_indices=_ro(bends),
        bend_dir=_ro(np.array(bdir, dtype=np.int32)),
        bend_width=_ro(bend_width),
        bend_length=_ro(np.ones(len(bends))),
        shear_indices=_ro(np.array(shears, dtype=np.int32).reshape(-1, 3)),
        tri_indices=_ro(np.array(tris, dtype=np.int32).reshape(-1, 3)),
        stretch_coef=_ro(stretch),
        bend_coef=_ro(bend),
        shear_coef=_ro(shear),
        gravity=_ro(grav),
    )
    return model


def clamped_bend_lengths(bends: np.ndarray, pinned: np.ndarray) -> np.ndarray:
    """(B,) the bending length of each triple (a, b, c), in σ (:attr:`Model.bend_length`): half the
    length of its two segments that are not held straight, a segment being held straight when both
    its ends are pinned. 1 for a free triple, ½ at a clamp, 0 inside one.

    Why: a triple's curvature is its turning angle ψ over the length of fabric that turns it. At a
    clamp's edge the clamped segment stays straight, so ψ is turned by the half segment beyond it
    alone, at twice the curvature; counting the full σ there made the joint at a clamp about twice
    too soft and a clamped strip's tip drop converge at first order in σ (docs/physics.md, lattice)."""
    b = bends.astype(np.int64)
    free1 = ~(pinned[b[:, 0]] & pinned[b[:, 1]])
    free2 = ~(pinned[b[:, 1]] & pinned[b[:, 2]])
    return 0.5 * (free1.astype(float) + free2.astype(float))


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
