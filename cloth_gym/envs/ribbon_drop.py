"""RibbonDrop: move a ribbon held at one end and release it so it lands flat in a target region."""

from __future__ import annotations

import math

import numpy as np

from ..sim.collision import CollisionOptions
from ..sim.lattice import Ribbon, build_cloth
from ..sim.model import ForceOptions, Model
from ..sim.obstacles import Plane
from . import RIBBON_DROP_V1, RIBBON_DROP_V2, RIBBON_DROP_V3, RIBBON_DROP_V4, palette
from .base import ClothEnv, ClothPhysics

__all__ = ["RibbonDropEnv"]

RIBBON_LENGTH_CM = 40.0
RIBBON_WIDTH_CM = 2.0
TARGET_HALF_CM = (30.0, 8.0)  # target region half extents along x and y
# local (warp, weft, normal) → world: the ribbon's length pointing down (i = 0 end on top)
HANGING = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])


def tilt_out_of_plane(q: np.ndarray, held: np.ndarray, angle_rad: float) -> None:
    """Rotate the hanging ribbon's positions ``q`` (cm) in place by ``angle_rad`` about the
    horizontal axis through the held particles that lies in the ribbon's plane, so that its free end
    swings out of the plane. A ribbon hanging exactly in one plane stays in it under any gripper
    motion within that plane; pressed down, it can then only buckle within its own plane, which no
    real ribbon does (docs/numerics.md, "Pressing a ribbon onto the floor")."""
    pivot = q[held].mean(axis=0)
    normal = HANGING[2]  # the ribbon's normal, world x: the free end moves along it
    rel = q - pivot
    down = rel @ np.array([0.0, 0.0, 1.0])
    out = rel @ normal
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    q[:] = pivot + rel + np.outer(down * c - out * s - down, [0.0, 0.0, 1.0]) \
        + np.outer(down * s + out * c - out, normal)


class RibbonDropEnv(ClothEnv):
    """
    ## Description
    A 40 × 2 cm ribbon (thick cotton) hangs from one point gripper holding its top end (lattice
    row i = 0) above a floor at z = 0. Move it and release it so that it lands flat inside a
    60 × 16 cm target region on the floor (long side along x). Self-collision is on
    (:class:`~cloth_gym.sim.collision.CollisionOptions`): a folding ribbon does not pass
    through itself.

    ## Action Space
    ``Box(-1, 1, (4,), float32)``: gripper dx, dy, dz (scaled to ±``max_step_cm`` = 2 cm per
    control step) and grip (> 0 closes within ``grasp_radius_cm`` = 1.5 cm, ≤ 0 opens and
    releases the ribbon with the gripper's velocity). Actions are clipped; a non-finite one
    raises :class:`~cloth_gym.errors.ConfigError`. The gripper stays 0.5 cm above the floor and
    inside x, y ∈ [−50, 50], z ∈ [0, 60] cm; a grasp that strains an edge past
    ``slip_strain_percent`` (30 %) slips.

    ## Observation Space
    ``"state"`` (default): ``Box((6N + 9,), float64)``, N = 42 (21 × 2 lattice): positions (cm),
    velocities (cm/s), the gripper (position, closed 0/1, particles held), the target's centre
    (x, y) and half extents (cm). ``"keypoints"``: ``(39,)``, 5 particles along the centre line
    (ends, quarter points, middle), the gripper and the target. ``"rgb"``: images.

    ## Rewards
    With f the fraction of particles flat inside the target (xy inside, z < 1 cm), ℓ = f⁴,
    h = 1[the gripper holds the ribbon], d the xy distance (cm) from the ribbon's centroid to
    the target's centre and a the action:

    * ``reward_hold = w_hold · (h + (1 − h) · ℓ)``                   (w_hold = 0.5)
    * ``reward_reach = w_reach · (1 − tanh(d / 20 cm))``            (w_reach = 1.0)
    * ``reward_flat = w_flat · f``                                  (w_flat = 1.0)
    * ``reward_release = w_release · (1 − h) · ℓ``                  (w_release = 1.0)
    * ``reward_ctrl = −w_ctrl · ‖a[:3]‖²``                          (w_ctrl = 0.01)
    * ``reward_success = w_success · 1[success]``                   (w_success = 2.0)

    ``reward`` is their sum (each term in ``info``, at most 5.5 per step); releasing pays more
    than holding only once most of the ribbon lies flat in the target (f > 0.76). Success
    (``info["is_success"]``): the gripper holds nothing and every particle lies flat inside.

    ## Starting State
    The ribbon hangs straight down from the closed gripper at xy in [−10, 10] cm, z in
    [44, 46] cm (its free end 4–6 cm above the floor); the target's centre is uniform in
    x, y ∈ [−15, 15] cm.

    ## Episode End
    Never terminates; truncated at 200 steps (10 s) or when the simulation diverges
    (``info["diverged"] = True``, zero reward, the last finite observation).

    ## Arguments
    As :class:`~cloth_gym.envs.corner_lift.CornerLiftEnv`, with ``sigma`` 2 cm (must divide 40
    and 2 cm), ``sim_dt`` 10 ms, ``strain_limiter_percent`` 1 % (0: off), ``solver_tol`` 1e-3,
    ``reward_weights`` keys ``hold``, ``reach``, ``flat``, ``release``, ``ctrl``, ``success``.
    Breen's model (``model="breen"``) takes 2.5 ms substeps without the limiter
    (``breen_defaults``; an explicit ``sim_dt`` or ``strain_limiter_percent`` wins). The
    measurements behind the defaults: ``docs/envs.md``, "RibbonDrop".

    ## Version History
    * v0: initial release.
    """

    n_grippers = 1
    hangs_at_start = True  # start_tilt_deg applies
    episode_fields = {"target_center": (2,)}
    #: 10 ms substeps with the 1 % limiter and CG tolerance 1e-3 (docs/envs.md)
    defaults = {"sigma": 2.0, "control_dt": 0.05,
                "sim_defaults": {"max_dt": 1e-2, "strain_limit_percent": 1.0, "tol": 1e-3}}
    #: Breen's model: 2.5 ms substeps, no limiter (docs/envs.md)
    breen_defaults = {"max_dt": 2.5e-3, "strain_limit_percent": None}
    default_reward_weights = {"hold": 0.5, "reach": 1.0, "flat": 1.0, "release": 1.0, "ctrl": 0.01,
                              "success": 2.0}
    reach_scale_cm = 20.0
    ribbon_length_cm = RIBBON_LENGTH_CM
    target_half_cm = np.array(TARGET_HALF_CM)
    flat_height_cm = 1.0

    def _build_model(self, material, options: ForceOptions, sigma: float) -> Model:
        floor = Plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
        # the ribbon folds onto itself when it lands: self-collision (vertex-triangle and edge-edge,
        # the paper's rigid-triangle response) keeps it from passing through itself
        return build_cloth(Ribbon(RIBBON_LENGTH_CM, RIBBON_WIDTH_CM), material, sigma=sigma, options=options,
                           origin=(0.0, 0.0, 45.0 - RIBBON_LENGTH_CM / 2), rotation=HANGING,
                           obstacles=[floor], contact_thickness=0.1,
                           collision=CollisionOptions(self_collision=True))

    def _workspace(self):
        return np.array([-50.0, -50.0, 0.0]), np.array([50.0, 50.0, 60.0])

    def held_end(self, model: Model) -> np.ndarray:
        """The particles of the top end row (i = 0)."""
        return np.nonzero(model.particle_grid[:, 0] == 0)[0]

    def _reset_task(self, physics: ClothPhysics, rng: np.random.Generator, options: dict) -> None:
        offset = np.array([*rng.uniform(-10.0, 10.0, 2), rng.uniform(-1.0, 1.0)])
        physics.state.particle_q[:] = physics.model.particle_q0 + offset
        end = self.held_end(physics.model)
        physics.grippers.reset([physics.state.particle_q[end].mean(axis=0)])
        physics.grippers.grasp(0, physics.state, end)
        self.target_center = rng.uniform(-15.0, 15.0, 2)
        if self.start_tilt_deg > 0.0:  # drawn last: the other draws stay those of a version without a tilt
            side = 1.0 if rng.uniform() < 0.5 else -1.0
            tilt_out_of_plane(physics.state.particle_q, end, side * math.radians(self.start_tilt_deg))

    def _keypoint_indices(self, model: Model) -> np.ndarray:
        nx, ny = model.grid_index.shape
        j = ny // 2
        return np.array([model.index(i, j) for i in (0, nx // 4, nx // 2, (3 * nx) // 4, nx - 1)])

    def _task_observation_size(self) -> int:
        return 4

    def _task_observation(self, physics: ClothPhysics) -> np.ndarray:
        return np.concatenate([self.target_center, self.target_half_cm])

    def _compute_measure(self, physics: ClothPhysics):
        """(particles inside the target region in xy (N,) bool, their heights (N,) cm)."""
        q = physics.state.particle_q
        inside = np.all(np.abs(q[:, :2] - self.target_center) <= self.target_half_cm, axis=1)
        return inside, q[:, 2].copy()

    def _success(self, physics, inside, z) -> bool:
        return bool(np.all(inside) and np.all(z < self.flat_height_cm) and not np.any(physics.grippers.held_by >= 0))

    def _is_success(self, physics: ClothPhysics) -> bool:
        return self._success(physics, *self._measure(physics))

    def _reward_terms(self, physics: ClothPhysics, action: np.ndarray) -> dict:
        w = self.reward_weights
        inside, z = self._measure(physics)
        held = float(np.any(physics.grippers.held_by >= 0))
        flat = float(np.mean(inside & (z < self.flat_height_cm)))
        laid = flat ** 4
        d = float(np.linalg.norm(physics.state.particle_q[:, :2].mean(axis=0) - self.target_center))
        return {
            "reward_hold": w["hold"] * (held + (1.0 - held) * laid),
            "reward_reach": w["reach"] * (1.0 - np.tanh(d / self.reach_scale_cm)),
            "reward_flat": w["flat"] * flat,
            "reward_release": w["release"] * (1.0 - held) * laid,
            "reward_ctrl": -w["ctrl"] * float(np.sum(action[:, :3] ** 2)),
            "reward_success": w["success"] * float(self._success(physics, inside, z)),
        }

    def _markers(self, physics: ClothPhysics) -> list:
        cx, cy = self.target_center
        hx, hy = self.target_half_cm
        corners = [(cx + sx * hx, cy + sy * hy, 0.0) for sx in (-1, 1) for sy in (-1, 1)]
        return super()._markers(physics) + [(np.array(c), 1.2, self.target_rgb) for c in corners]

    def _camera(self):
        from ..render import Camera

        return Camera.look_at(eye=(75.0, -75.0, 70.0), target=(0.0, 0.0, 12.0), up=(0, 0, 1), fov_deg=50)

    def _picture_camera(self):
        """From high up, front right: every target region the task draws (x within ±45 cm, y
        within ±23 cm) and the ribbon's start, its face (normal along x) seen at a slant, not edge-on."""
        from ..render import Camera

        return Camera.look_at(eye=(48.0, -78.0, 108.0), target=(2.0, -1.0, 11.0), up=(0, 0, 1), fov_deg=40)

    def _target_meshes(self, physics: ClothPhysics) -> list:
        """The target region on the floor: a border strip 1 cm wide in :attr:`target_rgb` around a
        tinted inside (:data:`~cloth_gym.envs.palette.TARGET_FILL` of the colour over the floor's)."""
        from ..render.shapes import box_mesh

        (cx, cy), (hx, hy) = self.target_center, self.target_half_cm
        w = 0.5  # half the border strip's width, cm
        fill = tuple(round(palette.TARGET_FILL * t + (1 - palette.TARGET_FILL) * f)
                     for t, f in zip(self.target_rgb, palette.FLOOR_RGB))
        out = [(*box_mesh((cx, cy, 0.01), (hx, hy, 0.01)), fill)]
        for sx in (-1, 1):  # the strips along y, then along x, each inside the region
            out.append((*box_mesh((cx + sx * (hx - w), cy, 0.02), (w, hy, 0.02)), self.target_rgb))
            out.append((*box_mesh((cx, cy + sx * (hy - w), 0.02), (hx, w, 0.02)), self.target_rgb))
        return out


class RibbonDropV1Env(RibbonDropEnv):
    """
    ## Description
    ``cloth_gym/RibbonDrop-v1``: the task of :class:`RibbonDropEnv` (action space, rewards,
    starting state, success, episode end and arguments are the same) on the ribbon at real
    fabric resolution, with the simulator's own lattice conventions
    (``cloth_gym.envs.RIBBON_DROP_V1``, ``gymnasium.spec(id).kwargs``; this class only makes them its
    defaults):

    | | v0 | v1 |
    |---|---|---|
    | lattice spacing ``sigma`` | 2 cm (21 × 2 = 42 particles) | 1 cm (41 × 3 = 123 particles) |
    | ``mass_lumping`` | ``"uniform"`` (a 42 × 4 cm ribbon's mass) | ``"area"`` (a 40 × 2 cm ribbon's) |
    | ``damping_model`` | ``"absolute"`` | ``"strain-rate"`` |
    | ``observation_dtype`` | ``"float64"`` | ``"float32"`` |
    | ``target_rgb`` (the target's corner markers) | (40, 80, 230) | (250, 150, 20), orange |
    | a particle that slipped from a closed gripper | grasped again at the next step | grasped again only after the gripper opens |
    | implicit substep, strain limiter | 10 ms, 1 % | 5 ms, none |
    | substeps of a fast-moving cloth | ``sim_dt`` | at most half a lattice spacing of travel per substep (``sim={"max_travel": 0.5}``) |

    ## Observation Space
    ``observation_mode="state"``: ``Box(-inf, inf, (747,), float32)``: 123 particles'
    positions and velocities, then the gripper and the task entries as in v0.

    ## Defaults
    Measured in ``docs/envs.md`` under "RibbonDrop-v1".

    ## Version History
    * v1: σ = 1 cm, area-lumped mass, strain-rate damping, float32 observations, orange target,
      no re-grasp of a slipped particle before the gripper opens, 5 ms substeps without a
      strain limiter, at most half a lattice spacing of travel per substep, gripper entries of
      the observation Box bounded.
    * v0: initial release (:class:`RibbonDropEnv`).
    """

    #: 5 ms substeps, no strain limiter: within 1.1 % strain of itself (docs/envs.md)
    defaults = RIBBON_DROP_V1


class RibbonDropV2Env(RibbonDropEnv):
    """
    ## Description
    ``cloth_gym/RibbonDrop-v2``: :class:`RibbonDropV1Env` (the same task, ribbon and arguments)
    with dynamics that keep a swing and a press onto the floor physical
    (``cloth_gym.envs.RIBBON_DROP_V2``):

    * **the start tilted out of the ribbon's plane** by ``start_tilt_deg`` = 0.5° about the
      gripper, to a side drawn at each reset (after v1's draws, so a seed gives v1's start and
      target). v1's ribbon hangs exactly in one plane and stays in it under any gripper motion
      within that plane; pressed onto the floor it can then buckle only within its own plane,
      which overstretched or diverged 8 of 8 pressed episodes;
    * **BDF2 solved to convergence** (``sim_defaults``: ``scheme="bdf2"``, ``newton_iters=10``,
      ``newton_tol=0.1`` cm/s, ``momentum_exact=True``): a swinging ribbon keeps its energy
      (v1's single linearised backward-Euler pass damped a swing from 45° to 0.05 of its energy
      in two periods) and free flight keeps its momentum.

    It costs about 4× the CPU of a v1 step (measured in ``docs/envs.md`` under "RibbonDrop-v2").

    ## Version History
    * v4: :class:`RibbonDropV4Env`.
    * v3: :class:`RibbonDropV3Env`.
    * v2: start tilted 0.5° out of plane; BDF2 with converged Newton passes, exact momentum.
    * v1: :class:`RibbonDropV1Env`.
    * v0: :class:`RibbonDropEnv`.
    """

    defaults = RIBBON_DROP_V2


class RibbonDropV3Env(RibbonDropEnv):
    """
    ## Description
    ``cloth_gym/RibbonDrop-v3``: :class:`RibbonDropV2Env` (the same task, ribbon, start and
    arguments) with the collision response coupled to the implicit solve (``sim_defaults``:
    ``couple_collisions=True``; ``cloth_gym.envs.RIBBON_DROP_V3``): the particles the
    self-collision pass moves are held along their displacement and the rest of the ribbon is
    solved for around them (:func:`~cloth_gym.sim.implicit.coupling.coupled_finish`). A ribbon whipped
    into itself then stays whole: under a jerk policy on fabrics ×0.25–4, 0 of 20 episodes
    diverge and 19 stay under 1 % strain, where v2 diverges in 2 and reaches 13 % in half of them
    (docs/numerics.md, "Shaking a ribbon"). Episodes without self-contact are v2's.

    ## Version History
    * v4: :class:`RibbonDropV4Env`.
    * v3: the collision response coupled to the implicit solve.
    * v2: :class:`RibbonDropV2Env`.
    * v1: :class:`RibbonDropV1Env`.
    * v0: :class:`RibbonDropEnv`.
    """

    defaults = RIBBON_DROP_V3


class RibbonDropV4Env(RibbonDropEnv):
    """
    ## Description
    ``cloth_gym/RibbonDrop-v4``: :class:`RibbonDropV3Env` (the same task, ribbon, start and
    arguments) with the control steps where a contact leaves a strain jump run again in shorter
    substeps (``sim_defaults``: ``refine_strain_rise=0.3``; ``cloth_gym.envs.RIBBON_DROP_V4``): a
    control step after which some edge is stretched more than 0.3 percentage points beyond its
    strain at the step's start, or which diverges, is run again from its start in 4× the
    substeps (1.25 ms). A fold landing on the pile at v3's 5 ms substeps leaves up to 1.4 %
    strain that 1.25 ms substeps do not; under random actions v3 reaches 68 % where v4 stays
    under 0.4 % (docs/numerics.md, "Refining the calls where a strain jumps"). Control steps
    without such a jump are v3's.

    ## Version History
    * v4: a control step whose strain jumps run again in 4× the substeps.
    * v3: :class:`RibbonDropV3Env`.
    * v2: :class:`RibbonDropV2Env`.
    * v1: :class:`RibbonDropV1Env`.
    * v0: :class:`RibbonDropEnv`.
    """

    defaults = RIBBON_DROP_V4
