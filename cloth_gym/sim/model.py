"""Static cloth model (topology + parameters), mutable state and control.

Following NVIDIA Warp's ``sim``: :func:`~cloth_gym.sim.lattice.build_cloth` turns a shape, a
material and a spacing into an immutable :class:`Model`; ``model.state()`` creates the
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
from dataclasses import dataclass, field
from functools import cached_property
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Literal, Sequence

import numpy as np

from ..errors import ConfigError, ConfigTypeError
from ..materials import Material
from ..validation import flag, one_of, real, real_array
from ..units import G

if TYPE_CHECKING:  # a string annotation only: collision imports this module
    from .collision import CollisionOptions

__all__ = ["ForceOptions", "Model", "State", "SolverMemory", "Control", "WARP", "WEFT", "STRAIN_GUARD_PERCENT",
           "MAX_INPUT_SPEED"]

WARP = 0
WEFT = 1


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
def read_only(a: np.ndarray) -> np.ndarray:
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
    def lattice_layout(self) -> tuple:
        """(warp lines, weft lines, stencil) of the implicit solve's matrix on this lattice
        (:func:`~cloth_gym.sim.implicit.levels.lattice_layout`), built once — milliseconds of Python —
        and shared, read only, by every level built on the model (an env makes a fresh integrator,
        hence fresh levels, every episode)."""
        from .implicit.levels import lattice_layout

        return lattice_layout(self)

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
        return read_only(self.particle_mass / self.material.areal_density)

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
        return dataclasses.replace(self, particle_inv_mass=read_only(inv),
                                   bend_length=read_only(clamped_bend_lengths(self.bend_indices, mask)))

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

    def restore(self, saved: "State") -> None:
        """Take back the contents of ``saved`` (a :meth:`copy` of this state, not used after): the
        positions and velocities copied into this state's own arrays (views of them stay valid),
        the rest taken over."""
        self.particle_q[:] = saved.particle_q
        self.particle_qd[:] = saved.particle_qd
        self.time, self.step, self.obstacle_offset, self.solver = (saved.time, saved.step, saved.obstacle_offset,
                                                                   saved.solver)


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
        return read_only(np.where(k, 0.0, model.particle_inv_mass))


def _collision_options():
    from .collision import CollisionOptions

    return CollisionOptions()


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
