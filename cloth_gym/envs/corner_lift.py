"""CornerLift: grasp a corner of a cloth lying on a table and bring it to a target point."""

from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError
from ..sim._numba import njit_brief
from ..sim.diagnostics import max_edge_strain
from ..sim.lattice import Rectangle, build_cloth
from ..sim.model import ForceOptions, Model
from ..sim.obstacles import Box, Plane
from . import CORNER_LIFT_V1, CORNER_LIFT_V2
from .base import ClothEnv, ClothPhysics

__all__ = ["CornerLiftEnv", "CornerLiftGoalEnv", "CornerLiftV1Env", "CornerLiftV2Env", "CornerLiftGoalV2Env"]

TABLE_HALF_CM = 25.0
TABLE_HEIGHT_CM = 40.0
CLOTH_CM = 20.0


@njit_brief
def nearest_held_sq(q, held_by, c):
    """Squared distance, cm², from particle ``c`` to the nearest held particle (``held_by`` ≥ 0);
    inf when none is held, NaN when one is NaN. Each square is summed as NumPy's
    ``einsum("ij,ij->i")`` sums three columns, ``(dx² + dz²) + dy²`` (its two-lane loop), so that
    the test against a radius is einsum's to the bit (``tests/test_envs.py`` checks it)."""
    best = np.inf
    for p in range(held_by.shape[0]):
        if held_by[p] >= 0:
            dx, dy, dz = q[p, 0] - q[c, 0], q[p, 1] - q[c, 1], q[p, 2] - q[c, 2]
            sq = (dx * dx + dz * dz) + dy * dy
            if sq != sq:
                return sq
            best = min(best, sq)
    return best


def _yaw(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class CornerLiftEnv(ClothEnv):
    """
    ## Description
    A 20 × 20 cm cloth (thick cotton) lies flat on a 50 × 50 cm table (top at z = 0); one point
    gripper hovers above it. Grasp the cloth's lifted corner (lattice node (0, 0)) and bring it
    to a target point above the table without over-stretching the cloth.

    ## Action Space
    ``Box(-1, 1, (4,), float32)``: gripper dx, dy, dz (scaled to ±``max_step_cm`` = 2 cm per
    control step, 40 cm/s at the 0.05 s control interval) and grip (> 0 closes, grasping the
    particles within ``grasp_radius_cm`` = 1.5 cm; ≤ 0 opens). Actions are clipped; a
    non-finite one raises :class:`~cloth_gym.errors.ConfigError`. The gripper stays 0.5 cm
    above the table and inside x, y ∈ [−30, 30], z ∈ [0, 40] cm; a grasped particle whose edge
    would stretch past ``slip_strain_percent`` (30 %) slips (:mod:`cloth_gym.envs.grippers`).

    ## Observation Space
    ``"state"`` (default): ``Box((6N + 17,), float64)``, N = 121: particle positions (cm) and
    velocities (cm/s), the gripper (position, closed 0/1, particles held), the target, the
    lifted corner, corner − gripper and target − corner (cm). ``"keypoints"``: ``(47,)``, the
    four corners (lifted first) and the centre only. ``"rgb"``: ``(image_size, image_size, 3)``.

    ## Rewards
    With g the gripper, c the corner, d = ‖c − target‖, ε_max the largest edge strain (%), a the
    action, h = 1[corner held], k = 1[gripper closed], r = 1 − tanh(‖g − c‖ / 5 cm):

    * ``reward_reach = w_reach · (h + (1 − h) · r)``                    (w_reach = 1.0)
    * ``reward_grasp = w_grasp · (h + (1 − h) · k · r)``                (w_grasp = 0.5)
    * ``reward_distance = w_distance · (1 − tanh(d / 10 cm))``          (w_distance = 2.0)
    * ``reward_strain = −w_strain · max(0, ε_max − 10 %)``              (w_strain = 0.1 /%)
    * ``reward_ctrl = −w_ctrl · ‖a[:3]‖²``                             (w_ctrl = 0.01)
    * ``reward_success = w_success · 1[success]``                      (w_success = 2.0)

    ``reward`` is their sum (each term in ``info``, at most 5.5 per step); "held": a held particle
    within ``grasp_radius_cm`` + σ/2 of c. Success (``info["is_success"]``): d < 2 cm, ε_max < 10 %.

    ## Starting State
    The cloth flat, shifted up to ±3 cm in x, y and turned up to ±15°; the open gripper at xy in
    [−5, 5] cm, 5–10 cm up; the target the corner's start plus up to ±5 cm in x, y, 5–12 cm up.
    ``reset(options={"gripper_start": "corner" or "held"})``: the gripper over the corner, or
    already holding it part of the way (curriculum starts, :class:`cloth_gym.wrappers.StartCurriculum`).

    ## Episode End
    Never terminates; truncated at 100 steps (5 s) or when the simulation diverges
    (``info["diverged"] = True``, zero reward, the last finite observation).

    ## Arguments
    ``material`` (name, YAML path, ``Material``, mapping or randomisation dict), ``model``
    (``"kes"``/``"breen"``), ``integrator`` (``"implicit"``/``"explicit"``), ``sigma`` (2 cm),
    ``control_dt`` (0.05 s), ``sim_dt`` (0.01 s), ``observation_mode``, ``reward_weights``,
    ``render_mode``, ``render_width``/``render_height`` (320 × 240), ``camera``, ``image_size``
    (64), ``max_step_cm``, ``grasp_radius_cm``, ``slip_strain_percent``,
    ``strain_limiter_percent`` (off), ``solver_tol`` (1e-4), ``solver_vtol`` and ``sleep_speed``
    (1e-3 cm/s), ``sim`` (the implicit integrator's own arguments), ``mass_lumping``,
    ``damping_model``, ``observation_dtype``, ``target_rgb``: each on the environments page
    (``docs/envs.md``, "Options"). Bad values raise :class:`~cloth_gym.errors.ConfigError` naming
    the field. ``FAST_OPTIONS``: one 50 ms substep per control step, 1 % strain limiter.
    The measurements behind the defaults: ``docs/envs.md``, "CornerLift".

    ## Version History
    * v0: initial release.
    """

    n_grippers = 1
    episode_fields = {"target": (3,)}
    reset_options = {"gripper_start": ("random", "corner", "held")}
    #: 10 ms substeps: the dynamics the published v0 policies learnt (docs/envs.md, "CornerLift")
    defaults = {"sigma": 2.0, "control_dt": 0.05, "sim_defaults": {"max_dt": 1e-2}}
    #: kwargs for one 50 ms substep per control step (docs/envs.md, "CornerLift")
    FAST_OPTIONS = {"sim_dt": 0.05, "strain_limiter_percent": 1.0, "solver_tol": 1e-3}
    #: control steps the ``"held"`` start may take (the closing step, then up to 2 cm per step)
    MAX_HELD_START_STEPS = 10
    default_reward_weights = {"reach": 1.0, "grasp": 0.5, "distance": 2.0, "strain": 0.1, "ctrl": 0.01,
                              "success": 2.0}
    reach_scale_cm = 5.0
    distance_scale_cm = 10.0
    strain_limit_percent = 10.0
    success_distance_cm = 2.0

    def _build_model(self, material, options: ForceOptions, sigma: float) -> Model:
        table = Box((0.0, 0.0, -TABLE_HEIGHT_CM / 2), (TABLE_HALF_CM, TABLE_HALF_CM, TABLE_HEIGHT_CM / 2))
        floor = Plane((0.0, 0.0, -TABLE_HEIGHT_CM), (0.0, 0.0, 1.0))
        return build_cloth(Rectangle(CLOTH_CM, CLOTH_CM), material, sigma=sigma, options=options,
                           origin=(0.0, 0.0, 0.1), obstacles=[table, floor], contact_thickness=0.1)

    def _workspace(self):
        return np.array([-30.0, -30.0, 0.0]), np.array([30.0, 30.0, 40.0])

    def lifted_corner(self, model: Model) -> int:
        """Particle index of the corner to lift: lattice node (0, 0)."""
        return int(model.grid_index[0, 0])

    def _reset_task(self, physics: ClothPhysics, rng: np.random.Generator, options: dict) -> None:
        q0 = physics.model.particle_q0
        R = _yaw(np.deg2rad(rng.uniform(-15.0, 15.0)))
        offset = np.array([*rng.uniform(-3.0, 3.0, 2), 0.0])
        physics.state.particle_q[:] = (q0 - q0.mean(axis=0)) @ R.T + q0.mean(axis=0) + offset
        gripper = np.array([*rng.uniform(-5.0, 5.0, 2), rng.uniform(5.0, 10.0)])
        corner = physics.state.particle_q[self.lifted_corner(physics.model)]
        self.target = corner + np.array([*rng.uniform(-5.0, 5.0, 2), 0.0])
        self.target[2] = rng.uniform(5.0, 12.0)
        if options["gripper_start"] != "random":  # within grasp_radius_cm of the corner (≤ 1.31 cm)
            gripper = np.array([*(corner[:2] + rng.uniform(-0.5, 0.5, 2)), rng.uniform(0.5, 1.2)])
        physics.grippers.reset([gripper])
        if options["gripper_start"] == "held":
            self._carry_part_way(physics, rng.uniform(0.0, 1.0))

    def _carry_part_way(self, physics: ClothPhysics, fraction: float) -> None:
        """The ``"held"`` start: close on the corner, then carry it ``fraction`` of the way from
        where it lies to the target, as the scripted expert would (full-speed control steps of
        :attr:`control_dt`, at most ``MAX_HELD_START_STEPS``; the episode then starts there, the
        cloth still moving)."""
        c = self.lifted_corner(physics.model)
        start = physics.state.particle_q[c]
        goal = start + fraction * (self.target - start)
        step_cm = self.gripper_config.max_step_cm
        action = np.array([[0.0, 0.0, 0.0, 1.0]])
        for _ in range(self.MAX_HELD_START_STEPS):
            physics.step(action, self.control_dt)
            if not self.corner_held(physics):  # not expected (the corner start grasps it): start so
                break
            move = goal - physics.state.particle_q[c]
            if np.linalg.norm(move) < 0.1 * step_cm:
                break
            action[0, :3] = np.clip(move / step_cm, -1.0, 1.0)

    def _keypoint_indices(self, model: Model) -> np.ndarray:
        nx, ny = model.grid_index.shape
        return np.array([model.index(0, 0), model.index(-1, 0), model.index(-1, -1), model.index(0, -1),
                         model.index(nx // 2, ny // 2)])

    def _task_observation_size(self) -> int:
        return 12

    def _task_observation(self, physics: ClothPhysics) -> np.ndarray:
        corner = physics.state.particle_q[self.lifted_corner(physics.model)]
        return np.concatenate([self.target, corner, corner - physics.grippers.position[0], self.target - corner])

    def corner_held(self, physics: ClothPhysics) -> bool:
        """Does the gripper hold a particle within grasp_radius_cm + σ/2 of the lifted corner?"""
        r = self.gripper_config.grasp_radius_cm + 0.5 * self.sigma
        return nearest_held_sq(physics.state.particle_q, physics.grippers.held_by,
                               self.lifted_corner(physics.model)) <= r * r

    def _compute_measure(self, physics: ClothPhysics):
        """(corner–target distance, cm; largest edge strain, percent)."""
        d = float(np.linalg.norm(physics.state.particle_q[self.lifted_corner(physics.model)] - self.target))
        return d, max_edge_strain(physics.model, physics.state)

    def _is_success(self, physics: ClothPhysics) -> bool:
        d, eps = self._measure(physics)
        return d < self.success_distance_cm and eps < self.strain_limit_percent

    def _reward_terms(self, physics: ClothPhysics, action: np.ndarray) -> dict:
        w = self.reward_weights
        d, eps = self._measure(physics)
        success = d < self.success_distance_cm and eps < self.strain_limit_percent
        held = self.corner_held(physics)
        corner = physics.state.particle_q[self.lifted_corner(physics.model)]
        g = physics.grippers.position[0]
        reach = math.sqrt((g[0] - corner[0]) ** 2 + (g[1] - corner[1]) ** 2 + (g[2] - corner[2]) ** 2)
        near = 1.0 - math.tanh(reach / self.reach_scale_cm)
        a = action[:, :3]
        return {
            "reward_reach": w["reach"] * (1.0 if held else near),
            "reward_grasp": w["grasp"] * (1.0 if held else float(physics.grippers.closed[0]) * near),
            "reward_distance": w["distance"] * (1.0 - math.tanh(d / self.distance_scale_cm)),
            "reward_strain": -w["strain"] * max(0.0, eps - self.strain_limit_percent),
            "reward_ctrl": -w["ctrl"] * float(np.einsum("ij,ij->", a, a)),
            "reward_success": w["success"] * float(success),
        }

    def _markers(self, physics: ClothPhysics) -> list:
        return super()._markers(physics) + [(self.target.copy(), 0.8, self.target_rgb)]

    def _camera(self):
        from ..render import Camera

        return Camera.look_at(eye=(0.0, -55.0, 45.0), target=(0.0, 0.0, 3.0), up=(0, 0, 1), fov_deg=40)

    def _picture_camera(self):
        """From the front: where the cloth, the gripper and the target start (the target up to
        12 cm above the table)."""
        from ..render import Camera

        return Camera.look_at(eye=(15.0, -45.0, 39.0), target=(-2.0, -4.0, 3.5), up=(0, 0, 1), fov_deg=40)

    def _target_meshes(self, physics: ClothPhysics) -> list:
        """The target point: a sphere on a thin post standing on the table, which shows its height."""
        from ..render.shapes import box_mesh, sphere_mesh

        x, y, z = self.target
        post = box_mesh((x, y, 0.5 * z), (0.15, 0.15, 0.5 * z))
        return [(*sphere_mesh(self.target, 1.0), self.target_rgb), (*post, self.target_rgb)]


class CornerLiftV1Env(CornerLiftEnv):
    """
    ## Description
    ``cloth_gym/CornerLift-v1``: :class:`CornerLiftEnv` with the keyword arguments
    ``cloth_gym.envs.CORNER_LIFT_V1`` (``gymnasium.spec(id).kwargs``; this class only makes them its
    defaults). The same task (action space, rewards, starting state, episode end, arguments) on the
    cloth at real fabric resolution, with the simulator's own lattice conventions (``cloth_gym.envs.V1``):

    | | v0 | v1 |
    |---|---|---|
    | lattice spacing ``sigma`` | 2 cm (121 particles) | 1 cm (441 particles) |
    | ``mass_lumping`` | ``"uniform"``: every particle ``W·σ²`` (a 22 × 22 cm cloth's mass) | ``"area"``: each particle the fabric area it stands for (a 20 × 20 cm cloth's) |
    | ``damping_model`` | ``"absolute"``: ``−λ·m·v`` on every particle | ``"strain-rate"``: on the rates of deformation only |
    | ``observation_dtype`` | ``"float64"`` | ``"float32"`` |
    | ``target_rgb`` (the target marker) | (40, 80, 230), close to the cloth's blue | (250, 150, 20), orange |
    | implicit substep, preconditioner | 10 ms, ``"auto"`` (band on 11 × 11) | 5 ms, the band factor |
    | a particle that slipped from a closed gripper | grasped again at the next step | grasped again only after the gripper opens |
    | substeps of a fast-moving cloth | ``sim_dt`` | at most half a lattice spacing of travel per substep (``sim={"max_travel": 0.5}``) |

    ## Observation Space
    ``observation_mode="state"``: ``Box(-inf, inf, (2663,), float32)``: 441 particles' positions
    and velocities, then the gripper and task entries as in v0. ``"keypoints"``: ``(47,)``,
    float32. ``"rgb"`` as in v0.

    ## Defaults
    Measured in ``docs/envs.md`` under "CornerLift-v1".

    ## Version History
    * v1: σ = 1 cm, area-lumped mass, strain-rate damping, float32 observations, orange target,
      5 ms substeps, no re-grasp of a slipped particle before the gripper opens, at most half a
      lattice spacing of travel per substep, gripper entries of the observation Box bounded.
    * v0: initial release (:class:`CornerLiftEnv`).
    """

    defaults = CORNER_LIFT_V1
    #: v0's fast settings (50 ms substeps with a 1 % strain limiter) were measured on v0's lattice only
    FAST_OPTIONS = None


class CornerLiftV2Env(CornerLiftEnv):
    """
    ## Description
    ``cloth_gym/CornerLift-v2``: :class:`CornerLiftEnv` with the keyword arguments
    ``cloth_gym.envs.CORNER_LIFT_V2``: those of v1 (the same task, cloth and arguments) with 10 ms
    implicit substeps instead of 5 ms (``sim_defaults["max_dt"]``). The travel rule of v1 (no free particle moves
    more than half a lattice spacing in a substep) still shortens the substeps of a fast-moving
    cloth.

    ## Defaults
    Measured in ``docs/envs.md`` under "CornerLift-v2".

    ## Version History
    * v2: 10 ms implicit substeps (v1: 5 ms).
    * v1: :class:`CornerLiftV1Env`.
    * v0: :class:`CornerLiftEnv`.
    """

    defaults = CORNER_LIFT_V2
    FAST_OPTIONS = None


class CornerLiftGoalEnv(CornerLiftEnv):
    """
    ## Description
    ``cloth_gym/CornerLiftGoal-v1`` (``CornerLiftGoal-v2``: the keyword arguments of CornerLift-v2):
    :class:`CornerLiftV1Env`'s task (the cloth, gripper, start,
    success and arguments are the same) as a goal-conditioned env in the convention of
    Gymnasium-Robotics, so that hindsight experience replay (Stable-Baselines3's
    ``HerReplayBuffer``) can relabel its goals: the goal is where the lifted corner should be.

    ## Observation Space
    ``Dict`` of float32 boxes:

    * ``"observation"``: the cloth (all particles' positions and velocities, ``"state"``, or the
      five keypoints', ``"keypoints"``; cm and cm/s), the gripper (position cm, closed 0/1,
      particles held) and the corner relative to the gripper (cm): ``(6N + 8,)``, no goal in it;
    * ``"achieved_goal"``: the lifted corner's position (3, cm);
    * ``"desired_goal"``: the target point (3, cm).

    ## Rewards
    Sparse: ``reward = w_success · 1[‖achieved − desired‖ < 2 cm and ε_max < 10 % and not
    diverged]`` (w_success = 1), in ``info["reward_success"]``. ``info["strain_percent"]`` holds
    ε_max, the cloth's largest edge strain. :meth:`compute_reward` computes the same from
    goals and infos, for one transition or a batch of them (the reward a relabelled goal
    would have given); a diverged step rewards 0, as it does here.

    ## Version History
    * v1: initial release, on CornerLift-v1's cloth.
    """

    OBSERVATION_MODES = ("state", "keypoints")
    default_reward_weights = {"success": 1.0}
    defaults = CORNER_LIFT_V1
    FAST_OPTIONS = None

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        from gymnasium import spaces

        # CornerLift's observation without its task entries, then the corner relative to the gripper
        low, high = self._observation_bounds(self._model)
        k = self._task_observation_size()
        inf = np.full(3, np.inf, dtype=self.observation_dtype)
        box = spaces.Box(np.concatenate([low[:-k], -inf]), np.concatenate([high[:-k], inf]), dtype=self.observation_dtype)
        goal = spaces.Box(-np.inf, np.inf, shape=(3,), dtype=self.observation_dtype)
        self.observation_space = spaces.Dict({"observation": box, "achieved_goal": goal, "desired_goal": goal})

    def _get_obs(self) -> dict:
        flat = super()._get_obs()  # cloth, gripper, then target, corner, corner − gripper, target − corner
        k = self._task_observation_size()
        task = flat[-k:]
        return {"observation": np.concatenate([flat[:-k], task[6:9]]), "achieved_goal": task[3:6].copy(),
                "desired_goal": task[0:3].copy()}

    def _task_info(self, physics: ClothPhysics) -> dict:
        return {"strain_percent": self._measure(physics)[1]}

    def _goals(self, physics: ClothPhysics) -> tuple:
        """(achieved, desired) as the observation holds them (in its dtype)."""
        corner = physics.state.particle_q[self.lifted_corner(physics.model)]
        return corner.astype(self.observation_dtype), self.target.astype(self.observation_dtype)

    def _is_success(self, physics: ClothPhysics) -> bool:
        # from the goals as observed, so that compute_reward on stored transitions agrees exactly
        achieved, desired = self._goals(physics)
        return bool(self._reached(achieved, desired, [self._task_info(physics)])[0])

    def _reward_terms(self, physics: ClothPhysics, action: np.ndarray) -> dict:
        return {"reward_success": self.compute_reward(*self._goals(physics), self._task_info(physics))}

    def _reached(self, achieved_goal, desired_goal, infos) -> np.ndarray:
        """(B,) bool: the corner within 2 cm of the goal, the strain below 10 %, not diverged."""
        a = np.asarray(achieved_goal, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(desired_goal, dtype=np.float64).reshape(-1, 3)
        ok = np.array([not i.get("diverged", False) for i in infos], dtype=bool)
        if any(good and "strain_percent" not in i for good, i in zip(ok, infos)):
            # empty infos would silently make every relabelled reward 0
            raise ConfigError("info", "compute_reward needs each step's info (its 'strain_percent'); with "
                              "Stable-Baselines3's HerReplayBuffer pass replay_buffer_kwargs copy_info_dict=True")
        strain = np.array([i.get("strain_percent", np.inf) for i in infos], dtype=np.float64)
        hit = np.linalg.norm(a - d, axis=1) < self.success_distance_cm
        return hit & (strain < self.strain_limit_percent) & ok

    def compute_reward(self, achieved_goal, desired_goal, info):
        """The reward of reaching ``achieved_goal`` when ``desired_goal`` was asked: (3,) goals
        and one ``info`` dict, or (B, 3) goals and a sequence of B infos (as ``HerReplayBuffer``
        passes them). Returns a float, or a (B,) float32 array."""
        single = isinstance(info, dict)
        r = self.reward_weights["success"] * self._reached(achieved_goal, desired_goal, [info] if single else list(info))
        return float(r[0]) if single else r.astype(np.float32)


class CornerLiftGoalV2Env(CornerLiftGoalEnv):
    """
    ## Description
    ``cloth_gym/CornerLiftGoal-v2``: :class:`CornerLiftGoalEnv` with the keyword arguments of
    CornerLift-v2 (``cloth_gym.envs.CORNER_LIFT_V2``: 10 ms implicit substeps instead of 5 ms);
    this class only makes them its defaults.

    ## Version History
    * v2: 10 ms implicit substeps, as CornerLift-v2.
    * v1: :class:`CornerLiftGoalEnv`.
    """

    defaults = CORNER_LIFT_V2
