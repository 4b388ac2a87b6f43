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
import inspect
import math
import numbers
from dataclasses import dataclass
from os import PathLike
from types import MappingProxyType
from typing import Any, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import EzPickle

from ..errors import ConfigError, ConfigTypeError, InsideObstacle, ResetNeeded, SimulationDiverged
from ..materials import Material, load_material
from ..sim.model import Control, ForceOptions, Model, State
from ..validation import integer, is_one_of, one_of, real, vector
from ..validation import seed as check_seed
from .grippers import GripperConfig, Grippers

__all__ = ["ClothEnv", "ClothPhysics", "EnvSnapshot", "resolve_material", "RANDOMISABLE", "MAX_SUBSTEPS"]

#: the most implicit substeps an env takes per control step (``control_dt / sim_dt``)
MAX_SUBSTEPS = 10_000

#: Keys of a domain-randomisation material dict, each a ``(low, high)`` range sampled
#: uniformly at every reset: multiplicative scales of the KES curves and the areal
#: density, and absolute values of friction (μ) and damping (1/s).
RANDOMISABLE = ("stretch_scale", "bending_scale", "shear_scale", "areal_density_scale", "friction", "damping")


def check_substeps(field: str, dt_field: str, sim_dt: float, control_dt: float) -> None:
    """A control step of ``control_dt`` s must be a whole number of substeps of ``sim_dt`` s (error
    naming ``field``), and at most :data:`MAX_SUBSTEPS` of them (error naming ``dt_field``)."""
    n_sub = control_dt / sim_dt
    if sim_dt > control_dt or abs(n_sub - round(n_sub)) > 1e-6 * n_sub:
        raise ConfigError(field, f"control_dt = {control_dt} s must be a whole number of physics steps of "
                          f"{sim_dt} s")
    if n_sub > MAX_SUBSTEPS:
        raise ConfigError(dt_field, f"{sim_dt} s makes {n_sub:.0f} substeps per control step of {control_dt} s, "
                          f"more than {MAX_SUBSTEPS:,}")


def _implicit_option(field: str, v: Any, default: float, integrator: str, lo: float, hi: float,
                     lo_open: bool = False) -> float:
    """An option of the implicit integrator: its ``default`` when None, else a number in the range."""
    if v is None:
        return default
    if integrator != "implicit":
        raise ConfigError(field, "is an option of the implicit integrator only")
    return real(field, v, lo, hi, lo_open=lo_open)


#: ``sim`` keys each of the env's own options sets (they stay for the v0 ids' documented kwargs)
SIM_ALIASES = {"sim_dt": "max_dt", "solver_tol": "tol", "solver_vtol": "vtol", "sleep_speed": "sleep_speed",
               "slow_sim_dt": "slow_dt", "slow_speed": "slow_speed", "strain_limiter_percent": "strain_limit_percent"}


def sim_keys() -> list[str]:
    """The keys of an env's ``sim`` mapping: the parameters of
    :class:`~cloth_gym.sim.implicit.ImplicitEuler`."""
    from ..sim.implicit import ImplicitEuler

    return [p for p in inspect.signature(ImplicitEuler.__init__).parameters if p != "self"]


def resolve_sim(sim, base: dict, given: set, integrator: str) -> dict:
    """The implicit integrator's settings of an env: ``base`` (the env's defaults and its own
    options, ``given`` naming those set by the user) updated with the ``sim`` mapping, checked by
    :class:`~cloth_gym.sim.implicit.ImplicitEuler` itself; errors name ``sim.<key>``."""
    from ..sim.implicit import ImplicitEuler

    if sim is None:
        sim = {}
    if not isinstance(sim, Mapping):
        raise ConfigTypeError("sim", f"must be a mapping of ImplicitEuler's options, got {sim!r}; keys: {sim_keys()}")
    if sim and integrator != "implicit":
        raise ConfigError("sim", "sets the implicit integrator's options; integrator='explicit' has none")
    allowed = sim_keys()
    for k in sim:
        if k not in allowed:
            raise ConfigError(f"sim.{k}", f"unknown key; allowed: {allowed}")
        clash = [name for name, key in SIM_ALIASES.items() if key == k and name in given]
        if clash:
            raise ConfigError(f"sim.{k}", f"is given twice: also as {clash[0]}=")
    out = {**base, **sim}
    try:
        ImplicitEuler(**out)
    except ConfigError as err:
        raise type(err)(f"sim.{err.field}", err.message) from None
    return out


#: the keys every material mapping has (``configs/materials/*.yaml``); a mapping with any of them is a
#: material, not a randomisation dict (whose keys may overlap a material's: ``friction``)
MATERIAL_KEYS = ("areal_density_g_per_cm2", "stretch", "bending", "shear")


def _is_randomisation(spec) -> bool:
    return (isinstance(spec, Mapping) and not any(k in spec for k in MATERIAL_KEYS)
            and ("base" in spec or any(k in spec for k in RANDOMISABLE)))


CAMERA_KEYS = ("eye", "target", "up", "fov_deg")


def _camera(spec):
    """The ``camera`` argument: a :class:`~cloth_gym.render.Camera`, or a mapping of
    :meth:`Camera.look_at <cloth_gym.render.Camera.look_at>`'s arguments (``eye`` and ``target``
    in cm, optional ``up`` and ``fov_deg``); errors name ``camera.<key>``."""
    from ..render import Camera

    if isinstance(spec, Camera):
        return spec
    if not isinstance(spec, Mapping):
        raise ConfigTypeError("camera", f"must be a cloth_gym.render.Camera or a mapping with keys "
                              f"{list(CAMERA_KEYS)}, got {spec!r}")
    unknown = sorted(str(k) for k in spec if k not in CAMERA_KEYS)
    if unknown:
        raise ConfigError(f"camera.{unknown[0]}", f"unknown key; allowed: {list(CAMERA_KEYS)}")
    for k in ("eye", "target"):
        if k not in spec:
            raise ConfigError(f"camera.{k}", "is required (cm, world frame)")
    try:
        return Camera.look_at(**spec)
    except ConfigError as err:
        raise type(err)(f"camera.{err.field}", err.message) from None


def _copy_obs(obs):
    """A copy of an observation (an array, or a dict of arrays)."""
    return {k: v.copy() for k, v in obs.items()} if isinstance(obs, dict) else obs.copy()


def _finite_obs(obs) -> bool:
    """Is every number of an observation (an array, or a dict of arrays) finite?"""
    return all(np.all(np.isfinite(v)) for v in obs.values()) if isinstance(obs, dict) else bool(np.all(np.isfinite(obs)))


def _rgb(field: str, value) -> tuple:
    """An RGB colour: three numbers in [0, 255]."""
    v = vector(field, value, 3)
    if np.any(v < 0) or np.any(v > 255):
        raise ConfigError(field, f"must be three numbers in [0, 255] (red, green, blue), got {value!r}")
    return tuple(int(round(c)) for c in v)


def validate_material(spec) -> None:
    """Check a ``material`` option now (names, paths and ranges), raising ConfigError naming the field."""
    if _is_randomisation(spec):
        unknown = sorted((k for k in spec if k not in ("base", *RANDOMISABLE)), key=str)
        if unknown:
            raise ConfigError(f"material.{unknown[0]}", f"unknown key; allowed: ['base', {', '.join(RANDOMISABLE)}]")
        base = spec.get("base", "thick_cotton")
        if isinstance(base, Mapping) and not any(k in base for k in MATERIAL_KEYS):
            raise ConfigError("material.base", f"must be a material (a name, a YAML path, a Material or a material "
                              f"mapping with keys {list(MATERIAL_KEYS)}), got {base!r}")
        try:
            base = load_material(base)  # once: every range's extremes below are drawn on it
        except ConfigError as err:
            raise type(err)(f"material.base.{err.field}", err.message) from None
        for k in RANDOMISABLE:
            if k in spec:
                r = spec[k]
                if not (isinstance(r, (tuple, list)) and len(r) == 2):
                    raise ConfigTypeError(f"material.{k}", f"must be a (low, high) range, got {r!r}")
                lo_allowed = 0.0
                lo = real(f"material.{k}", r[0], lo_allowed, 1e4, lo_open=k.endswith("_scale"))
                hi = real(f"material.{k}", r[1], lo_allowed, 1e4, lo_open=k.endswith("_scale"))
                if lo > hi:
                    raise ConfigError(f"material.{k}", f"low {lo} > high {hi}")
        # each range's extremes must make a valid material too (friction <= 10, density <= 10 g/cm², ...)
        for k in RANDOMISABLE:
            for pick in (0, 1):
                if k in spec:
                    try:
                        resolve_material({"base": base, k: (spec[k][pick], spec[k][pick])}, None)
                    except ConfigError as err:
                        raise ConfigError(f"material.{k}", f"{spec[k][pick]!r} makes an invalid material: "
                                          f"{err}") from None
    elif isinstance(spec, Mapping) and not any(k in spec for k in MATERIAL_KEYS):
        raise ConfigError("material", f"a mapping must be a material (keys {list(MATERIAL_KEYS)}, ...) or a "
                          f"randomisation dict (keys 'base', {', '.join(RANDOMISABLE)}); got keys "
                          f"{sorted(map(str, spec))}")
    elif isinstance(spec, (str, PathLike, Mapping, Material)):
        load_material(spec)
    else:
        raise ConfigTypeError("material", f"expected a name, YAML path, Material, or a randomisation dict, "
                              f"got {spec!r}")


def resolve_material(spec, rng: np.random.Generator | None) -> Material:
    """The material of an episode: ``spec`` loaded, or sampled from its ranges with ``rng``."""
    if not _is_randomisation(spec):
        return load_material(spec)
    m = load_material(spec.get("base", "thick_cotton"))
    rng = rng if rng is not None else np.random.default_rng(0)

    def draw(k, default):
        if k not in spec:
            return default
        lo, hi = spec[k]
        return float(rng.uniform(lo, hi))

    changes = dict(
        stretch=m.stretch.scaled(*(2 * [draw("stretch_scale", 1.0)])),
        bending=m.bending.scaled(*(2 * [draw("bending_scale", 1.0)])),
        shear=m.shear.scaled(*(2 * [draw("shear_scale", 1.0)])),
        areal_density=m.areal_density * draw("areal_density_scale", 1.0),
        friction=draw("friction", m.friction),
        damping=draw("damping", m.damping),
    )
    return m.replace(**changes)


@dataclass(frozen=True)
class EnvSnapshot:
    """Everything a cloth env's episode depends on, copied (:meth:`ClothEnv.get_state`).

    Restoring it (:meth:`ClothEnv.set_state`) and replaying the same actions is bit-identical to
    what followed when it was taken. It pickles, so it can be stored or sent to another process.

    Attributes
    ----------
    env
        The env class's name: a snapshot restores only into an env of that class (and the same
        lattice).
    model
        The episode's :class:`~cloth_gym.sim.model.Model` (immutable, shared; a randomised
        material makes one per episode).
    state
        The cloth: positions, velocities, time, step, obstacle offsets and the integrator's memory
        (:class:`~cloth_gym.sim.model.State`, a copy).
    grippers
        Each gripper's position, velocity, closed flag, the particles it holds, the slips so far.
    task
        The task's episode fields (:attr:`ClothEnv.episode_fields`, e.g. CornerLift's ``target``).
    rng, rng_seed
        The env's ``np_random`` generator, copied, and the seed it reports (``np_random_seed``).
    elapsed_steps
        Env steps since the last reset. A ``TimeLimit`` wrapper counts its own; restore it with
        ``env.set_wrapper_attr("_elapsed_steps", snapshot.elapsed_steps)``.
    diverged
        Whether the episode had diverged (then every step is a truncation).
    last_obs
        The last observation returned.
    """

    env: str
    model: Model
    state: State
    grippers: dict
    task: dict
    rng: np.random.Generator
    rng_seed: int | None
    elapsed_steps: int
    diverged: bool
    last_obs: np.ndarray | dict


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


class ClothEnv(gym.Env, EzPickle):
    """Base class of the cloth envs; see a task's docstring for its specification.

    Subclasses set ``n_grippers``, ``default_reward_weights``, ``default_sigma``,
    ``default_control_dt`` and implement the task hooks ``_build_model``,
    ``_reset_task``, ``_task_observation``, ``_keypoint_indices``,
    ``_reward_terms``, ``_is_success``, ``_workspace`` and ``_camera``.
    """

    metadata = {"render_modes": ["rgb_array", "depth_array", "human"], "render_fps": 20}
    n_grippers: int = 1
    default_reward_weights: dict = {}
    default_sigma: float = 2.0
    default_control_dt: float = 0.05
    #: the lattice conventions (:class:`~cloth_gym.sim.model.ForceOptions`' ``mass_lumping`` and
    #: ``damping_model``): the paper's, with which the v0 results were measured
    default_mass_lumping: str = "uniform"
    default_damping_model: str = "absolute"
    default_observation_dtype: str = "float64"
    #: give the observation Box the bounds that are known (each gripper's position within the
    #: workspace, closed 0/1, particles held 0..N) rather than (-inf, inf) everywhere
    bounded_observations: bool = False
    #: the colour of the task's target markers in frames and ``"rgb"`` observations (0–255)
    default_target_rgb: tuple = (40, 80, 230)
    #: may a closed gripper grasp again a particle that slipped from it (GripperConfig.regrasp_slipped)?
    gripper_regrasps_slipped: bool = True
    #: ImplicitEuler's ``max_travel`` (lattice spacings a free particle may move in one substep;
    #: None: off): shorter substeps while the cloth moves fast, as when a released cloth hits the floor
    default_max_travel: float | None = None
    default_sim_dt: float = 5e-3
    #: ``reset(options=...)`` keys a task accepts, each with its allowed values (the first is the
    #: default); any other key or value is a ConfigError naming it.
    reset_options: dict[str, tuple] = {}
    default_solver_tol: float = 1e-4
    #: ImplicitEuler's preconditioner: "auto" (the band factor on the small env lattices) unless a task
    #: measured better (DrapeOntoTable: lines)
    solver_preconditioner: str = "auto"
    default_solver_vtol: float = 1e-3  # cm/s: CG's absolute floor (ImplicitEuler's vtol)
    default_sleep_speed: float = 1e-3  # cm/s: a cloth at rest sleeps below it (ImplicitEuler's sleep_speed)
    #: s: substeps of a slow, quiet cloth (ImplicitEuler's slow_dt; 0: off) and the speed below which
    #: it applies (cm/s, ImplicitEuler's slow_speed)
    default_slow_sim_dt: float = 0.0
    default_slow_speed: float = 1.0
    default_strain_limiter_percent: float | None = None  # the implicit integrator's limiter (None: off)
    #: the defaults above that Breen's model (``model="breen"``) replaces (keys ``sim_dt``,
    #: ``strain_limiter_percent``): they were measured on KES cloth, and Breen's quartic springs,
    #: nearly slack at small strain, make a different cloth (docs/physics.md, Breen's model)
    breen_defaults: dict = {}
    OBSERVATION_MODES = ("state", "keypoints", "rgb")
    #: the attributes a task sets at reset that later steps read (its episode state, beyond the
    #: physics): copied into and out of snapshots (:meth:`get_state`)
    episode_fields: tuple[str, ...] = ()

    def __init__(self, material="thick_cotton", model: str = "kes", integrator: str = "implicit",
                 sigma: float | None = None, control_dt: float | None = None, sim_dt: float | None = None,
                 observation_mode: str = "state", reward_weights: Mapping[str, float] | None = None,
                 render_mode: str | None = None, image_size: int = 64, max_step_cm: float = 2.0,
                 grasp_radius_cm: float = 1.5, slip_strain_percent: float = 30.0,
                 strain_limiter_percent: float | None = None, solver_tol: float | None = None,
                 solver_vtol: float | None = None, sleep_speed: float | None = None,
                 slow_sim_dt: float | None = None, slow_speed: float | None = None, render_width: int = 320,
                 render_height: int = 240, camera=None, sim: Mapping | None = None,
                 mass_lumping: str | None = None, damping_model: str | None = None,
                 observation_dtype: str | None = None, target_rgb=None, **unknown):
        if isinstance(sim, Mapping):  # a plain dict: EzPickle keeps the arguments, and must pickle them
            sim = dict(sim)
        if unknown:  # a TypeError in Python's own words would not list what is valid
            valid = [p for p in inspect.signature(type(self).__init__).parameters if p not in ("self", "unknown")]
            name = sorted(unknown)[0]
            raise ConfigTypeError(name, f"unknown keyword argument of {type(self).__name__}; valid: {valid}")
        EzPickle.__init__(self, material=material, model=model, integrator=integrator, sigma=sigma,
                          control_dt=control_dt, sim_dt=sim_dt, observation_mode=observation_mode,
                          reward_weights=reward_weights, render_mode=render_mode, image_size=image_size,
                          max_step_cm=max_step_cm, grasp_radius_cm=grasp_radius_cm,
                          slip_strain_percent=slip_strain_percent, strain_limiter_percent=strain_limiter_percent,
                          solver_tol=solver_tol, solver_vtol=solver_vtol, sleep_speed=sleep_speed,
                          slow_sim_dt=slow_sim_dt, slow_speed=slow_speed, render_width=render_width,
                          render_height=render_height, camera=camera, sim=sim, mass_lumping=mass_lumping,
                          damping_model=damping_model, observation_dtype=observation_dtype, target_rgb=target_rgb)
        # ---- validation (every field named in the error)
        validate_material(material)
        if not isinstance(model, str) or model not in ("kes", "breen"):
            raise ConfigError("model", f"must be 'kes' or 'breen', got {model!r}")
        if not isinstance(integrator, str) or integrator not in ("implicit", "explicit"):
            raise ConfigError("integrator", f"must be 'implicit' or 'explicit', got {integrator!r}")
        sigma = self.default_sigma if sigma is None else real("sigma", sigma, 0.0, 50.0, lo_open=True)
        control_dt = (self.default_control_dt if control_dt is None
                      else real("control_dt", control_dt, 1e-3, 1.0, unit="s"))
        defaults = {"sim_dt": self.default_sim_dt, "strain_limiter_percent": self.default_strain_limiter_percent,
                    **(self.breen_defaults if model == "breen" else {})}
        sim_dt_given = sim_dt is not None
        if sim_dt is None:  # the default substep, shortened to divide control_dt
            sim_dt = control_dt / max(1, math.ceil(control_dt / defaults["sim_dt"] - 1e-9))
        else:
            sim_dt = real("sim_dt", sim_dt, 1e-6, 1.0, unit="s")
        if integrator != "implicit" and sim_dt_given:
            raise ConfigError("sim_dt", "is an option of the implicit integrator only (the explicit one picks "
                              "its substeps from its stability limit)")
        if strain_limiter_percent is None:  # the env's default (implicit integrator only)
            strain_limiter_percent = defaults["strain_limiter_percent"] if integrator == "implicit" else None
        else:
            if integrator != "implicit":
                raise ConfigError("strain_limiter_percent", "is an option of the implicit integrator only")
            strain_limiter_percent = real("strain_limiter_percent", strain_limiter_percent, 0.0, 100.0)
            if strain_limiter_percent == 0.0:  # 0: off
                strain_limiter_percent = None
        solver_tol = _implicit_option("solver_tol", solver_tol, self.default_solver_tol, integrator, 0.0, 0.1,
                                      lo_open=True)
        solver_vtol = _implicit_option("solver_vtol", solver_vtol, self.default_solver_vtol, integrator, 0.0, 10.0)
        sleep_speed = _implicit_option("sleep_speed", sleep_speed, self.default_sleep_speed, integrator, 0.0, 10.0)
        slow_sim_dt = _implicit_option("slow_sim_dt", slow_sim_dt, self.default_slow_sim_dt, integrator, 0.0,
                                       control_dt)
        slow_speed = _implicit_option("slow_speed", slow_speed, self.default_slow_speed, integrator, 0.0, 100.0)
        if integrator == "implicit":
            legacy = dict(sim_dt=sim_dt, solver_tol=solver_tol, solver_vtol=solver_vtol, sleep_speed=sleep_speed,
                          slow_sim_dt=slow_sim_dt, slow_speed=slow_speed, strain_limiter_percent=strain_limiter_percent)
            given = {k for k, v in self._ezpickle_kwargs.items() if k in SIM_ALIASES and v is not None}
            base = {SIM_ALIASES[k]: v for k, v in legacy.items()}
            base["preconditioner"] = self.solver_preconditioner
            if self.default_max_travel is not None:
                base["max_travel"] = self.default_max_travel
            given_max_dt = isinstance(sim, Mapping) and "max_dt" in sim
            sim = resolve_sim(sim, base, given, integrator)
            sim_dt, solver_tol, solver_vtol = sim["max_dt"], sim["tol"], sim["vtol"]
            sleep_speed, slow_sim_dt, slow_speed = sim["sleep_speed"], sim["slow_dt"], sim["slow_speed"]
            strain_limiter_percent = sim["strain_limit_percent"]
            if given_max_dt:
                check_substeps("sim.max_dt", "sim.max_dt", sim_dt, control_dt)
            else:
                check_substeps("control_dt", "sim_dt", sim_dt, control_dt)
        else:
            resolve_sim(sim, {}, set(), integrator)
            sim = {}
        if not isinstance(observation_mode, str) or observation_mode not in self.OBSERVATION_MODES:
            raise ConfigError("observation_mode", f"must be one of {list(self.OBSERVATION_MODES)}, "
                              f"got {observation_mode!r}")
        if render_mode is not None and not is_one_of(render_mode, self.metadata["render_modes"]):
            raise ConfigError("render_mode", f"must be one of {self.metadata['render_modes']} or None, "
                              f"got {render_mode!r}")
        if render_mode == "human":
            self._require_pygame()
        def default(value, fallback):  # None: the env version's default
            return fallback if value is None else value

        mass_lumping = one_of("mass_lumping", default(mass_lumping, self.default_mass_lumping), ("uniform", "area"))
        damping_model = one_of("damping_model", default(damping_model, self.default_damping_model),
                               ("absolute", "strain-rate"))
        observation_dtype = one_of("observation_dtype", default(observation_dtype, self.default_observation_dtype),
                                   ("float64", "float32"))
        self.target_rgb = self.default_target_rgb if target_rgb is None else _rgb("target_rgb", target_rgb)
        image_size = integer("image_size", image_size, 16, 1024)
        render_width = integer("render_width", render_width, 16, 4096)
        render_height = integer("render_height", render_height, 16, 4096)
        self.camera = None if camera is None else _camera(camera)
        weights = dict(self.default_reward_weights)
        if reward_weights is not None and not isinstance(reward_weights, Mapping):
            raise ConfigTypeError("reward_weights", f"must be a mapping of reward term to weight, got "
                                  f"{reward_weights!r}; terms: {sorted(weights)}")
        for k, v in (reward_weights or {}).items():
            if k not in weights:
                raise ConfigError(f"reward_weights.{k}", f"unknown reward term; allowed: {sorted(weights)}")
            weights[k] = real(f"reward_weights.{k}", v, -1e6, 1e6)
        self.gripper_config = GripperConfig(max_step_cm=max_step_cm, grasp_radius_cm=grasp_radius_cm,
                                            slip_strain_percent=slip_strain_percent,
                                            regrasp_slipped=self.gripper_regrasps_slipped)

        self.material_spec = material
        self.force_options = ForceOptions(model=model, mass_lumping=mass_lumping, damping_model=damping_model)
        self.observation_dtype = np.dtype(observation_dtype)
        self.integrator_kind = integrator
        self.sigma = float(sigma)
        self.control_dt = float(control_dt)
        self.sim_dt = float(sim_dt)
        self.strain_limiter_percent = strain_limiter_percent
        self.solver_tol = float(solver_tol)
        self.solver_vtol = float(solver_vtol)
        self.sleep_speed = float(sleep_speed)
        self.slow_sim_dt = float(slow_sim_dt)
        self.slow_speed = float(slow_speed)
        #: the implicit integrator's settings: the env's defaults, its options and ``sim`` (empty
        #: for the explicit integrator); each episode's integrator is ``ImplicitEuler(**sim)``
        self.sim = MappingProxyType(dict(sim))
        self.observation_mode = observation_mode
        self.reward_weights = weights
        self.render_mode = render_mode
        self.image_size = int(image_size)
        self.render_width = render_width
        self.render_height = render_height
        self._renderers: dict = {}
        self._window = None  # the pygame window of render_mode="human"
        self._keypoints_cache = None

        # the scene with the nominal material (rebuilt per episode only when randomised)
        try:
            self._model = self._build_model(resolve_material(material, None), self.force_options, self.sigma)
        except ConfigError as err:
            if err.field.endswith("_cm"):  # a cloth size that is no multiple of sigma
                raise ConfigError("sigma", str(err)) from None
            raise
        self.physics: ClothPhysics | None = None
        self._diverged = False
        self._last_obs = None
        self.elapsed_steps = 0

        self.action_space = spaces.Box(-1.0, 1.0, shape=(4 * self.n_grippers,), dtype=np.float32)
        if observation_mode == "rgb":
            self._require_renderer("observation_mode")
            self.observation_space = spaces.Box(0, 255, (self.image_size, self.image_size, 3), dtype=np.uint8)
        else:
            low, high = self._observation_bounds(self._model)
            self.observation_space = spaces.Box(low, high, dtype=self.observation_dtype)

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

    _measured: tuple = (None, None)  # (state key, measure) of the last state measured

    def _measure(self, physics: ClothPhysics):
        """:meth:`_compute_measure` of the current state, computed once per state (reward and
        success both call it; a reset starts afresh)."""
        key = (id(physics.state), physics.state.step, physics.state.time)
        if self._measured[0] != key:
            self._measured = (key, self._compute_measure(physics))
        return self._measured[1]

    def _keypoint_indices(self, model: Model) -> np.ndarray:
        return model.corners()

    def _reward_terms(self, physics: ClothPhysics, action: np.ndarray) -> dict:
        raise NotImplementedError

    def _is_success(self, physics: ClothPhysics) -> bool:
        raise NotImplementedError

    def _camera(self):
        raise NotImplementedError

    def _markers(self, physics: ClothPhysics) -> list:
        """Renderer markers: the grippers (red closed, green open), plus the task's."""
        out = []
        for g in range(physics.grippers.count):
            rgb = (220, 40, 40) if physics.grippers.closed[g] else (40, 200, 40)
            out.append((physics.grippers.position[g].copy(), 0.8, rgb))
        return out

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
        self._measured = (None, None)  # a new episode (its target may change)
        self._reset_task(self.physics, rng, options)
        self._diverged = False
        self.elapsed_steps = 0
        obs = self._get_obs()
        self._last_obs = obs
        if self.render_mode == "human":
            self.render()
        return obs, {"is_success": bool(self._is_success(self.physics)), "diverged": False}

    def _validate_action(self, action) -> np.ndarray:
        """``action`` as (grippers, 4) floats clipped to [−1, 1]: any real array-like of the right
        size; a wrong type (a string, a mapping, complex or ragged numbers) is a ConfigTypeError, a
        wrong size or a non-finite value a ConfigError."""
        expected = f"{4 * self.n_grippers} numbers ([dx, dy, dz, grip] per gripper)"
        if isinstance(action, (str, bytes, Mapping)) or action is None:
            raise ConfigTypeError("action", f"expected {expected}, got {action!r}")
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

    def step(self, action):
        if self.physics is None:
            raise ResetNeeded("call reset() before step()")
        a = self._validate_action(action)
        self.elapsed_steps += 1
        if self._diverged:  # stepping a diverged episode: nothing moves
            terms = {f"reward_{k}": 0.0 for k in self.reward_weights}
            return _copy_obs(self._last_obs), 0.0, False, True, {**terms, "is_success": False, "diverged": True}
        try:
            self.physics.step(a, self.control_dt)
        except (SimulationDiverged, InsideObstacle) as err:  # the latter: a released particle left in an obstacle
            self._diverged = True
            terms = {f"reward_{k}": 0.0 for k in self.reward_weights}
            info = {**terms, "is_success": False, "diverged": True, "divergence": str(err)}
            return _copy_obs(self._last_obs), 0.0, False, True, info
        terms = {k: float(v) for k, v in self._reward_terms(self.physics, a).items()}  # plain floats in info
        reward = float(sum(terms.values()))
        obs = self._get_obs()
        if self.observation_mode != "rgb" and not _finite_obs(obs):  # belt and braces
            self._diverged = True
            terms = {k: 0.0 for k in terms}
            return _copy_obs(self._last_obs), 0.0, False, True, {**terms, "is_success": False, "diverged": True}
        self._last_obs = obs
        if self.render_mode == "human":
            self.render()
        info = {**terms, "is_success": bool(self._is_success(self.physics)), "diverged": False,
                "slips": int(self.physics.grippers.slips), **self._task_info(self.physics)}
        return obs, reward, False, False, info

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
        rng = copy.deepcopy(self.np_random)
        return EnvSnapshot(type(self).__name__, p.model, p.state.copy(), p.grippers.snapshot(), task, rng,
                           self._np_random_seed, self.elapsed_steps, self._diverged,
                           None if self._last_obs is None else _copy_obs(self._last_obs))

    def set_state(self, snapshot: EnvSnapshot) -> None:
        """Return to ``snapshot`` (from :meth:`get_state` of an env of the same class and lattice),
        copying it in: the snapshot stays usable for further restores. A fresh integrator and
        fresh grippers take over; everything a later step reads is in the snapshot."""
        if not isinstance(snapshot, EnvSnapshot):
            raise ConfigTypeError("snapshot", f"expected an EnvSnapshot (env.get_state()), got "
                                  f"{type(snapshot).__name__}")
        if snapshot.env != type(self).__name__:
            raise ConfigError("snapshot", f"was taken from a {snapshot.env}, not a {type(self).__name__}")
        if snapshot.model.particle_count != self._model.particle_count:
            raise ConfigError("snapshot", f"has {snapshot.model.particle_count} particles, this env's cloth "
                              f"{self._model.particle_count} (another sigma?)")
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
        self._measured = (None, None)

    def __getstate__(self) -> dict:
        """Pickle and ``copy.deepcopy``: the constructor's arguments (EzPickle) and, mid-episode,
        the episode (:meth:`get_state`), so a copy continues where the original is."""
        d = EzPickle.__getstate__(self)
        if self.physics is not None:
            d["_episode"] = self.get_state()
        return d

    def __setstate__(self, d: dict) -> None:
        d = dict(d)
        episode = d.pop("_episode", None)
        EzPickle.__setstate__(self, d)
        if episode is not None:
            self.set_state(episode)

    def _get_obs(self) -> np.ndarray:
        p = self.physics
        if self.observation_mode == "rgb":
            return self._render_frame(self.image_size, self.image_size)
        if self.observation_mode == "state":
            cloth = np.concatenate([p.state.particle_q.ravel(), p.state.particle_qd.ravel()])
        else:
            cache = self._keypoints_cache
            if cache is None or cache[0] is not p.model:  # a model's keypoints do not change
                cache = self._keypoints_cache = (p.model, np.asarray(self._keypoint_indices(p.model)))
            k = cache[1]
            cloth = np.concatenate([p.state.particle_q[k].ravel(), p.state.particle_qd[k].ravel()])
        # np.concatenate always allocates: the observation shares no memory with the state
        obs = np.concatenate([cloth, p.grippers.observation().ravel(),
                              np.asarray(self._task_observation(p), dtype=np.float64).ravel()])
        return obs if self.observation_dtype == np.float64 else obs.astype(self.observation_dtype)

    # ------------------------------------------------------------------ rendering
    def _require_renderer(self, field: str):
        try:
            from .. import render  # noqa: F401
        except ImportError as err:
            raise ConfigError(field, f"needs the renderer (cloth_gym.render), which cannot be imported: {err}") from None

    def _renderer(self, width: int, height: int):
        from ..render import Renderer

        key = (width, height)
        r = self._renderers.get(key)
        if r is None:
            r = self._renderers[key] = Renderer(width, height, camera=self.camera or self._camera())
        return r

    def _render_frame(self, width: int, height: int) -> np.ndarray:
        frame = self._renderer(width, height).render_scene(self.physics.model, self.physics.state,
                                                           markers=self._markers(self.physics))
        return np.ascontiguousarray(frame, dtype=np.uint8)

    def _require_pygame(self):
        try:
            import pygame  # noqa: F401
        except ImportError:
            raise ConfigError("render_mode", "'human' shows the frames in a pygame window, and pygame is not "
                              "installed (pip install pygame); 'rgb_array' returns them instead") from None

    def render(self):
        """The scene seen by the task's camera (or the ``camera`` argument), ``render_width`` ×
        ``render_height`` px (320 × 240 by default): an RGB frame (H, W, 3) uint8
        (``render_mode="rgb_array"``); its depth image (H, W) float32, the distance in cm along the
        view direction, ``inf`` where only background shows (``"depth_array"``); or the frame shown
        in a window (``"human"``, also after every reset and step; returns None). None without a
        render mode."""
        if self.render_mode is None or self.physics is None:
            return None
        self._require_renderer("render_mode")
        if self.render_mode == "depth_array":
            return self._renderer(self.render_width, self.render_height).render_scene_depth(
                self.physics.model, self.physics.state, markers=self._markers(self.physics))
        frame = self._render_frame(self.render_width, self.render_height)
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


class V1Defaults:
    """What the v1 envs change over v0, as a mixin before the task class (``class
    CornerLiftV1Env(V1Defaults, CornerLiftEnv)``); the first four are also arguments:

    * the real fabric resolution, σ = 1 cm;
    * the simulator's own lattice conventions: each particle's mass and each element's width
      from the fabric area it stands for, and the material's damping acting on deformation rates
      only (a carried or falling cloth is not slowed);
    * float32 observations (what SB3 and torch use);
    * target markers in orange, far from the cloth's blue;
    * a particle that slipped from a gripper is not grasped again until the gripper opens (a taut
      grasp that slips lets go, rather than slipping and re-grasping while the strain ratchets up
      to the strain guard);
    * substeps short enough that no free particle moves more than half a lattice spacing in one
      (``sim={"max_travel": 0.5}``: a cloth released 60 cm above the floor lands at about 3 m/s,
      which in 5 ms substeps on a 1 cm lattice tears it past the strain guard);
    * observation Boxes with the bounds that are known: each gripper's position within the
      workspace, closed 0 or 1, particles held 0 to N (the cloth and task entries stay unbounded).
    """

    default_sigma: float = 1.0
    default_mass_lumping: str = "area"
    default_damping_model: str = "strain-rate"
    default_observation_dtype: str = "float32"
    default_target_rgb: tuple = (250, 150, 20)
    gripper_regrasps_slipped: bool = False
    default_max_travel: float | None = 0.5
    bounded_observations: bool = True
