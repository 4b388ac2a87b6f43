"""Typed bundles of arrays: what the compiled kernels read.

A kernel takes a few of these instead of long positional argument lists. Each is a
``NamedTuple``: numba passes it as one typed argument and its fields are read by name
(``fd.edges``, ``world.touching``), and plain Python code builds and inspects it like any other
tuple. The bundles fall in three kinds:

* **static, from the model** (built once per model, read-only): :class:`ForceData` (the force
  laws and their elements), :class:`ObstacleData` (analytic obstacles),
  :class:`CollisionData` (self-collision and mesh obstacles);
* **per call** (inputs of one integrator call): :class:`World` (obstacles where they are now,
  the contact record) and :class:`Guard` (divergence thresholds and the strain limiter);
* **solver internals** (:mod:`cloth_gym.sim.implicit`): the lattice levels, their
  linearised stiffness and the solver's scratch arrays.

Status codes that kernels return are :class:`Status` values; :class:`Phase` names the parts of a
call that the integrators' phase profile times.
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple

import numpy as np

__all__ = ["Status", "ForceData", "ObstacleData", "CollisionData", "NoCollisionPass", "World", "Guard", "Force", "Phase"]


class Status(IntEnum):
    """What a kernel run reports (its first return value)."""

    OK = 0
    NON_FINITE = 1  # a position or velocity is NaN or infinite
    SPEED = 2  # a particle faster than Guard.max_speed
    STRAIN = 3  # an edge stretched beyond Guard.max_strain_percent
    NOT_SPD = 4  # the implicit solver's coarse or band matrix is not positive definite


# the reasons SimulationDiverged names, by status
DIVERGE_REASONS = {Status.NON_FINITE: "non-finite", Status.SPEED: "speed", Status.STRAIN: "strain",
                   Status.NOT_SPD: "not-spd"}



class Phase(IntEnum):
    """The parts of an integrator call whose time the phase profile reports
    (``ImplicitEuler.last_profile``, ``SymplecticEuler.last_profile``): indices of the kernels'
    profile array, whose last entry (:data:`N_PHASES`) holds the whole loop's count."""

    FORCES = 0  # the forces at the start of each step (explicit: its only force evaluation)
    PREPARE = 1  # air drag's linearisation, the lumped mass, the obstacle contacts' constraints and friction
    ASSEMBLY = 2  # the stiffness blocks, and the preconditioner's set-up but for the band factor
    RHS = 3  # the right-hand side (BDF2: with its history terms)
    FACTOR = 4  # the band preconditioner's Cholesky factorisation
    SOLVE = 5  # the first PCG solve, less its factorisation (explicit: the velocity and position update)
    FRICTION = 6  # the friction re-solve, less its factorisation
    NEWTON = 7  # Newton passes after the first, less their factorisations
    OBSTACLES = 8  # analytic obstacles (moving them, contact), the strain limiter
    COLLISION = 9  # the collision pass: mesh obstacles, self-collision
    CHECKS = 10  # the divergence check


N_PHASES = len(Phase)
PHASE_NAMES = tuple(p.name.lower() for p in Phase)
# plain ints for the kernels
P_FORCES, P_PREPARE, P_ASSEMBLY, P_RHS, P_FACTOR, P_SOLVE = 0, 1, 2, 3, 4, 5
P_FRICTION, P_NEWTON, P_OBSTACLES, P_COLLISION, P_CHECKS = 6, 7, 8, 9, 10
# after the phases, the profile array holds the whole loop's count (N_PHASES), then two parts of
# every PCG solve (inside the solve, friction and Newton phases): the operator's products ``A·p``
# and the preconditioner's applies
P_CG_PRODUCT, P_CG_PRECONDITION = N_PHASES + 1, N_PHASES + 2
PROFILE_SIZE = N_PHASES + 3


class Force(IntEnum):
    """Bits of :attr:`ForceData.flags`: which forces a model computes."""

    GRAVITY = 1 << 0
    STRETCH = 1 << 1
    BENDING = 1 << 2
    SHEAR = 1 << 3
    AIR = 1 << 4
    DAMPING = 1 << 5  # the paper's damping of absolute velocity (mass-proportional)
    BREEN = 1 << 6  # Breen's laws instead of the KES model
    STRAIN_DAMPING = 1 << 7  # the material's damping of the rates of deformation


class ForceData(NamedTuple):
    """The model's forces as the kernels read them (units CGS: cm, g, s, dyne).

    flags: :class:`Force` bits. mass: (N,) g. area: (N,) cm², the fabric each particle stands
    for. gravity: (3,) cm/s². damping_rate: λ of the
    absolute (mass-proportional) damping, 1/s. damping_time: β of the strain-rate damping, s.
    alpha: the KES compression factor. c_air: air-drag coefficient, g/cm³. sigma: lattice spacing,
    cm. edges (E, 2), edge_dir (E,), rest (E,) cm, edge_width (E,) (in σ), stretch_coef (2, 2),
    breen_c0 (dyne·cm): stretch. triples (B, 3), bend_dir (B,), bend_width (B,), bend_length (B,) (in σ),
    bend_coef (2, 3),
    x0_curv (1/cm): bending. corners (S, 3), shear_coef (3,), x0_shear (degrees): shear. tris
    (T, 3): the triangles of the air drag's normals.
    """

    flags: int
    mass: np.ndarray
    area: np.ndarray
    gravity: np.ndarray
    damping_rate: float
    damping_time: float
    alpha: float
    c_air: float
    sigma: float
    edges: np.ndarray
    edge_dir: np.ndarray
    rest: np.ndarray
    edge_width: np.ndarray
    stretch_coef: np.ndarray
    breen_c0: float
    triples: np.ndarray
    bend_dir: np.ndarray
    bend_width: np.ndarray
    bend_length: np.ndarray
    bend_coef: np.ndarray
    x0_curv: float
    corners: np.ndarray
    shear_coef: np.ndarray
    x0_shear: float
    tris: np.ndarray


class ObstacleData(NamedTuple):
    """The analytic obstacles (plane, box, sphere, cylinder) as packed by
    :func:`~cloth_gym.sim.obstacles.pack_obstacles`: types (K,), params (K, 9) at their model
    placement, friction (K,); the material's restitution and the contact thickness (cm)."""

    types: np.ndarray
    params: np.ndarray
    friction: np.ndarray
    restitution: float
    thickness: float


class CollisionData(NamedTuple):
    """The collision pass's inputs (:func:`~cloth_gym.sim.collision.collision_args`): flags,
    iterations, self-contact thickness (cm) and friction, the triangles, triangle edges and points
    tested, the pair lists' Verlet margin (cm), then the mesh obstacles' vertices (mv), faces (mf),
    face normals (mn), friction (mmu) and their uniform grid (g_lo, g_inv_cell, g_dims, g_start,
    g_items) with its visit stamps."""

    flags: int
    iterations: int
    thickness_self: float
    mu_self: float
    tris: np.ndarray
    tri_edges: np.ndarray
    point_idx: np.ndarray
    margin: float
    mv: np.ndarray
    mf: np.ndarray
    mn: np.ndarray
    mmu: np.ndarray
    g_lo: np.ndarray
    g_inv_cell: float
    g_dims: np.ndarray
    g_start: np.ndarray
    g_items: np.ndarray
    stamp: np.ndarray


class NoCollisionPass(CollisionData):
    """The :class:`CollisionData` of a model without a collision pass (no self-collision, no mesh
    obstacle): the same fields, its own type, so that a step compiled for it holds none of the
    collision pass's code (:func:`~cloth_gym.sim.collision_kernels.run_collision_pass`)."""

    __slots__ = ()


class World(NamedTuple):
    """Everything but the cloth that one integrator call moves or reads: the obstacles (their
    static data, ``prm`` the parameters where they are now, ``offset`` (K, 3) cm from their model
    placement, advanced in place, and ``vel`` (K, 3) cm/s), the contact record ``touching`` (N,)
    (obstacle each particle touched in the last step, −1: none; updated in place) and the collision
    pass's data."""

    obstacles: ObstacleData
    prm: np.ndarray
    offset: np.ndarray
    vel: np.ndarray
    touching: np.ndarray
    collision: CollisionData  # or NoCollisionPass


class Guard(NamedTuple):
    """Divergence thresholds and the strain limiter of a run: a particle faster than
    ``max_speed`` (cm/s) or an edge longer than ``1 + max_strain_percent/100`` of its rest length
    ends the run; ``strain_limit`` (a fraction, 0: off) and ``strain_iters`` configure
    :func:`~cloth_gym.sim.substep.limit_strain`."""

    max_speed: float
    max_strain_percent: float
    strain_limit: float
    strain_iters: int


class Unlimited(Guard):
    """The :class:`Guard` of a run without the strain limiter (``strain_limit`` 0): the same
    fields, its own type, so that a step compiled for it holds none of the limiter's code
    (:func:`~cloth_gym.sim.substep.limiter_stage`)."""

    __slots__ = ()
