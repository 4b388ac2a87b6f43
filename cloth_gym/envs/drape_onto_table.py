"""DrapeOntoTable: lay a hanging tablecloth over a table, centred, with even overhang."""

from __future__ import annotations

import math

import numpy as np

from ..sim._numba import njit_brief
from ..sim.lattice import Rectangle, build_cloth
from ..sim.model import ForceOptions, Model
from ..sim.obstacles import Box, Plane
from . import DRAPE_ONTO_TABLE_V2, V1
from .base import ClothEnv, ClothPhysics

__all__ = ["DrapeOntoTableEnv", "table_coverage", "overhangs"]

CLOTH_CM = 40.0
TABLE_HALF_CM = 10.0
TABLE_HEIGHT_CM = 40.0
# local (warp, weft, normal) → world: warp along x, weft pointing down (j = 0 edge on top)
HANGING = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def table_coverage(model: Model, q: np.ndarray, half: float, top_z: float = 0.0, spacing: float = 2.0) -> float:
    """Fraction of the table top covered by cloth: sample points on a grid of ``spacing`` cm;
    a point is covered when it lies, in the xy projection, under a cloth triangle that rests on
    the top: its particles at most 1 cm above the top and at most 1.5 σ below it (a triangle
    folding over the table's edge still covers the strip up to the edge). A point on a
    triangle's edge counts as under it."""
    s = np.arange(-half + spacing / 2, half, spacing)
    return _coverage(np.ascontiguousarray(q, dtype=np.float64), model.tri_indices, s, float(top_z),
                     1.5 * float(model.sigma))


@njit_brief
def _coverage(q, tri, s, top_z, below):
    """The kernel of :func:`table_coverage`: sample points (s_i, s_j); the triangles resting on the
    top are found once, then each point is tested until one triangle holds it."""
    on = np.empty(tri.shape[0], dtype=np.int64)
    n_on = 0
    for t in range(tri.shape[0]):
        ok = True
        for k in range(3):
            z = q[tri[t, k], 2] - top_z
            if not (z < 1.0 and z > -below):
                ok = False
        if ok:
            on[n_on] = t
            n_on += 1
    if n_on == 0:
        return 0.0
    covered = 0
    for i in range(s.shape[0]):
        for j in range(s.shape[0]):
            px = s[i]
            py = s[j]
            for m in range(n_on):
                t = on[m]
                ax, ay = q[tri[t, 0], 0], q[tri[t, 0], 1]
                bx, by = q[tri[t, 1], 0], q[tri[t, 1], 1]
                cx, cy = q[tri[t, 2], 0], q[tri[t, 2], 1]
                d1 = (bx - ax) * (py - ay) - (by - ay) * (px - ax)
                d2 = (cx - bx) * (py - by) - (cy - by) * (px - bx)
                d3 = (ax - cx) * (py - cy) - (ay - cy) * (px - cx)
                neg = d1 < 0 or d2 < 0 or d3 < 0
                pos = d1 > 0 or d2 > 0 or d3 > 0
                if not (neg and pos):
                    covered += 1
                    break
    return covered / (s.shape[0] * s.shape[0])


def overhangs(q: np.ndarray, half: float, top_z: float = 0.0) -> np.ndarray:
    """(4,) overhang (cm) beyond the table's −x, +x, −y, +y edges: over the particles beyond that
    edge and along its middle half (away from the corners, where a drape hangs lower), the largest distance from the edge line,
    ``sqrt(h² + d²)`` with h the horizontal distance past the edge and d the drop below the top
    (the hanging length of a straight flap, whatever its angle); 0 if none."""
    out = np.zeros(4)
    _overhangs(np.ascontiguousarray(q, dtype=np.float64), float(half), float(top_z), out)
    return out


@njit_brief
def _overhangs(q, half, top_z, out):
    for k in range(4):
        axis = 0 if k < 2 else 1
        sign = -1.0 if k % 2 == 0 else 1.0
        best = 0.0
        for p in range(q.shape[0]):
            beyond = sign * q[p, axis] - half
            if beyond > 0 and abs(q[p, 1 - axis]) <= 0.5 * half:
                drop = max(top_z - q[p, 2], 0.0)
                best = max(best, math.hypot(beyond, drop))
        out[k] = best


class DrapeOntoTableEnv(ClothEnv):
    """
    ## Description
    A 40 × 40 cm tablecloth (thick cotton) hangs from two point grippers holding two adjacent
    corners (its top edge) beside a 20 × 20 cm table (top at z = 0, a solid block down to the
    floor at z = −40 cm). Lay it over the table, centred, covering the top, with an even
    overhang of 10 cm on every side, and let go.

    ## Action Space
    ``Box(-1, 1, (8,), float32)``: ``[dx, dy, dz, grip]`` for gripper 0 (the x < 0 corner), then
    gripper 1; displacements scaled to ±``max_step_cm`` = 2 cm per control step, grip > 0
    closes (within ``grasp_radius_cm`` = 1.5 cm), ≤ 0 opens and releases the corner with the
    gripper's velocity. Actions are clipped; a non-finite one raises
    :class:`~cloth_gym.errors.ConfigError`. Grippers stay 0.5 cm clear of table and floor and
    inside x ∈ [−45, 45], y ∈ [−50, 45], z ∈ [−39, 60] cm; a grasp that strains an edge past
    ``slip_strain_percent`` (30 %) slips.

    ## Observation Space
    ``"state"`` (default): ``Box((6N + 10,), float64)``, N = 121: positions (cm), velocities
    (cm/s), then each gripper's position, closed (0/1) and particles held. ``"keypoints"``:
    ``(40,)``, the four corners and the centre, then the grippers. ``"rgb"``: images.

    ## Rewards
    With c ∈ [0, 1] the covered fraction of the table top (:func:`table_coverage`), o_s the
    overhang beyond side s (:func:`overhangs`, cm), e = mean_s |o_s − 10 cm| / 10 cm,
    u = 1 − tanh(e), ℓ = c⁴ · u (laid), h ∈ {0, ½, 1} the fraction of grippers holding cloth, k
    the fraction closed, d the xy distance (cm) from the cloth's centroid to the table's centre,
    a the action:

    * ``reward_hold = w_hold · (h + (1 − h) · ℓ)``                   (w_hold = 0.5)
    * ``reward_reach = w_reach · (1 − tanh(d / 20 cm))``            (w_reach = 1.0)
    * ``reward_coverage = w_coverage · c``                          (w_coverage = 1.0)
    * ``reward_overhang = w_overhang · u``                          (w_overhang = 1.0)
    * ``reward_release = w_release · (1 − k) · ℓ``                  (w_release = 1.0)
    * ``reward_ctrl = −w_ctrl · ‖a_xyz‖²`` (both grippers)          (w_ctrl = 0.01)
    * ``reward_success = w_success · 1[success]``                   (w_success = 2.0)

    ``reward`` is their sum (each term in ``info``, at most 6.5 per step). Success
    (``info["is_success"]``): c ≥ 0.95, every |o_s − 10 cm| ≤ 3 cm, both grippers open.

    ## Starting State
    The cloth hangs flat and vertical, its top edge held by the closed grippers, centred at
    x = 0, y = −30 cm, top edge at z = 45 cm, shifted by up to ±3 cm in x, y and ±2 cm in z.

    ## Episode End
    Never terminates; truncated at 150 steps (7.5 s) or when the simulation diverges
    (``info["diverged"] = True``, zero reward, the last finite observation).

    ## Arguments
    As :class:`~cloth_gym.envs.corner_lift.CornerLiftEnv`, with ``sigma`` 4 cm, ``sim_dt``
    5 ms, ``solver_tol`` 1e-3 (line preconditioner), ``reward_weights`` keys ``hold``,
    ``reach``, ``coverage``, ``overhang``, ``release``, ``ctrl``, ``success``, and
    ``slow_sim_dt`` (0.025 s; 0: off) and ``slow_speed`` (1 cm/s): the substep of a released
    cloth that moves slower than that. ``FAST_OPTIONS``: 10 ms substeps, 1 % strain limiter.
    The measurements behind the defaults: ``docs/envs.md``, "DrapeOntoTable".

    ## Version History
    * v0: initial release.
    """

    n_grippers = 2
    #: 5 ms substeps; a settling cloth: 25 ms substeps below 1 cm/s; CG tolerance 1e-3, its error ~10x
    #: below the 5 ms substeps' (docs/envs.md); the line preconditioner (the band factor costs more
    #: than the iterations it saves here)
    defaults = {"sigma": 4.0, "control_dt": 0.05,
                "sim_defaults": {"max_dt": 5e-3, "slow_dt": 0.025, "tol": 1e-3, "preconditioner": "lines"}}
    #: kwargs for 10 ms substeps with the 1 % limiter and tolerance 1e-3 (docs/envs.md)
    FAST_OPTIONS = {"sim_dt": 0.01, "strain_limiter_percent": 1.0, "solver_tol": 1e-3}
    default_reward_weights = {"hold": 0.5, "reach": 1.0, "coverage": 1.0, "overhang": 1.0, "release": 1.0,
                              "ctrl": 0.01, "success": 2.0}
    reach_scale_cm = 20.0
    cloth_cm = CLOTH_CM
    table_half_cm = TABLE_HALF_CM
    target_overhang_cm = (CLOTH_CM - 2 * TABLE_HALF_CM) / 2
    overhang_tolerance_cm = 3.0
    coverage_threshold = 0.95
    start_center = np.array([0.0, -30.0, 45.0 - CLOTH_CM / 2])

    def _build_model(self, material, options: ForceOptions, sigma: float) -> Model:
        table = Box((0.0, 0.0, -TABLE_HEIGHT_CM / 2), (TABLE_HALF_CM, TABLE_HALF_CM, TABLE_HEIGHT_CM / 2))
        floor = Plane((0.0, 0.0, -TABLE_HEIGHT_CM), (0.0, 0.0, 1.0))
        return build_cloth(Rectangle(CLOTH_CM, CLOTH_CM), material, sigma=sigma, options=options,
                           origin=self.start_center, rotation=HANGING, obstacles=[table, floor],
                           contact_thickness=0.1)

    def _workspace(self):
        return np.array([-45.0, -50.0, -TABLE_HEIGHT_CM + 1.0]), np.array([45.0, 45.0, 60.0])

    def held_corners(self, model: Model) -> np.ndarray:
        return np.array([model.index(0, 0), model.index(-1, 0)])

    def _reset_task(self, physics: ClothPhysics, rng: np.random.Generator, options: dict) -> None:
        offset = np.array([*rng.uniform(-3.0, 3.0, 2), rng.uniform(-2.0, 2.0)])
        physics.state.particle_q[:] = physics.model.particle_q0 + offset
        corners = self.held_corners(physics.model)
        physics.grippers.reset(physics.state.particle_q[corners])
        for g, p in enumerate(corners):
            physics.grippers.grasp(g, physics.state, [p])

    def _keypoint_indices(self, model: Model) -> np.ndarray:
        nx, ny = model.grid_index.shape
        return np.array([model.index(0, 0), model.index(-1, 0), model.index(-1, -1), model.index(0, -1),
                         model.index(nx // 2, ny // 2)])

    def _compute_measure(self, physics: ClothPhysics):
        """(table coverage, |overhang − target| per side in cm)."""
        q = physics.state.particle_q
        err = np.abs(overhangs(q, TABLE_HALF_CM) - self.target_overhang_cm)
        return table_coverage(physics.model, q, TABLE_HALF_CM), err

    def _success(self, physics, cov, err) -> bool:
        return bool(cov >= self.coverage_threshold and max(err.tolist()) <= self.overhang_tolerance_cm
                    and not any(physics.grippers.closed.tolist()))

    def _is_success(self, physics: ClothPhysics) -> bool:
        return self._success(physics, *self._measure(physics))

    def _reward_terms(self, physics: ClothPhysics, action: np.ndarray) -> dict:
        w = self.reward_weights
        cov, err = self._measure(physics)
        g = physics.grippers
        n = self.n_grippers
        # plain floats: these few numbers cost more as numpy calls than the rest of the reward
        holding = set(g.held_by[g.held_by >= 0].tolist())
        held = len(holding) / n
        closed = sum(bool(c) for c in g.closed) / n
        score = 1.0 - math.tanh(sum(err.tolist()) / len(err) / self.target_overhang_cm)
        cx, cy = physics.state.particle_q[:, :2].mean(axis=0).tolist()
        laid = cov ** 4 * score
        return {
            "reward_hold": w["hold"] * (held + (1.0 - held) * laid),
            "reward_reach": w["reach"] * (1.0 - math.tanh(math.hypot(cx, cy) / self.reach_scale_cm)),
            "reward_coverage": w["coverage"] * cov,
            "reward_overhang": w["overhang"] * score,
            "reward_release": w["release"] * (1.0 - closed) * laid,
            "reward_ctrl": -w["ctrl"] * sum(x * x for x in action[:, :3].ravel().tolist()),
            "reward_success": w["success"] * float(self._success(physics, cov, err)),
        }

    def _camera(self):
        from ..render import Camera

        return Camera.look_at(eye=(55.0, -75.0, 60.0), target=(0.0, -8.0, 5.0), up=(0, 0, 1), fov_deg=45)

    def _picture_camera(self):
        """The hanging start, the table and the target hem line, from the front right."""
        from ..render import Camera

        return Camera.look_at(eye=(70.0, -75.0, 80.0), target=(-1.0, -10.0, 8.0), up=(0, 0, 1), fov_deg=38)

    def _target_meshes(self, physics: ClothPhysics) -> list:
        """Where the hem should hang: a band 1 cm high round the table, ``target_overhang_cm``
        below its top, just outside its sides (the draped cloth covers it)."""
        from ..render.shapes import box_mesh

        h = self.table_half_cm + 0.05
        return [(*box_mesh((0.0, 0.0, -self.target_overhang_cm), (h, h, 0.5)), self.target_rgb)]


class DrapeOntoTableV1Env(DrapeOntoTableEnv):
    """
    ## Description
    ``cloth_gym/DrapeOntoTable-v1``: the task of :class:`DrapeOntoTableEnv` (action space,
    rewards, starting state, success, episode end and arguments are the same) on the cloth at
    real fabric resolution, with the simulator's own lattice conventions
    (``cloth_gym.envs.V1``, ``gymnasium.spec(id).kwargs``; this class only makes them its defaults):

    | | v0 | v1 |
    |---|---|---|
    | lattice spacing ``sigma`` | 4 cm (121 particles) | 1 cm (1,681 particles) |
    | ``mass_lumping`` | ``"uniform"`` (a 44 × 44 cm cloth's mass) | ``"area"`` (a 40 × 40 cm cloth's) |
    | ``damping_model`` | ``"absolute"`` | ``"strain-rate"`` |
    | ``observation_dtype`` | ``"float64"`` | ``"float32"`` |
    | a particle that slipped from a closed gripper | grasped again at the next step | grasped again only after the gripper opens |
    | substeps of a fast-moving cloth | ``sim_dt`` | at most half a lattice spacing of travel per substep (``sim={"max_travel": 0.5}``) |

    ## Observation Space
    ``observation_mode="state"``: ``Box(-inf, inf, (10,096,), float32)``: 1,681 particles'
    positions and velocities, then the two grippers and the task entries as in v0.
    ``"keypoints"`` and ``"rgb"`` as in v0 (keypoints float32).

    ## Defaults
    Measured in ``docs/envs.md`` under "DrapeOntoTable-v1".

    ## Version History
    * v1: σ = 1 cm, area-lumped mass, strain-rate damping, float32 observations, no re-grasp
      of a slipped particle before the gripper opens, at most half a lattice spacing of travel
      per substep, gripper entries of the observation Box bounded.
    * v0: initial release (:class:`DrapeOntoTableEnv`).
    """

    #: v0's fast settings (10 ms substeps with a 1 % strain limiter) were measured on v0's lattice only
    defaults = V1
    FAST_OPTIONS = None


class DrapeOntoTableV2Env(DrapeOntoTableEnv):
    """
    ## Description
    ``cloth_gym/DrapeOntoTable-v2``: :class:`DrapeOntoTableV1Env` (the same task, cloth and
    arguments) with a control step that diverges run again rather than ending the episode
    (``cloth_gym.envs.DRAPE_ONTO_TABLE_V2``: ``sim_defaults`` ``retry_diverged=True``). The
    implicit step takes one linearised Newton pass per substep; shaken hard (a gripper reversing
    at full speed every step next to a stiff corner) that pass can overshoot where the stretch
    stiffens and tear the cloth past the divergence guard. v2 then runs the same control step
    again from its start with Newton iterated to convergence and a line search, and the episode
    goes on; only a step that diverges that way too truncates it (``info["diverged"]``).

    A step that does not diverge is computed exactly as in v1, at v1's cost, so every episode
    that v1 ends without a divergence is the same in v2, to the bit. A retried step costs about
    ten of v1's. Measured under a jerk policy on randomised fabrics in ``docs/numerics.md``,
    "Shaking a cloth".

    ## Version History
    * v2: a diverged control step is run again with converged Newton passes.
    * v1: :class:`DrapeOntoTableV1Env`.
    * v0: :class:`DrapeOntoTableEnv`.
    """

    defaults = DRAPE_ONTO_TABLE_V2
    FAST_OPTIONS = None
