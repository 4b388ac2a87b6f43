"""Point grippers that grasp cloth particles and carry them kinematically.

A gripper is a point in the world (cm) with an open/closed state. Its action is
``[dx, dy, dz, grip] ∈ [−1, 1]⁴``:

* ``dx, dy, dz`` are scaled by :attr:`GripperConfig.max_step_cm`: the gripper
  moves by at most that many cm per axis in one control step (its velocity over
  the step is the displacement divided by the control interval);
* ``grip > 0`` closes the gripper, ``grip ≤ 0`` opens it. A closed gripper
  that holds nothing grasps every free particle within
  :attr:`GripperConfig.grasp_radius_cm` of its point, at every control step
  until it holds some (SoftGym's picker does the same); so an agent can close
  first and then reach, and a grasp needs no exact open → closed timing (with
  that timing, PPO found no grasp in CornerLift in 90k steps). Grasped particles keep
  their offset to the gripper and move with it exactly (they are passed to the
  integrators as ``Control.kinematic`` with the gripper's velocity). Opening
  releases them with the gripper's velocity of the last control step.
* The gripper point is kept at least :attr:`GripperConfig.clearance_cm` away
  from every obstacle (table, floor: it cannot pass through them) and inside
  the task's workspace box; a gripper carrying particles is also stopped where
  one of them would come within the contact thickness of an obstacle (held
  particles are kinematic, so the simulator does not collide them).
* **Slip**: after every control step, while a grasped particle has an
  incident lattice edge stretched past :attr:`GripperConfig.slip_strain_percent`,
  the grasped particle with the most strained edge is released (with the
  gripper's velocity), so a grasp that would tear the cloth slips instead of
  exploding. (A check before the step, with the neighbours where they were,
  would release any particle moved by more than 30 % of σ in one step.)
  With :attr:`GripperConfig.regrasp_slipped` False (the v1 envs) a particle that slipped is
  not grasped again until its gripper opens; otherwise (v0) a closed gripper left holding
  nothing grasps it again at the next step, and a grasp pulled taut slips and re-grasps over
  and over while the strain ratchets up.

The grippers hold no simulator: :meth:`Grippers.prepare` writes the held
particles' velocities into a state and returns the kinematic mask for the
step; :meth:`Grippers.after_step` applies the slip check to the state reached.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..sim._numba import njit_brief
from ..sim.model import Model, State
from ..sim.obstacles import signed_distance
from ..validation import flag, real

__all__ = ["GripperConfig", "Grippers"]


@dataclass(frozen=True)
class GripperConfig:
    """Gripper constants (CGS).

    max_step_cm: largest displacement per axis in one control step, cm (action ±1).
    grasp_radius_cm: particles within this distance of a closing gripper are grasped, cm.
    slip_strain_percent: a grasped particle slips (is released) when one of its edges
        would be stretched past this strain, percent.
    clearance_cm: smallest distance kept between the gripper point and any obstacle, cm.
    regrasp_slipped: may a closed gripper grasp again a particle that slipped from it before
        it opens (the v0 envs: yes)?
    """

    max_step_cm: float = 2.0
    grasp_radius_cm: float = 1.5
    slip_strain_percent: float = 30.0
    clearance_cm: float = 0.5
    regrasp_slipped: bool = True

    def __post_init__(self):
        for name, lo, hi in (("max_step_cm", 0.0, 100.0), ("grasp_radius_cm", 0.0, 100.0),
                             ("slip_strain_percent", 0.0, 1000.0), ("clearance_cm", 0.0, 100.0)):
            real(name, getattr(self, name), lo, hi, lo_open=True, unit="%" if name.endswith("percent") else "cm")
        flag("regrasp_slipped", self.regrasp_slipped)


class Grippers:
    """``count`` point grippers acting on one model (see the module docstring).

    Attributes
    ----------
    position
        (G, 3) gripper points, cm.
    velocity
        (G, 3) gripper velocities over the last control step, cm/s.
    closed
        (G,) bool.
    held_by
        (N,) int, index of the gripper holding each particle, −1 if free.
    slipped
        (N,) int, index of the gripper each particle slipped from since that gripper last
        opened, −1 if none.
    """

    def __init__(self, model: Model, count: int, config: GripperConfig,
                 workspace_low, workspace_high):
        self.model = model
        self.count = int(count)
        self.config = config
        self.low = np.asarray(workspace_low, dtype=float)
        self.high = np.asarray(workspace_high, dtype=float)
        n = model.particle_count
        self.position = np.zeros((count, 3))
        self.velocity = np.zeros((count, 3))
        self.closed = np.zeros(count, dtype=bool)
        self.held_by = -np.ones(n, dtype=np.int64)
        self.slipped = -np.ones(n, dtype=np.int64)
        self.slips = 0
        # particle → incident edges (CSR), for the slip check
        e = model.edge_indices
        ends = np.concatenate([e[:, 0], e[:, 1]])
        eid = np.concatenate([np.arange(len(e)), np.arange(len(e))])
        order = np.argsort(ends, kind="stable")
        self._inc_edges = eid[order]
        self._inc_off = np.zeros(n + 1, dtype=np.int64)
        np.add.at(self._inc_off, ends + 1, 1)
        self._inc_off = np.cumsum(self._inc_off)
        self._types, self._params, _ = model.obstacle_arrays

    # ------------------------------------------------------------------ state
    #: what changes during an episode (everything else follows from the model and the config)
    EPISODE_FIELDS = ("position", "velocity", "closed", "held_by", "slipped", "slips")

    def snapshot(self) -> dict:
        """The grippers' episode state (:data:`EPISODE_FIELDS`), copied."""
        return {k: np.copy(getattr(self, k)) if isinstance(getattr(self, k), np.ndarray) else getattr(self, k)
                for k in self.EPISODE_FIELDS}

    def restore(self, snap: dict) -> None:
        """Set the episode state from :meth:`snapshot`'s dict (copied in)."""
        self.slipped[:] = -1  # a snapshot pickled before ``slipped`` existed has none
        for k in self.EPISODE_FIELDS:
            if k not in snap:
                continue
            v = snap[k]
            setattr(self, k, np.array(v, copy=True) if isinstance(v, np.ndarray) else v)

    def reset(self, positions) -> None:
        """Open grippers at ``positions`` (G, 3) cm, holding nothing."""
        self.position[:] = self.clamp(np.asarray(positions, dtype=float).reshape(self.count, 3))
        self.velocity[:] = 0.0
        self.closed[:] = False
        self.held_by[:] = -1
        self.slipped[:] = -1
        self.slips = 0

    def grasp(self, g: int, state: State, particles=None, around=None) -> np.ndarray:
        """Close gripper ``g`` and grasp ``particles`` (default: the free ones within the radius of
        ``around``, default the gripper's point)."""
        if particles is None:
            d = np.linalg.norm(state.particle_q - (self.position[g] if around is None else around), axis=1)
            ok = (d <= self.config.grasp_radius_cm) & (self.held_by < 0) & (self.model.particle_inv_mass > 0)
            if not self.config.regrasp_slipped:
                ok &= self.slipped < 0
            particles = np.nonzero(ok)[0]
        particles = np.asarray(particles, dtype=np.int64)
        self.held_by[particles] = g
        self.closed[g] = True
        return particles

    def release(self, g: int, state: State) -> None:
        """Open gripper ``g``: its particles go free with the gripper's velocity."""
        held = self.held_by == g
        state.particle_qd[held] = self.velocity[g]
        self.held_by[held] = -1
        self.slipped[self.slipped == g] = -1
        self.closed[g] = False

    def held(self, g: int) -> np.ndarray:
        return np.nonzero(self.held_by == g)[0]

    def clamp(self, points: np.ndarray) -> np.ndarray:
        """Points moved into the workspace and out of the obstacles (to the clearance)."""
        out = np.array(points, dtype=np.float64, order="C", copy=True).reshape(-1, 3)
        push_points_out(out, self._types, self._params, float(self.config.clearance_cm), self.low, self.high)
        return out

    def _keep_load_clear(self, target: np.ndarray, state: State) -> np.ndarray:
        """Raise each gripper's target so that the particles it carries stay out of the obstacles
        (kinematic particles are not collided by the simulator: the gripper must not push them in)."""
        lift_carried(target, self.position, state.particle_q, self.held_by, self._types, self._params,
                     float(self.model.contact_thickness))
        return target

    # ------------------------------------------------------------------ control step
    def prepare(self, actions: np.ndarray, state: State, dt: float) -> np.ndarray:
        """Apply ``actions`` (G, 4) in [−1, 1] for a control step of ``dt`` s.

        Opens/closes the grippers, moves their points, writes the held particles'
        velocities into ``state.particle_qd`` and returns the (N,) kinematic mask."""
        for g in range(self.count):
            want_closed = actions[g, 3] > 0.0
            if self.closed[g] and not want_closed:
                self.release(g, state)
        target = self.clamp(self.position + actions[:, :3] * self.config.max_step_cm)
        target = self._keep_load_clear(target, state)
        grasped = False
        for g in range(self.count):
            if actions[g, 3] > 0.0 and (not self.closed[g] or not np.any(self.held_by == g)):
                grasped |= self.grasp(g, state, around=target[g]).size > 0
        if grasped:  # what was just grasped moves with the gripper this step: keep it out of the obstacles too
            target = self._keep_load_clear(target, state)
        self.velocity = (target - self.position) / dt
        self.position = target
        held = np.empty(self.held_by.shape[0], dtype=np.bool_)
        carry_velocities(self.held_by, self.velocity, state.particle_qd, held)
        return held

    def after_step(self, state: State) -> None:
        """Slip check on the state reached."""
        self._slip(state.particle_q, state)

    def _slip(self, q: np.ndarray, state: State) -> None:
        limit = 1.0 + self.config.slip_strain_percent / 100.0
        e = self.model.edge_indices
        while True:
            k, stretch = most_stretched_held_edge(q, self.held_by, self._inc_edges, self._inc_off, e,
                                                  self.model.edge_rest_length)
            if k < 0 or stretch <= limit:
                return
            a, b = e[k]
            p = a if self.held_by[a] >= 0 else b
            g = self.held_by[p]
            self.held_by[p] = -1
            self.slipped[p] = g
            state.particle_qd[p] = self.velocity[g]
            q = q.copy()
            q[p] = state.particle_q[p] + 0.0  # no longer carried: it stays where it is
            self.slips += 1

    def observation(self) -> np.ndarray:
        """(G, 5): position (cm), closed (0/1), number of particles held."""
        counts = np.bincount(self.held_by + 1, minlength=self.count + 1)[1:].astype(float)
        return np.concatenate([self.position, self.closed[:, None].astype(float), counts[:, None]], axis=1)


# ---------------------------------------------------------------- kernels
@njit_brief
def most_stretched_held_edge(q, held_by, inc_edges, inc_off, edges, rest):
    """(edge, stretch) of the lattice edge with the largest stretch |x_b − x_a| / rest among the
    edges at a held particle (``held_by`` ≥ 0; ``inc_edges[inc_off[p]:inc_off[p + 1]]`` are p's
    edges), the first at a tie, held particles in index order; (−1, 0.0) when no held particle has
    an edge. The length is √((dx² + dy²) + dz²), as numpy's norm sums three components."""
    best, best_stretch = -1, 0.0
    for p in range(held_by.shape[0]):
        if held_by[p] < 0:
            continue
        for j in range(inc_off[p], inc_off[p + 1]):
            k = inc_edges[j]
            a, b = edges[k, 0], edges[k, 1]
            dx, dy, dz = q[b, 0] - q[a, 0], q[b, 1] - q[a, 1], q[b, 2] - q[a, 2]
            stretch = np.sqrt(dx * dx + dy * dy + dz * dz) / rest[k]
            if best < 0 or stretch > best_stretch:
                best, best_stretch = k, stretch
    return best, best_stretch


@njit_brief
def push_points_out(points, types, params, clearance, low, high):
    """Move each point of ``points`` (G, 3) cm, in place, into the box [low, high] and at least
    ``clearance`` cm outside every obstacle: up to three pushes along the outward normals (a point
    in a corner between two obstacles needs more than one), then clipped to the box again."""
    for g in range(points.shape[0]):
        for i in range(3):
            points[g, i] = min(max(points[g, i], low[i]), high[i])
        for _ in range(3):
            moved = False
            for k in range(types.shape[0]):
                d, n0, n1, n2 = signed_distance(types[k], params[k], points[g, 0], points[g, 1], points[g, 2])
                if d < clearance:
                    points[g, 0] += (clearance - d) * n0
                    points[g, 1] += (clearance - d) * n1
                    points[g, 2] += (clearance - d) * n2
                    moved = True
            if not moved:
                break
        for i in range(3):
            points[g, i] = min(max(points[g, i], low[i]), high[i])


@njit_brief
def carry_velocities(held_by, velocity, qd, held):
    """``held[p]``: is particle p held (``held_by[p]`` ≥ 0); each held particle's velocity ``qd[p]``
    (cm/s) set to its gripper's, ``velocity[held_by[p]]``."""
    for p in range(held_by.shape[0]):
        g = held_by[p]
        held[p] = g >= 0
        if g >= 0:
            qd[p, 0], qd[p, 1], qd[p, 2] = velocity[g, 0], velocity[g, 1], velocity[g, 2]


@njit_brief
def lift_carried(target, position, q, held_by, types, params, thickness):
    """Raise each carrier's ``target`` (G, 3) cm, in place, so that the particles it carries
    (``held_by == g``), moved rigidly by ``target − position``, stay at least ``thickness`` cm outside
    every obstacle: up to three passes over its particles, each pushing the target along the
    obstacle normal by the particle's penetration."""
    for g in range(target.shape[0]):
        carries = False
        for p in range(q.shape[0]):
            if held_by[p] == g:
                carries = True
                break
        if not carries:
            continue
        for _ in range(3):
            moved = False
            for p in range(q.shape[0]):
                if held_by[p] != g:
                    continue
                for k in range(types.shape[0]):
                    d, n0, n1, n2 = signed_distance(types[k], params[k], q[p, 0] + target[g, 0] - position[g, 0],
                                                    q[p, 1] + target[g, 1] - position[g, 1],
                                                    q[p, 2] + target[g, 2] - position[g, 2])
                    if d < thickness - 1e-9:
                        target[g, 0] += (thickness - d) * n0
                        target[g, 1] += (thickness - d) * n1
                        target[g, 2] += (thickness - d) * n2
                        moved = True
            if not moved:
                break
