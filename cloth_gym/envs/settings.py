"""The settings of a cloth env: its keyword arguments, checked once, as one frozen object.

:class:`EnvSettings` holds three parts: :class:`PhysicsSettings` (material, force model,
lattice, integrator and its substeps), :class:`TaskSettings` (reward weights, grippers) and
:class:`ViewSettings` (observations and rendering). :meth:`EnvSettings.from_kwargs` builds it
from an env's keyword arguments; a keyword left ``None`` takes the env's default, which its
class states in ``defaults`` (merged along the class hierarchy, ``sim_defaults`` key by key).
A registered version is its task's class with other keyword arguments (``gymnasium.spec(id).kwargs``,
``cloth_gym.envs.ENV_SPECS``). Every bad value raises :class:`~cloth_gym.errors.ConfigError`
naming the field; an unknown keyword lists the valid ones.
"""

from __future__ import annotations

import functools
import inspect
import math
from dataclasses import dataclass
from os import PathLike
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from ..errors import ConfigError, ConfigTypeError
from ..materials import Material, available_materials, load_material
from ..sim.model import ForceOptions
from ..validation import flag, integer, is_one_of, one_of, real, vector
from .grippers import GripperConfig

__all__ = ["EnvSettings", "PhysicsSettings", "TaskSettings", "ViewSettings", "OPTIONS", "BASE_DEFAULTS",
           "class_defaults", "init_signature", "LIBRARY", "MAX_SUBSTEPS", "RANDOMISABLE", "material_choices",
           "resolve_material", "validate_material"]

#: the most implicit substeps an env takes per control step (``control_dt / sim_dt``)
MAX_SUBSTEPS = 10_000

#: every keyword argument of a cloth env, in order, with its default (None: the env's, from its
#: class's ``defaults``; for the solver options: from ``sim_defaults``)
OPTIONS = {
    "material": "thick_cotton", "model": "kes", "integrator": "implicit", "sigma": None, "control_dt": None,
    "sim_dt": None, "observation_mode": "state", "reward_weights": None, "render_mode": None, "image_size": 64,
    "max_step_cm": 2.0, "grasp_radius_cm": 1.5, "slip_strain_percent": 30.0, "strain_limiter_percent": None,
    "solver_tol": None, "solver_vtol": None, "sleep_speed": None, "slow_sim_dt": None, "slow_speed": None,
    "render_width": 320, "render_height": 240, "camera": None, "sim": None, "mass_lumping": None,
    "damping_model": None, "observation_dtype": None, "target_rgb": None, "regrasp_slipped": None,
    "bounded_observations": None, "start_tilt_deg": None, "sim_defaults": None,
}

#: ``ClothEnv.defaults``: what a keyword left None means unless a task or version says otherwise.
#: ``sim_defaults`` are :class:`~cloth_gym.sim.implicit.ImplicitEuler`'s settings under its own names.
BASE_DEFAULTS = {
    "sigma": 2.0, "control_dt": 0.05, "mass_lumping": "uniform", "damping_model": "absolute",
    "observation_dtype": "float64", "target_rgb": (40, 80, 230), "regrasp_slipped": True,
    "bounded_observations": False, "start_tilt_deg": 0.0,
    "sim_defaults": {"max_dt": 5e-3, "tol": 1e-4, "vtol": 1e-3, "sleep_speed": 1e-3, "slow_dt": 0.0,
                     "slow_speed": 1.0, "strain_limit_percent": None, "preconditioner": "auto",
                     "momentum_exact": False, "max_travel": None, "retry_diverged": False},
}

#: ``sim`` keys each of the env's own solver options sets (the v0 ids' documented names)
SIM_ALIASES = {"sim_dt": "max_dt", "solver_tol": "tol", "solver_vtol": "vtol", "sleep_speed": "sleep_speed",
               "slow_sim_dt": "slow_dt", "slow_speed": "slow_speed", "strain_limiter_percent": "strain_limit_percent"}

#: Keys of a domain-randomisation material dict, each a ``(low, high)`` range sampled
#: uniformly at every reset: multiplicative scales of the KES curves and the areal
#: density, and absolute values of friction (μ) and damping (1/s).
RANDOMISABLE = ("stretch_scale", "bending_scale", "shear_scale", "areal_density_scale", "friction", "damping")

#: ``material="library"`` (or ``{"choose": "library", ...}``): each episode's fabric drawn
#: uniformly from every shipped material (``cloth_gym.materials.available_materials()``)
LIBRARY = "library"

#: the keys every material mapping has (``configs/materials/*.yaml``); a mapping with any of them is a
#: material, not a randomisation dict (whose keys may overlap a material's: ``friction``)
MATERIAL_KEYS = ("areal_density_g_per_cm2", "stretch", "bending", "shear")

CAMERA_KEYS = ("eye", "target", "up", "fov_deg")


def init_signature() -> inspect.Signature:
    """The signature of ``ClothEnv.__init__``: ``self`` and every option of :data:`OPTIONS`, keyword only."""
    kw = inspect.Parameter.KEYWORD_ONLY
    return inspect.Signature([inspect.Parameter("self", inspect.Parameter.POSITIONAL_OR_KEYWORD)]
                             + [inspect.Parameter(k, kw, default=v) for k, v in OPTIONS.items()])


def class_defaults(cls) -> dict:
    """The defaults of ``cls``: every ``defaults`` mapping along its class hierarchy, the most derived
    winning, ``sim_defaults`` merged key by key."""
    out, sim = {}, {}
    for c in reversed(cls.__mro__):
        d = c.__dict__.get("defaults")
        if d:
            out.update(d)
            sim.update(d.get("sim_defaults", {}))
    out["sim_defaults"] = sim
    return out


def sim_keys() -> list[str]:
    """The keys of an env's ``sim`` mapping: the parameters of :class:`~cloth_gym.sim.implicit.ImplicitEuler`."""
    from ..sim.implicit import ImplicitEuler

    return [p for p in inspect.signature(ImplicitEuler.__init__).parameters if p != "self"]


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


def _sim_mapping(field: str, sim, integrator: str) -> dict:
    """``sim`` or ``sim_defaults`` as a dict with only ImplicitEuler's keys (errors name ``field.<key>``)."""
    if sim is None:
        return {}
    if not isinstance(sim, Mapping):
        raise ConfigTypeError(field, f"must be a mapping of ImplicitEuler's options, got {sim!r}; keys: {sim_keys()}")
    allowed = sim_keys()
    for k in sim:
        if k not in allowed:
            raise ConfigError(f"{field}.{k}", f"unknown key; allowed: {allowed}")
    return dict(sim)


def _checked_by_integrator(field: str, settings: dict) -> dict:
    """``settings`` if ``ImplicitEuler(**settings)`` accepts them; its error renamed ``field.<key>``."""
    from ..sim.implicit import ImplicitEuler

    try:
        ImplicitEuler(**settings)
    except ConfigError as err:
        raise type(err)(f"{field}.{err.field}", err.message) from None
    return settings


def resolve_sim(sim, base: dict, given: set, integrator: str) -> dict:
    """The implicit integrator's settings of an env: ``base`` (the env's defaults and its own
    options, ``given`` naming those set by the user) updated with the ``sim`` mapping, checked by
    :class:`~cloth_gym.sim.implicit.ImplicitEuler` itself; errors name ``sim.<key>``."""
    sim = _sim_mapping("sim", sim, integrator)
    if sim and integrator != "implicit":
        raise ConfigError("sim", "sets the implicit integrator's options; integrator='explicit' has none")
    for k in sim:
        clash = [name for name, key in SIM_ALIASES.items() if key == k and name in given]
        if clash:
            raise ConfigError(f"sim.{k}", f"is given twice: also as {clash[0]}=")
    return _checked_by_integrator("sim", {**base, **sim})


def _is_randomisation(spec) -> bool:
    """Whether ``spec`` draws each episode's material: ``"library"``, a list of materials, or a
    randomisation dict (keys ``base`` or ``choose`` and the ranges of :data:`RANDOMISABLE`)."""
    if isinstance(spec, str) and spec == LIBRARY or isinstance(spec, (list, tuple)):
        return True
    return (isinstance(spec, Mapping) and not any(k in spec for k in MATERIAL_KEYS)
            and ("base" in spec or "choose" in spec or any(k in spec for k in RANDOMISABLE)))


def _as_dict(spec) -> tuple[Mapping, str]:
    """A randomisation ``spec`` as a dict, and the field its choices are named under in errors."""
    if isinstance(spec, (str, list, tuple)):
        return {"choose": spec}, "material"
    return spec, "material.choose"


@functools.lru_cache(maxsize=64)
def _shipped(name: str) -> Material:
    """A shipped material by name, read once (a measured fabric's file holds its samples: 25 ms)."""
    return load_material(name)


def _load_choice(spec) -> Material:
    if isinstance(spec, str) and "/" not in spec and "." not in spec:
        return _shipped(spec)
    return load_material(spec)


def _choice_specs(choose, field: str) -> list:
    if isinstance(choose, str) and choose == LIBRARY:
        names = available_materials()
        if not names:
            raise ConfigError(field, "'library': no shipped materials found (a broken install?)")
        return names
    if not isinstance(choose, (list, tuple)):
        raise ConfigTypeError(field, f"must be {LIBRARY!r} or a list of materials (names, YAML paths, Materials, "
                              f"material mappings), got {choose!r}")
    if not choose:
        raise ConfigError(field, "must name at least one material")
    return list(choose)


def material_choices(spec) -> tuple[Material, ...] | None:
    """The materials an episode's fabric is drawn from (uniformly, before any ranges are applied),
    or None when ``spec`` chooses none (one material, or ranges on one ``base``)."""
    if not _is_randomisation(spec):
        return None
    d, field = _as_dict(spec)
    if "choose" not in d:
        return None
    out = []
    for i, c in enumerate(_choice_specs(d["choose"], field)):
        try:
            out.append(_load_choice(c))
        except ConfigError as err:
            raise type(err)(f"{field}[{i}]" + (f".{err.field}" if err.field != "material" else ""),
                            err.message) from None
    return tuple(out)


def _check_ranges(spec, base: Material) -> None:
    """Each ``(low, high)`` range of a randomisation dict: ordered, in range, and both its extremes
    making a valid material on ``base``."""
    for k in RANDOMISABLE:
        if k in spec:
            r = spec[k]
            if not (isinstance(r, (tuple, list)) and len(r) == 2):
                raise ConfigTypeError(f"material.{k}", f"must be a (low, high) range, got {r!r}")
            lo = real(f"material.{k}", r[0], 0.0, 1e4, lo_open=k.endswith("_scale"))
            hi = real(f"material.{k}", r[1], 0.0, 1e4, lo_open=k.endswith("_scale"))
            if lo > hi:
                raise ConfigError(f"material.{k}", f"low {lo} > high {hi}")
    # each range's extremes must make a valid material too (friction <= 10, density <= 10 g/cm², ...)
    for k in RANDOMISABLE:
        for pick in (0, 1):
            if k in spec:
                try:
                    resolve_material({"base": base, k: (spec[k][pick], spec[k][pick])}, None)
                except ConfigError as err:
                    raise ConfigError(f"material.{k}", f"{spec[k][pick]!r} makes an invalid material"
                                      f"{' on ' + repr(base.name) if 'choose' in spec else ''}: {err}") from None


def validate_material(spec) -> None:
    """Check a ``material`` option now (names, paths, choices and ranges), raising ConfigError
    naming the field."""
    if _is_randomisation(spec):
        d, _ = _as_dict(spec)
        allowed = ("base", "choose", *RANDOMISABLE)
        unknown = sorted((k for k in d if k not in allowed), key=str)
        if unknown:
            raise ConfigError(f"material.{unknown[0]}", f"unknown key; allowed: {list(allowed)}")
        if "base" in d and "choose" in d:
            raise ConfigError("material.choose", "give 'base' (one material) or 'choose' (several), not both")
        bases = material_choices(spec)
        if bases is None:
            base = d.get("base", "thick_cotton")
            if isinstance(base, Mapping) and not any(k in base for k in MATERIAL_KEYS):
                raise ConfigError("material.base", f"must be a material (a name, a YAML path, a Material or a "
                                  f"material mapping with keys {list(MATERIAL_KEYS)}), got {base!r}")
            try:
                bases = (load_material(base),)  # once: every range's extremes are drawn on it
            except ConfigError as err:
                raise type(err)(f"material.base.{err.field}", err.message) from None
        for base in bases:
            _check_ranges(d, base)
    elif isinstance(spec, Mapping) and not any(k in spec for k in MATERIAL_KEYS):
        raise ConfigError("material", f"a mapping must be a material (keys {list(MATERIAL_KEYS)}, ...) or a "
                          f"randomisation dict (keys 'base', 'choose', {', '.join(RANDOMISABLE)}); got keys "
                          f"{sorted(map(str, spec))}")
    elif isinstance(spec, (str, PathLike, Mapping, Material)):
        load_material(spec)
    else:
        raise ConfigTypeError("material", f"expected a name, YAML path, Material, {LIBRARY!r}, a list of "
                              f"materials or a randomisation dict, got {spec!r}")


def resolve_material(spec, rng: np.random.Generator | None) -> Material:
    """The material of an episode: ``spec`` loaded, or drawn with ``rng``: first the fabric from
    its choices (uniformly), then each range's value (uniformly, in :data:`RANDOMISABLE` order).
    Without ``rng`` (the env's nominal model): the first choice, and ranges drawn with seed 0."""
    if not _is_randomisation(spec):
        return load_material(spec)
    d, field = _as_dict(spec)
    if "choose" not in d:
        m = load_material(d.get("base", "thick_cotton"))
    else:  # load only the one drawn (validate_material has loaded every choice once)
        specs = _choice_specs(d["choose"], field)
        m = _load_choice(specs[0 if rng is None else int(rng.integers(len(specs)))])
    if not any(k in d for k in RANDOMISABLE):
        return m
    rng = rng if rng is not None else np.random.default_rng(0)

    def draw(k, default):
        if k not in d:
            return default
        lo, hi = d[k]
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


def _rgb(field: str, value) -> tuple:
    """An RGB colour: three numbers in [0, 255]."""
    v = vector(field, value, 3)
    if np.any(v < 0) or np.any(v > 255):
        raise ConfigError(field, f"must be three numbers in [0, 255] (red, green, blue), got {value!r}")
    return tuple(int(round(c)) for c in v)


def _require_pygame() -> None:
    try:
        import pygame  # noqa: F401
    except ImportError:
        raise ConfigError("render_mode", "'human' shows the frames in a pygame window, and pygame is not "
                          "installed (pip install pygame); 'rgb_array' returns them instead") from None


@dataclass(frozen=True)
class PhysicsSettings:
    """The simulation: ``material`` (as given: a randomisation dict is sampled at each reset), the
    force model and lattice conventions (``force_options``), the lattice spacing ``sigma`` (cm), the
    control interval and the implicit substep (s), and the integrator: ``"implicit"``, built as
    ``ImplicitEuler(**sim)``, or ``"explicit"`` (``sim`` empty). ``sim_dt`` … ``strain_limiter_percent``
    repeat entries of ``sim`` under the env's own names (the explicit integrator: the defaults)."""

    material: Any
    force_options: ForceOptions
    integrator: str
    sigma: float
    control_dt: float
    sim_dt: float
    sim: Mapping
    strain_limiter_percent: float | None
    solver_tol: float
    solver_vtol: float
    sleep_speed: float
    slow_sim_dt: float
    slow_speed: float


@dataclass(frozen=True)
class TaskSettings:
    """The task's weight of each reward term, the grippers' constants and the largest tilt (degrees)
    out of its plane of a starting cloth that hangs (each reset draws one uniformly within ±it)."""

    reward_weights: Mapping
    gripper: GripperConfig
    start_tilt_deg: float = 0.0


@dataclass(frozen=True)
class ViewSettings:
    """Observations (mode, dtype, whether the gripper entries of the Box are bounded) and rendering
    (mode, frame size, ``"rgb"`` observation size, camera: None for the task's, target marker colour)."""

    observation_mode: str
    observation_dtype: np.dtype
    bounded_observations: bool
    render_mode: str | None
    render_width: int
    render_height: int
    image_size: int
    camera: Any
    target_rgb: tuple


@dataclass(frozen=True)
class EnvSettings:
    """An env's settings, checked: :class:`PhysicsSettings`, :class:`TaskSettings`,
    :class:`ViewSettings`, and ``kwargs``, the keyword arguments as given (what pickling replays)."""

    physics: PhysicsSettings
    task: TaskSettings
    view: ViewSettings
    kwargs: Mapping

    @classmethod
    def from_kwargs(cls, env_cls, kwargs: Mapping) -> "EnvSettings":
        """The settings of an ``env_cls`` made with ``kwargs``: unknown keys raise
        :class:`~cloth_gym.errors.ConfigTypeError` listing the valid ones; a key left None takes
        the env's default (:func:`class_defaults`)."""
        unknown = sorted((k for k in kwargs if k not in OPTIONS), key=str)
        if unknown:  # a TypeError in Python's own words would not list what is valid
            raise ConfigTypeError(unknown[0], f"unknown keyword argument of {env_cls.__name__}; "
                                  f"valid: {list(OPTIONS)}")
        given = dict(kwargs)
        for k in ("sim", "sim_defaults"):  # plain dicts: pickling replays the arguments
            if isinstance(given.get(k), Mapping):
                given[k] = dict(given[k])
        kw = {**OPTIONS, **given}
        defaults = class_defaults(env_cls)
        physics = _physics(env_cls, kw, defaults)
        view = _view(env_cls, kw, defaults)
        task = _task(env_cls, kw, defaults)
        return cls(physics, task, view, MappingProxyType(given))


def _solver_defaults(env_cls, kw: dict, defaults: dict) -> dict:
    """ImplicitEuler's defaults of this env: its class's ``sim_defaults``, the ``sim_defaults``
    argument's key by key, then, on Breen's model, the class's ``breen_defaults``."""
    base = dict(defaults["sim_defaults"])
    own = _sim_mapping("sim_defaults", kw["sim_defaults"], kw["integrator"])
    if own:
        _checked_by_integrator("sim_defaults", {**base, **own})
    base.update(own)
    if kw["model"] == "breen":
        base.update(getattr(env_cls, "breen_defaults", {}))
    return base


def _physics(env_cls, kw: dict, defaults: dict) -> PhysicsSettings:
    validate_material(kw["material"])
    model, integrator = kw["model"], kw["integrator"]
    if not isinstance(model, str) or model not in ("kes", "breen"):
        raise ConfigError("model", f"must be 'kes' or 'breen', got {model!r}")
    if not isinstance(integrator, str) or integrator not in ("implicit", "explicit"):
        raise ConfigError("integrator", f"must be 'implicit' or 'explicit', got {integrator!r}")
    sigma = defaults["sigma"] if kw["sigma"] is None else real("sigma", kw["sigma"], 0.0, 50.0, lo_open=True)
    control_dt = (defaults["control_dt"] if kw["control_dt"] is None
                  else real("control_dt", kw["control_dt"], 1e-3, 1.0, unit="s"))
    base = _solver_defaults(env_cls, kw, defaults)
    if kw["sim_dt"] is None:  # the default substep, shortened to divide control_dt
        sim_dt = control_dt / max(1, math.ceil(control_dt / base["max_dt"] - 1e-9))
    else:
        sim_dt = real("sim_dt", kw["sim_dt"], 1e-6, 1.0, unit="s")
        if integrator != "implicit":
            raise ConfigError("sim_dt", "is an option of the implicit integrator only (the explicit one picks "
                              "its substeps from its stability limit)")
    limiter = kw["strain_limiter_percent"]
    if limiter is None:  # the env's default (implicit integrator only)
        limiter = base["strain_limit_percent"] if integrator == "implicit" else None
    else:
        if integrator != "implicit":
            raise ConfigError("strain_limiter_percent", "is an option of the implicit integrator only")
        limiter = real("strain_limiter_percent", limiter, 0.0, 100.0)
        if limiter == 0.0:  # 0: off
            limiter = None
    own = dict(sim_dt=sim_dt, strain_limiter_percent=limiter,
               solver_tol=_implicit_option("solver_tol", kw["solver_tol"], base["tol"], integrator, 0.0, 0.1,
                                           lo_open=True),
               solver_vtol=_implicit_option("solver_vtol", kw["solver_vtol"], base["vtol"], integrator, 0.0, 10.0),
               sleep_speed=_implicit_option("sleep_speed", kw["sleep_speed"], base["sleep_speed"], integrator,
                                            0.0, 10.0),
               slow_sim_dt=_implicit_option("slow_sim_dt", kw["slow_sim_dt"], base["slow_dt"], integrator, 0.0,
                                            control_dt),
               slow_speed=_implicit_option("slow_speed", kw["slow_speed"], base["slow_speed"], integrator, 0.0,
                                           100.0))
    sim = _integrator_settings(kw, base, own, control_dt)
    if sim:  # the settings the integrator will use, under the env's own names
        own.update(sim_dt=sim["max_dt"], solver_tol=sim["tol"], solver_vtol=sim["vtol"],
                   sleep_speed=sim["sleep_speed"], slow_sim_dt=sim["slow_dt"], slow_speed=sim["slow_speed"],
                   strain_limiter_percent=sim["strain_limit_percent"])
    lumping = one_of("mass_lumping", _or(kw["mass_lumping"], defaults["mass_lumping"]), ("uniform", "area"))
    damping = one_of("damping_model", _or(kw["damping_model"], defaults["damping_model"]),
                     ("absolute", "strain-rate"))
    floats = {k: float(v) for k, v in own.items() if k != "strain_limiter_percent"}
    return PhysicsSettings(kw["material"], ForceOptions(model=model, mass_lumping=lumping, damping_model=damping),
                           integrator, float(sigma), float(control_dt), sim=MappingProxyType(sim),
                           strain_limiter_percent=own["strain_limiter_percent"], **floats)


def _integrator_settings(kw: dict, base: dict, own: dict, control_dt: float) -> dict:
    """``ImplicitEuler``'s arguments: ``base`` (the env's solver defaults), the env's own options
    ``own`` and the ``sim`` mapping over them, with the substeps checked against ``control_dt``
    (empty for the explicit integrator, which takes no ``sim``)."""
    if kw["integrator"] != "implicit":
        resolve_sim(kw["sim"], {}, set(), kw["integrator"])
        return {}
    given = {k for k in SIM_ALIASES if kw[k] is not None}
    sim = resolve_sim(kw["sim"], {**base, **{SIM_ALIASES[k]: v for k, v in own.items()}}, given, "implicit")
    if isinstance(kw["sim"], Mapping) and "max_dt" in kw["sim"]:
        check_substeps("sim.max_dt", "sim.max_dt", sim["max_dt"], control_dt)
    else:
        check_substeps("control_dt", "sim_dt", sim["max_dt"], control_dt)
    return sim


def _or(value, fallback):
    """``value``, or ``fallback`` (the env's default) when it is None."""
    return fallback if value is None else value


def _view(env_cls, kw: dict, defaults: dict) -> ViewSettings:
    mode = kw["observation_mode"]
    if not isinstance(mode, str) or mode not in env_cls.OBSERVATION_MODES:
        raise ConfigError("observation_mode", f"must be one of {list(env_cls.OBSERVATION_MODES)}, got {mode!r}")
    render_mode = kw["render_mode"]
    if isinstance(render_mode, str) and render_mode == "human":
        _require_pygame()  # not advertised without pygame: say what is missing
    if render_mode is not None and not is_one_of(render_mode, env_cls.metadata["render_modes"]):
        raise ConfigError("render_mode", f"must be one of {env_cls.metadata['render_modes']} or None, "
                          f"got {render_mode!r}")
    dtype = one_of("observation_dtype", _or(kw["observation_dtype"], defaults["observation_dtype"]),
                   ("float64", "float32"))
    rgb = defaults["target_rgb"] if kw["target_rgb"] is None else _rgb("target_rgb", kw["target_rgb"])
    image_size = integer("image_size", kw["image_size"], 16, 1024)
    width = integer("render_width", kw["render_width"], 16, 4096)
    height = integer("render_height", kw["render_height"], 16, 4096)
    camera = None if kw["camera"] is None else _camera(kw["camera"])
    bounded = flag("bounded_observations", _or(kw["bounded_observations"], defaults["bounded_observations"]))
    return ViewSettings(mode, np.dtype(dtype), bounded, render_mode, width, height, image_size, camera, rgb)


def _task(env_cls, kw: dict, defaults: dict) -> TaskSettings:
    weights = dict(env_cls.default_reward_weights)
    given = kw["reward_weights"]
    if given is not None and not isinstance(given, Mapping):
        raise ConfigTypeError("reward_weights", f"must be a mapping of reward term to weight, got "
                              f"{given!r}; terms: {sorted(weights)}")
    for k, v in (given or {}).items():
        if k not in weights:
            raise ConfigError(f"reward_weights.{k}", f"unknown reward term; allowed: {sorted(weights)}")
        weights[k] = real(f"reward_weights.{k}", v, -1e6, 1e6)
    gripper = GripperConfig(max_step_cm=kw["max_step_cm"], grasp_radius_cm=kw["grasp_radius_cm"],
                            slip_strain_percent=kw["slip_strain_percent"],
                            regrasp_slipped=_or(kw["regrasp_slipped"], defaults["regrasp_slipped"]))
    tilt = real("start_tilt_deg", _or(kw["start_tilt_deg"], defaults["start_tilt_deg"]), 0.0, 10.0, unit="degrees")
    if tilt and not getattr(env_cls, "hangs_at_start", False):
        raise ConfigError("start_tilt_deg", f"tilts a cloth that hangs at the start (RibbonDrop's); "
                          f"{env_cls.__name__} takes 0, got {tilt}")
    return TaskSettings(MappingProxyType(weights), gripper, tilt)
