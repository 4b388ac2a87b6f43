"""The simulation plumbing shared by the cloth envs (Gymnasium's ``mujoco_env.py`` role).

Three layers, as in dm_control:

* :class:`ClothPhysics` holds the simulation: the immutable model, the mutable
  state, the integrator and the grippers. It knows nothing about tasks.
* A task (a :class:`ClothEnv` subclass, one module per task) builds its scene,
  resets it, and computes observations extras, reward terms and success from
  the physics it is handed; it keeps no simulator globals.
* :class:`ClothEnv` (this module) is the Gymnasium front: option validation,
  action validation and scaling, the control step, divergence handling,
  observation modes and rendering.
"""

from __future__ import annotations

import copy
import dataclasses
import importlib.util
import numbers
from dataclasses import dataclass
from typing import Any, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import EzPickle

from ..errors import ConfigError, ConfigTypeError, InsideObstacle, ResetNeeded, SimulationDiverged
from ..materials import Material
from ..sim.model import Control, ForceOptions, Model, State
from ..validation import is_one_of
from ..validation import seed as check_seed
from . import palette
from .grippers import Grippers
from .snapshot import SNAPSHOT_FORMAT, EnvSnapshot, check_snapshot, env_id
from .settings import (BASE_DEFAULTS, MAX_SUBSTEPS, RANDOMISABLE, EnvSettings, _is_randomisation, init_signature,
                       material_choices, resolve_material)

__all__ = ["ClothEnv", "ClothPhysics", "EnvSnapshot", "resolve_material", "RANDOMISABLE", "MAX_SUBSTEPS"]


def _copy_obs(obs):
    """A copy of an observation (an array, or a dict of arrays)."""
    return {k: v.copy() for k, v in obs.items()} if isinstance(obs, dict) else obs.copy()


def _plain_real(a) -> bool:
    """Is ``a`` a plain ndarray of bools, integers or floats of at most 64 bits: one whose values
    are finite exactly where their float64 copies are (a longer float may overflow float64)?"""
    return type(a) is np.ndarray and a.dtype.kind in "biuf" and a.dtype.itemsize <= 8


def _finite_obs(obs) -> bool:
    """Is every number of an observation (an array, or a dict of arrays) finite?"""
    return all(np.isfinite(v).all() for v in obs.values()) if isinstance(obs, dict) else bool(np.isfinite(obs).all())


@dataclass
class ClothPhysics:
    """One simulation: model, state, integrator, grippers. No task logic."""

    model: Model
    state: State
    integrator: Any
    grippers: Grippers

    def step(self, actions: np.ndarray, dt: float) -> None:
        """One control step of ``dt`` s: grippers act, the cloth is integrated, slip is checked."""
        kinematic = self.grippers.prepare(actions, self.state, dt)
        self.integrator.step(self.model, self.state, Control(kinematic=kinematic), dt)
        self.grippers.after_step(self.state)


def _pygame_installed() -> bool:
    """Whether pygame can be imported (looked up without importing it)."""
    try:
        return importlib.util.find_spec("pygame") is not None
    except (ImportError, ValueError):
        return False


#: the render modes every env advertises: ``"human"`` only where pygame is installed
RENDER_MODES = ["rgb_array", "depth_array", *(["human"] if _pygame_installed() else [])]


class ClothEnv(gym.Env, EzPickle):
    """Base class of the cloth envs; see a task's docstring for its specification.

    The keyword arguments (:data:`~cloth_gym.envs.settings.OPTIONS`) are checked into
    :attr:`settings` (:class:`~cloth_gym.envs.settings.EnvSettings`); an argument left None takes
    the class's default from :attr:`defaults`. Subclasses set ``n_grippers``,
    ``default_reward_weights``, the ``defaults`` they change, and implement the task hooks
    ``_build_model``, ``_reset_task``, ``_task_observation``, ``_keypoint_indices``,
    ``_reward_terms``, ``_is_success``, ``_workspace`` and ``_camera``, and for ``render()``
    frames ``_picture_camera`` and ``_target_meshes``.
    """

    #: ``"human"`` (a pygame window) is advertised only where pygame is installed, so that checkers
    #: which make the env in every advertised mode (``gymnasium.utils.env_checker.check_env``) pass
    metadata = {"render_modes": RENDER_MODES, "render_fps": 20}
    n_grippers: int = 1
    default_reward_weights: dict = {}
    #: the default of each keyword argument left None (the options table of ``docs/envs.md``); a
    #: subclass's ``defaults`` names only what it changes (``sim_defaults`` merge key by key:
    #: :func:`~cloth_gym.envs.settings.class_defaults`)
    defaults: dict = BASE_DEFAULTS
    #: ImplicitEuler settings that Breen's model (``model="breen"``) puts over ``sim_defaults``: they
    #: were measured on KES cloth, and Breen's quartic springs, nearly slack at small strain, make a
    #: different cloth (docs/physics.md, Breen's model); an explicit option still wins
    breen_defaults: dict = {}
    #: ``reset(options=...)`` keys a task accepts, each with its allowed values (the first is the
    #: default); any other key or value is a ConfigError naming it.
    reset_options: dict[str, tuple] = {}
    OBSERVATION_MODES = ("state", "keypoints", "rgb")
    #: the attributes a task sets at reset that later steps read (its episode state, beyond the
    #: physics), each a float64 array of the shape given: copied into and out of snapshots
    #: (:meth:`get_state`); a snapshot's ``task`` must have exactly these keys
    episode_fields: dict[str, tuple] = {}

    def __init__(self, **kwargs):
        #: the env's checked settings (frozen); the attributes below repeat them
        self.settings = EnvSettings.from_kwargs(type(self), kwargs)
        EzPickle.__init__(self, **self.settings.kwargs)
        self._apply_settings(self.settings)
        self._renderers: dict = {}
        self._window = None  # the pygame window of render_mode="human"
        self._keypoints_cache = None
        self._measured = None  # (state, step, time, measure) of the last state measured

        # the scene with the nominal material (rebuilt per episode only when randomised)
        try:
            self._model = self._build_model(resolve_material(self.material_spec, None), self.force_options,
                                            self.sigma)
        except ConfigError as err:
            if err.field.endswith("_cm"):  # a cloth size that is no multiple of sigma
                raise ConfigError("sigma", str(err)) from None
            raise
        self.physics: ClothPhysics | None = None
        self._diverged = False
        self._last_obs = None
        self.elapsed_steps = 0

        self.action_space = spaces.Box(-1.0, 1.0, shape=(4 * self.n_grippers,), dtype=np.float32)
        if self.observation_mode == "rgb":
            self._require_renderer("observation_mode")
            self.observation_space = spaces.Box(0, 255, (self.image_size, self.image_size, 3), dtype=np.uint8)
        else:
            low, high = self._observation_bounds(self._model)
            self.observation_space = spaces.Box(low, high, dtype=self.observation_dtype)

    __init__.__signature__ = init_signature()

    def _apply_settings(self, s: EnvSettings) -> None:
        """The env's attributes from its settings (what the task code and users read)."""
        p, t, v = s.physics, s.task, s.view
        self.material_spec = p.material
        #: whether each episode draws its fabric from several materials (``info["material"]`` names it)
        self.chooses_material = material_choices(p.material) is not None
        self.force_options = p.force_options
        self.integrator_kind = p.integrator
        self.sigma, self.control_dt, self.sim_dt = p.sigma, p.control_dt, p.sim_dt
        self.strain_limiter_percent = p.strain_limiter_percent
        self.solver_tol, self.solver_vtol, self.sleep_speed = p.solver_tol, p.solver_vtol, p.sleep_speed
        self.slow_sim_dt, self.slow_speed = p.slow_sim_dt, p.slow_speed
        #: the implicit integrator's settings: the env's defaults, its options and ``sim`` (empty
        #: for the explicit integrator); each episode's integrator is ``ImplicitEuler(**sim)``
        self.sim = p.sim
        self.reward_weights = dict(t.reward_weights)
        self.gripper_config = t.gripper
        #: the largest tilt (degrees) out of its plane of a hanging start cloth, drawn in ±it each reset
        self.start_tilt_deg = t.start_tilt_deg
        self.observation_mode = v.observation_mode
        self.observation_dtype = v.observation_dtype
        #: the observation Box bounds what is known (each gripper's position within the workspace,
        #: closed 0/1, particles held 0..N) rather than (-inf, inf) everywhere
        self.bounded_observations = v.bounded_observations
        self.render_mode = v.render_mode
        self.render_width, self.render_height, self.image_size = v.render_width, v.render_height, v.image_size
        self.camera = v.camera
        #: the colour of the task's target markers in frames and ``"rgb"`` observations (0–255)
        self.target_rgb = v.target_rgb

    # ------------------------------------------------------------------ task hooks
    def _build_model(self, material: Material, options: ForceOptions, sigma: float) -> Model:
        raise NotImplementedError

    def _workspace(self) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _reset_task(self, physics: ClothPhysics, rng: np.random.Generator, options: dict) -> None:
        """Set the episode's starting state; ``options`` holds every key of :attr:`reset_options`."""
        raise NotImplementedError

    def check_reset_options(self, options: dict | None) -> dict:
        """``options`` checked against :attr:`reset_options` (ConfigError naming ``options.<key>``),
        with the defaults filled in."""
        if options is None:
            options = {}
        if not isinstance(options, dict):
            raise ConfigTypeError("options", f"must be a dict of reset options (allowed keys: "
                                  f"{sorted(self.reset_options) or 'none'}), got {options!r}")
        out = {k: allowed[0] for k, allowed in self.reset_options.items()}
        for k, v in options.items():
            if k not in self.reset_options:
                raise ConfigError(f"options.{k}", f"unknown reset option of {type(self).__name__}; "
                                  f"allowed: {sorted(self.reset_options) or 'none'}")
            if not is_one_of(v, self.reset_options[k]):
                raise ConfigError(f"options.{k}", f"must be one of {list(self.reset_options[k])}, got {v!r}")
            out[k] = v
        return out

    def _task_observation(self, physics: ClothPhysics) -> np.ndarray:
        return np.zeros(0)

    def _compute_measure(self, physics: ClothPhysics):
        """What both the task's reward and its success test need from the state (default: nothing);
        read it through :meth:`_measure`."""
        return None

    def _measure(self, physics: ClothPhysics):
        """:meth:`_compute_measure` of the current state, computed once per state (reward and
        success both call it; a reset starts afresh): kept with the state object it was computed
        on and that state's step and time."""
        s, m = physics.state, self._measured
        if m is None or m[0] is not s or m[1] != s.step or m[2] != s.time:
            m = self._measured = (s, s.step, s.time, self._compute_measure(physics))
        return m[3]

    def _keypoint_indices(self, model: Model) -> np.ndarray:
        return model.corners()

    def _reward_terms(self, physics: ClothPhysics, action: np.ndarray) -> dict:
        raise NotImplementedError

    def _is_success(self, physics: ClothPhysics) -> bool:
        raise NotImplementedError

    def _camera(self):
        """The camera of ``"rgb"`` observations."""
        raise NotImplementedError

    def _markers(self, physics: ClothPhysics) -> list:
        """The markers of ``"rgb"`` observations: the grippers (red closed, green open), plus the
        task's. Frames of ``render()`` draw :meth:`_picture_markers` and :meth:`_target_meshes`."""
        out = []
        for g in range(physics.grippers.count):
            rgb = (220, 40, 40) if physics.grippers.closed[g] else (40, 200, 40)
            out.append((physics.grippers.position[g].copy(), 0.8, rgb))
        return out

    def _picture_camera(self):
        """The camera of ``render()`` frames, framed on the part of the scene the task uses
        (default: :meth:`_camera`)."""
        return self._camera()

    def _picture_markers(self, physics: ClothPhysics) -> list:
        """The grippers in ``render()`` frames: spheres of the grasp radius (what a closing gripper
        grasps lies inside), in the colours of :mod:`~cloth_gym.envs.palette` (open, closed on
        nothing, closed and holding particles)."""
        g = physics.grippers
        holding = np.bincount(g.held_by + 1, minlength=g.count + 1)[1:] > 0
        r = self.gripper_config.grasp_radius_cm
        return [(g.position[k].copy(), r, palette.gripper_rgb(g.closed[k], holding[k])) for k in range(g.count)]

    def _target_meshes(self, physics: ClothPhysics) -> list:
        """The task's target in ``render()`` frames: ``(vertices, faces, rgb)`` meshes in :attr:`target_rgb`."""
        return []

    # ------------------------------------------------------------------ plumbing
    def _make_integrator(self):
        if self.integrator_kind == "implicit":
            from ..sim.implicit import ImplicitEuler

            return ImplicitEuler(**self.sim)
        from ..sim.integrators import SymplecticEuler

        return SymplecticEuler(on_unstable="substep")

    def _observation_size(self, model: Model) -> int:
        extra = self._task_observation_size()
        if self.observation_mode == "state":
            return 6 * model.particle_count + 5 * self.n_grippers + extra
        return 6 * len(self._keypoint_indices(model)) + 5 * self.n_grippers + extra

    def _task_observation_size(self) -> int:
        return 0

    def _observation_bounds(self, model: Model) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) of the flat observation, in its dtype: infinite, but for the grippers'
        entries when :attr:`bounded_observations` (positions are clamped to the workspace)."""
        n = self._observation_size(model)
        low, high = np.full(n, -np.inf), np.full(n, np.inf)
        if self.bounded_observations:
            start = n - self._task_observation_size() - 5 * self.n_grippers
            ws_low, ws_high = self._workspace()
            low[start:start + 5 * self.n_grippers] = np.tile(np.concatenate([ws_low, [0.0, 0.0]]), self.n_grippers)
            high[start:start + 5 * self.n_grippers] = np.tile(np.concatenate([ws_high, [1.0, model.particle_count]]),
                                                              self.n_grippers)
        return low.astype(self.observation_dtype), high.astype(self.observation_dtype)

    def _task_info(self, physics: ClothPhysics) -> dict:
        """Entries a task adds to a (non-diverged) step's ``info``: plain Python numbers."""
        return {}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=check_seed("seed", seed))
        options = self.check_reset_options(options)
        rng = self.np_random
        model = self._model
        if _is_randomisation(self.material_spec):
            model = self._build_model(resolve_material(self.material_spec, rng), self.force_options, self.sigma)
        low, high = self._workspace()
        grippers = Grippers(model, self.n_grippers, self.gripper_config, low, high)
        # a fresh integrator per episode: no contact or history state carried between episodes
        self.physics = ClothPhysics(model, model.state(), self._make_integrator(), grippers)
        self._measured = None  # a new episode (its target may change)
        self._reset_task(self.physics, rng, options)
        self._diverged = False
        self.elapsed_steps = 0
        obs = self._get_obs()
        self._last_obs = obs
        if self.render_mode == "human":
            self.render()
        return obs, {"is_success": bool(self._is_success(self.physics)), "diverged": False, **self._material_info()}

    def _validate_action(self, action) -> np.ndarray:
        """``action`` as (grippers, 4) floats clipped to [−1, 1]: any real array-like of the right
        size; a wrong type (a string, a mapping, complex or ragged numbers) is a ConfigTypeError, a
        wrong size or a non-finite value a ConfigError."""
        if _plain_real(action) and action.size == 4 * self.n_grippers and np.isfinite(action).all():
            # the common case, checked in one line
            return np.clip(action.reshape(self.n_grippers, 4).astype(np.float64), -1.0, 1.0)
        expected = f"{4 * self.n_grippers} numbers ([dx, dy, dz, grip] per gripper)"
        if isinstance(action, (str, bytes, Mapping)) or action is None:
            raise ConfigTypeError("action", f"expected {expected}, got {action!r}")
        if np.ma.isMaskedArray(action) and np.ma.getmaskarray(action).any():
            raise ConfigError("action", f"has masked entries: expected {expected}, got {action!r}")
        try:
            raw = np.asarray(action)
            # real dtypes convert, and object arrays of real numbers; complex, strings, None do not
            if raw.dtype.kind not in "biuf" and not (raw.dtype.kind == "O" and all(
                    isinstance(v, numbers.Real) for v in raw.flat)):
                raise TypeError
            a = raw.astype(np.float64)
        except (TypeError, ValueError, OverflowError):
            raise ConfigTypeError("action", f"expected {expected}, got {action!r}") from None
        if a.size != 4 * self.n_grippers:
            raise ConfigError("action", f"expected {expected}, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ConfigError("action", f"must be finite, got {a.tolist()}")
        return np.clip(a.reshape(self.n_grippers, 4), -1.0, 1.0)

    @classmethod
    def _actions_pass(cls, actions) -> bool:
        """Would every row of ``actions`` pass :meth:`_validate_action`, as one call can tell: a
        plain real ndarray of rows of ``4 · n_grippers`` finite numbers. False only means "check the
        rows one by one" (and always for a class that checks actions its own way)."""
        return (cls._validate_action is ClothEnv._validate_action and _plain_real(actions) and actions.ndim == 2
                and actions.shape[1] == 4 * cls.n_grippers and bool(np.isfinite(actions).all()))

    def step(self, action):
        if self.physics is None:
            raise ResetNeeded("call reset() before step()")
        a = self._validate_action(action)
        self.elapsed_steps += 1
        if self._diverged:  # stepping a diverged episode: nothing moves
            terms = {f"reward_{k}": 0.0 for k in self.reward_weights}
            info = {**terms, "is_success": False, "diverged": True, **self._material_info()}
            return _copy_obs(self._last_obs), 0.0, False, True, info
        try:
            self.physics.step(a, self.control_dt)
        except (SimulationDiverged, InsideObstacle) as err:  # the latter: a released particle left in an obstacle
            self._diverged = True
            terms = {f"reward_{k}": 0.0 for k in self.reward_weights}
            info = {**terms, "is_success": False, "diverged": True, "divergence": str(err), **self._material_info()}
            return _copy_obs(self._last_obs), 0.0, False, True, info
        terms = {k: float(v) for k, v in self._reward_terms(self.physics, a).items()}  # plain floats in info
        reward = float(sum(terms.values()))
        obs = self._get_obs()
        if self.observation_mode != "rgb" and not _finite_obs(obs):  # belt and braces
            self._diverged = True
            terms = {k: 0.0 for k in terms}
            info = {**terms, "is_success": False, "diverged": True, **self._material_info()}
            return _copy_obs(self._last_obs), 0.0, False, True, info
        self._last_obs = obs
        if self.render_mode == "human":
            self.render()
        info = {**terms, "is_success": bool(self._is_success(self.physics)), "diverged": False,
                "slips": int(self.physics.grippers.slips), **self._task_info(self.physics), **self._material_info()}
        return obs, reward, False, False, info

    def _material_info(self) -> dict:
        """``{"material": name}`` of the episode's fabric when the env chooses among several, else empty."""
        return {"material": self.physics.model.material.name} if self.chooses_material else {}

    # ------------------------------------------------------------------ save and restore
    def get_state(self) -> EnvSnapshot:
        """A copy of the episode as it stands (:class:`EnvSnapshot`): the cloth with the
        integrator's memory, the grippers, the task's state, the step count and the random
        generator. :meth:`set_state` returns the env to it; the same actions then give the same
        observations, rewards and infos, bit for bit. For planning (MCTS, shooting), debugging a
        divergence, or saving an episode to disk (it pickles)."""
        if self.physics is None:
            raise ResetNeeded("call reset() before get_state(): there is no episode to save")
        p = self.physics
        task = {k: copy.deepcopy(getattr(self, k)) for k in self.episode_fields}
        return EnvSnapshot(format=SNAPSHOT_FORMAT, env=type(self).__name__, env_id=env_id(self),
                           material=self._model.material.name, force_model=self.force_options.model,
                           integrator=self.integrator_kind, observation_mode=self.observation_mode,
                           model=p.model, state=p.state.copy(), grippers=p.grippers.snapshot(), task=task,
                           rng=copy.deepcopy(self.np_random), rng_seed=self._np_random_seed,
                           elapsed_steps=self.elapsed_steps, diverged=self._diverged,
                           last_obs=None if self._last_obs is None else _copy_obs(self._last_obs))

    def set_state(self, snapshot: EnvSnapshot) -> None:
        """Return to ``snapshot`` (from :meth:`get_state` of an env of the same id, material, force
        model, integrator, observation mode and lattice), copying it in: the snapshot stays usable
        for further restores. A fresh integrator and fresh grippers take over; everything a later
        step reads is in the snapshot. The whole snapshot is checked first
        (:func:`~cloth_gym.envs.snapshot.check_snapshot`): a :class:`~cloth_gym.errors.SnapshotError`
        names the first field that does not fit, and the env is left as it was."""
        check_snapshot(self, snapshot)
        low, high = self._workspace()
        grippers = Grippers(snapshot.model, self.n_grippers, self.gripper_config, low, high)
        grippers.restore(snapshot.grippers)
        self.physics = ClothPhysics(snapshot.model, snapshot.state.copy(), self._make_integrator(), grippers)
        for k, v in snapshot.task.items():
            setattr(self, k, copy.deepcopy(v))
        self._np_random = copy.deepcopy(snapshot.rng)
        self._np_random_seed = snapshot.rng_seed  # both, or Gymnasium would reseed the generator on reading the seed
        self.elapsed_steps = int(snapshot.elapsed_steps)
        self._diverged = bool(snapshot.diverged)
        self._last_obs = None if snapshot.last_obs is None else _copy_obs(snapshot.last_obs)
        self._measured = None

    def __getstate__(self) -> dict:
        """Pickle and ``copy.deepcopy``: the constructor's arguments (EzPickle) and, mid-episode,
        the episode (:meth:`get_state`), so a copy continues where the original is."""
        d = EzPickle.__getstate__(self)
        if self.spec is not None:  # the Gymnasium id the env was made as (its snapshots name it); the
            # spec's kwargs as the checked ones, which pickle (a mappingproxy given as ``sim`` does not)
            d["_spec"] = dataclasses.replace(self.spec, kwargs=dict(d["_ezpickle_kwargs"]))
        if self.physics is not None:
            d["_episode"] = self.get_state()
        return d

    def __setstate__(self, d: dict) -> None:
        d = dict(d)
        episode = d.pop("_episode", None)
        spec = d.pop("_spec", None)
        EzPickle.__setstate__(self, d)
        if spec is not None:
            self.spec = spec
        if episode is not None:
            self.set_state(episode)

    def _get_obs(self) -> np.ndarray:
        p = self.physics
        if self.observation_mode == "rgb":
            return self._render_frame(self.image_size, self.image_size)
        q, qd = p.state.particle_q, p.state.particle_qd
        if self.observation_mode == "keypoints":
            cache = self._keypoints_cache
            if cache is None or cache[0] is not p.model:  # a model's keypoints do not change
                cache = self._keypoints_cache = (p.model, np.asarray(self._keypoint_indices(p.model)))
            q, qd = q[cache[1]], qd[cache[1]]
        # np.concatenate always allocates (the observation shares no memory with the state) and
        # rounds each float64 to the observation's dtype as astype would
        return np.concatenate([q.ravel(), qd.ravel(), p.grippers.observation().ravel(),
                               np.asarray(self._task_observation(p), dtype=np.float64).ravel()],
                              dtype=self.observation_dtype, casting="same_kind")

    # ------------------------------------------------------------------ rendering
    def _require_renderer(self, field: str):
        try:
            from .. import render  # noqa: F401
        except ImportError as err:
            raise ConfigError(field, f"needs the renderer (cloth_gym.render), which cannot be imported: {err}") from None

    def _renderer(self, width: int, height: int, picture: bool = False):
        """The renderer of ``"rgb"`` observations, or with ``picture`` of ``render()`` frames: each
        with the ``camera`` argument if given, else the task's :meth:`_camera` or :meth:`_picture_camera`."""
        from ..render import Renderer

        key = (width, height, picture)
        r = self._renderers.get(key)
        if r is None:
            camera = self.camera or (self._picture_camera() if picture else self._camera())
            r = self._renderers[key] = Renderer(width, height, camera=camera)
        return r

    def _render_frame(self, width: int, height: int) -> np.ndarray:
        """An ``"rgb"`` observation image: the task's camera, the markers of :meth:`_markers`."""
        frame = self._renderer(width, height).render_scene(self.physics.model, self.physics.state,
                                                           markers=self._markers(self.physics))
        return np.ascontiguousarray(frame, dtype=np.uint8)

    def _picture_frame(self, width: int, height: int, depth: bool = False) -> np.ndarray:
        """A ``render()`` frame: :meth:`_picture_camera`, the grippers and the target in the colours
        of :mod:`~cloth_gym.envs.palette`; with ``depth`` its depth image."""
        p = self.physics
        r = self._renderer(width, height, picture=True)
        kw = dict(markers=self._picture_markers(p), meshes=self._target_meshes(p))
        if depth:
            return r.render_scene_depth(p.model, p.state, **kw)
        return np.ascontiguousarray(r.render_scene(p.model, p.state, **kw), dtype=np.uint8)

    def render(self):
        """The scene seen by the task's picture camera (or the ``camera`` argument), ``render_width``
        × ``render_height`` px (320 × 240 by default), the grippers and the target in the colours of
        :mod:`~cloth_gym.envs.palette`: an RGB frame (H, W, 3) uint8 (``render_mode="rgb_array"``);
        its depth image (H, W) float32, the distance in cm along the view direction, ``inf`` where
        only background shows (``"depth_array"``); or the frame shown in a window (``"human"``, also
        after every reset and step; returns None). None without a render mode."""
        if self.render_mode is None or self.physics is None:
            return None
        self._require_renderer("render_mode")
        if self.render_mode == "depth_array":
            return self._picture_frame(self.render_width, self.render_height, depth=True)
        frame = self._picture_frame(self.render_width, self.render_height)
        if self.render_mode == "rgb_array":
            return frame
        self._show(frame)
        return None

    def _show(self, frame: np.ndarray) -> None:
        import pygame

        if self._window is None:
            pygame.display.init()
            self._window = pygame.display.set_mode(frame.shape[1::-1])
            self._clock = pygame.time.Clock()
        self._window.blit(pygame.surfarray.make_surface(frame.swapaxes(0, 1)), (0, 0))
        pygame.event.pump()
        pygame.display.flip()
        self._clock.tick(self.metadata["render_fps"])

    def close(self):
        self._renderers.clear()
        if self._window is not None:
            import pygame

            pygame.display.quit()
            self._window = None
