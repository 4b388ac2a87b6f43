"""Training configurations: rl-baselines3-zoo's hyperparameter files, loaded into typed objects.

``configs/train/<algo>.yaml`` is a file in the zoo's format, keyed by env id,
with a ``default`` entry used for ids it does not name (the zoo reads it the
same way), so that::

    python -m rl_zoo3.train --algo ppo --env cloth_gym/CornerLift-v0 \\
        --gym-packages cloth_gym -conf configs/train/ppo.yaml

trains with the very same numbers as ``scripts/train.py``. Entries may share
settings through YAML anchors (``<<: *default``).

Unlike the zoo, nothing here is ``eval``-ed: a value is data. Allowed keys are
the zoo's own (``n_timesteps``, ``policy``, ``n_envs``, ``normalize``,
``env_kwargs``, ``policy_kwargs``, ``env_wrapper``, ``callback``) plus the
constructor arguments of the SB3 algorithm; anything else is a :class:`~cloth_gym.errors.ConfigError` that
lists what is allowed. Learning rates may be a number or the zoo's linear
schedule string ``"lin_<initial>"``. ``policy_kwargs`` accepts ``net_arch``,
``log_std_init``, ``ortho_init``, ``activation_fn`` (a name: ``tanh``,
``relu``, ``elu``, ``leaky_relu``), ``n_critics``, ``use_sde``,
``share_features_extractor`` and ``features_extractor_class`` (a class of
:mod:`cloth_gym.agents.features` by its full name) with its ``features_extractor_kwargs``; a
config with a features extractor trains through ``scripts/train.py``, not the zoo (which would
need the class as Python in a ``policy_kwargs`` string). ``env_wrapper`` (the zoo's
key: a name, a ``{name: kwargs}`` mapping, or a list of them) accepts the
classes of :mod:`cloth_gym.wrappers` by their full name
(``cloth_gym.wrappers.StartCurriculum``); ``scripts/train.py`` wraps the
training envs with them, not the evaluation env. ``replay_buffer_class`` (off-policy only) is a
name, ``HerReplayBuffer``, with its arguments as a ``replay_buffer_kwargs`` mapping. ``callback`` (the zoo's key,
in the same forms) accepts the classes of :mod:`cloth_gym.agents.callbacks`
(``cloth_gym.agents.callbacks.ExpertDemos``: scripted-expert episodes in the replay buffer,
SACfD style; ``cloth_gym.agents.callbacks.GripExploration``: ez-greedy on the grip), for
the off-policy algorithms (``sac``, ``tqc``) only; their arguments are checked
here, when the config loads.

Every shipped file is therefore a zoo file. The keys of cloth_gym's earlier
format (``expert_demos``, ``demo_pretrain_steps``, ``grip_exploration``) are
rejected with the ``callback`` entry that replaces them.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from cloth_gym.errors import ConfigError, ConfigTypeError
from cloth_gym.materials import configs_dir
from cloth_gym.validation import is_file, read_yaml

__all__ = ["ALGOS", "TrainConfig", "load_train_config", "parse_overrides", "with_overrides", "algo_class",
           "require_ray", "CONFIG_DIR"]

CONFIG_DIR = configs_dir() / "train"
ALGOS = ("ppo", "sac", "tqc")
ZOO_KEYS = ("n_timesteps", "policy", "n_envs", "normalize", "env_kwargs", "policy_kwargs", "env_wrapper",
            "callback")
WRAPPER_MODULE = "cloth_gym.wrappers"
CALLBACK_MODULE = "cloth_gym.agents.callbacks"
#: the module path of the callbacks in run configs written before the baselines shipped inside the
#: package (``cloth_gym.agents.callbacks.ExpertDemos``): read as CALLBACK_MODULE
LEGACY_CALLBACK_MODULE = "agents.callbacks"
# cloth_gym's earlier keys (before they became zoo callbacks) -> the callback that replaces them
_FORMER_KEYS = {
    "expert_demos": "callback: [{cloth_gym.agents.callbacks.ExpertDemos: {episodes: N, pretrain_steps: M}}]",
    "demo_pretrain_steps": "callback: [{cloth_gym.agents.callbacks.ExpertDemos: {episodes: N, pretrain_steps: M}}]",
    "grip_exploration": "callback: [{cloth_gym.agents.callbacks.GripExploration: {probability: P, mean_steps: M}}]",
}
OFF_POLICY = ("sac", "tqc")
#: replay buffers a config may name under ``replay_buffer_class`` (SB3's classes, by name)
REPLAY_BUFFERS = ("HerReplayBuffer",)
POLICY_KWARGS = ("net_arch", "log_std_init", "ortho_init", "activation_fn", "n_critics", "use_sde",
                 "features_extractor_class", "features_extractor_kwargs", "share_features_extractor")
FEATURES_MODULE = "cloth_gym.agents.features"
ACTIVATIONS = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU"}
_NOT_CONFIGURABLE = {"self", "policy", "env", "verbose", "seed", "device", "tensorboard_log", "_init_setup_model",
                     "policy_kwargs"}


def algo_class(algo: str):
    """The SB3 (or sb3-contrib) class of ``algo``."""
    if algo == "ppo":
        from stable_baselines3 import PPO
        return PPO
    if algo == "sac":
        from stable_baselines3 import SAC
        return SAC
    if algo == "tqc":
        try:
            from sb3_contrib import TQC
        except ImportError as err:  # pragma: no cover - sb3-contrib is in the train extra
            raise ConfigError("algo", "tqc needs sb3-contrib (pip install sb3-contrib)") from err
        return TQC
    raise ConfigError("algo", f"must be one of {list(ALGOS)}, got {algo!r}")


def require_ray(field: str):
    """The ``ray`` module, imported; without Ray installed a ConfigError naming ``field`` (the option
    that asked for Ray) and the extra that installs it."""
    try:
        import ray
    except ImportError as err:
        raise ConfigError(field, "needs Ray, which the cluster extra installs: pip install 'cloth_gym[cluster]'") from err
    return ray


def _algo_params(algo: str) -> set[str]:
    sig = inspect.signature(algo_class(algo).__init__)
    return {p for p in sig.parameters if p not in _NOT_CONFIGURABLE and p not in ("args", "kwargs")}


@dataclass(frozen=True)
class TrainConfig:
    """One resolved training configuration (all fields validated).

    algo: ``ppo``, ``sac`` or ``tqc``. env_id: a Gymnasium id.
    n_timesteps: environment steps to train for (all envs together).
    policy: SB3 policy name (``MlpPolicy`` for state observations, ``CnnPolicy`` for rgb).
    n_envs: parallel envs. normalize: wrap in ``VecNormalize`` (observations and rewards).
    env_kwargs: constructor arguments of the env. policy_kwargs: see the module docstring.
    algo_kwargs: constructor arguments of the SB3 algorithm.
    env_wrapper: ``((name, kwargs), ...)``, :mod:`cloth_gym.wrappers` classes applied to the
    training envs in this order (not to the evaluation env).
    callback: ``((name, kwargs), ...)``, :mod:`cloth_gym.agents.callbacks` classes given to ``learn`` in
    this order, before the evaluation and checkpoint callbacks.
    """

    algo: str
    env_id: str
    n_timesteps: int
    policy: str = "MlpPolicy"
    n_envs: int = 1
    normalize: bool = False
    env_kwargs: dict = field(default_factory=dict)
    policy_kwargs: dict = field(default_factory=dict)
    algo_kwargs: dict = field(default_factory=dict)
    env_wrapper: tuple = ()
    callback: tuple = ()

    def callbacks(self) -> list:
        """New instances of the config's :mod:`cloth_gym.agents.callbacks` (one set per training run: they
        keep state, such as the demonstrations' statistics)."""
        from . import callbacks as module

        return [getattr(module, name.rsplit(".", 1)[1])(**kwargs) for name, kwargs in self.callback]

    def wrapper_class(self):
        """A callable ``env -> wrapped env`` for SB3's ``make_vec_env`` (None without wrappers)."""
        if not self.env_wrapper:
            return None
        import cloth_gym.wrappers as module

        chain = [(getattr(module, name.rsplit(".", 1)[1]), dict(kwargs)) for name, kwargs in self.env_wrapper]

        def wrap(env):
            for cls, kwargs in chain:
                env = cls(env, **kwargs)
            return env

        return wrap

    def to_zoo_dict(self) -> dict:
        """The entry as it would appear in the zoo's YAML (for the run directory)."""
        d: dict[str, Any] = {"n_timesteps": self.n_timesteps, "policy": self.policy, "n_envs": self.n_envs,
                             "normalize": self.normalize}
        if self.env_kwargs:
            d["env_kwargs"] = dict(self.env_kwargs)
        if self.policy_kwargs:
            d["policy_kwargs"] = dict(self.policy_kwargs)
        if self.env_wrapper:
            d["env_wrapper"] = [{name: dict(kwargs)} for name, kwargs in self.env_wrapper]
        if self.callback:
            d["callback"] = [{name: dict(kwargs)} for name, kwargs in self.callback]
        d.update(self.algo_kwargs)
        return d

    def sb3_kwargs(self) -> dict:
        """Keyword arguments for the algorithm's constructor (schedules and activations resolved)."""
        kw = {k: _schedule(v) if k in ("learning_rate", "clip_range") else v for k, v in self.algo_kwargs.items()}
        if "replay_buffer_class" in kw:
            kw["replay_buffer_class"] = _replay_buffer(kw["replay_buffer_class"])
        if "train_freq" in kw and isinstance(kw["train_freq"], list):
            kw["train_freq"] = tuple(kw["train_freq"])
        pk = dict(self.policy_kwargs)
        if "features_extractor_class" in pk:
            pk["features_extractor_class"] = _features_class(pk["features_extractor_class"])
        if "activation_fn" in pk:
            import torch.nn as nn
            pk["activation_fn"] = getattr(nn, ACTIVATIONS[pk["activation_fn"]])
        if pk:
            kw["policy_kwargs"] = pk
        return kw


def _schedule(v):
    if isinstance(v, str) and v.startswith("lin_"):
        initial = float(v[4:])
        return lambda progress_remaining: progress_remaining * initial
    return v


def _check_number(key, v, lo, hi, integer=False):
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and -1e300 < v < 1e300 and math.isfinite(v) \
        and lo <= v <= hi
    if integer:
        ok = ok and float(v).is_integer()
    if not ok:
        kind = "an integer" if integer else "a number"
        raise ConfigError(f"train.{key}", f"must be {kind} in [{lo}, {hi}], got {v!r}")


def _validate(algo: str, env_id: str, entry: dict) -> TrainConfig:
    if not isinstance(entry, dict):
        raise ConfigError("train", f"the entry for {env_id!r} must be a mapping, got {type(entry).__name__}")
    for key, replacement in _FORMER_KEYS.items():
        if key in entry:
            raise ConfigError(f"train.{key}", f"is no longer a key: use the zoo's {replacement}")
    allowed = set(ZOO_KEYS) | _algo_params(algo)
    unknown = sorted((k for k in entry if k not in allowed), key=str)
    if unknown:
        raise ConfigError(f"train.{unknown[0]}", f"unknown key for {algo} (keys: {unknown}); allowed: "
                          f"{sorted(allowed)}")
    if "n_timesteps" not in entry:
        raise ConfigError("train.n_timesteps", "is required")
    _check_number("n_timesteps", entry["n_timesteps"], 1, 1e10, integer=True)
    n_envs = entry.get("n_envs", 1)
    _check_number("n_envs", n_envs, 1, 256, integer=True)
    normalize = entry.get("normalize", False)
    if not isinstance(normalize, bool):
        raise ConfigError("train.normalize", f"must be true or false (strings are not evaluated), got {normalize!r}")
    policy = entry.get("policy", "MlpPolicy")
    if not isinstance(policy, str) or policy not in ("MlpPolicy", "CnnPolicy", "MultiInputPolicy"):
        raise ConfigError("train.policy", f"must be MlpPolicy, CnnPolicy or MultiInputPolicy, got {policy!r}")
    env_kwargs = entry.get("env_kwargs") or {}
    if not isinstance(env_kwargs, dict):
        raise ConfigError("train.env_kwargs", f"must be a mapping, got {env_kwargs!r}")
    pk = entry.get("policy_kwargs") or {}
    if not isinstance(pk, dict):
        raise ConfigError("train.policy_kwargs", f"must be a mapping (strings are not evaluated), got {pk!r}")
    for k in pk:
        if k not in POLICY_KWARGS:
            raise ConfigError(f"train.policy_kwargs.{k}", f"unknown key; allowed: {list(POLICY_KWARGS)}")
    if "activation_fn" in pk and not (isinstance(pk["activation_fn"], str) and pk["activation_fn"] in ACTIVATIONS):
        raise ConfigError("train.policy_kwargs.activation_fn", f"must be one of {list(ACTIVATIONS)}, "
                          f"got {pk['activation_fn']!r}")
    _check_features_extractor(pk)
    wrappers = _named_classes("env_wrapper", "wrapper", entry.get("env_wrapper"), WRAPPER_MODULE)
    callbacks = _named_classes("callback", "callback", entry.get("callback"), CALLBACK_MODULE)
    _check_callbacks(algo, callbacks)
    algo_kwargs = {k: v for k, v in entry.items() if k not in ZOO_KEYS}
    for key in ("learning_rate", "clip_range"):
        v = algo_kwargs.get(key)
        if isinstance(v, str):
            try:
                ok = v.startswith("lin_") and 0 < float(v[4:]) <= 1
            except ValueError:
                ok = False
            if not ok:
                raise ConfigError(f"train.{key}", f"must be a number or 'lin_<initial>', got {v!r}")
        elif v is not None:
            _check_number(key, v, 0.0, 1.0)
    for key in ("gamma", "gae_lambda", "tau"):
        if key in algo_kwargs:
            _check_number(key, algo_kwargs[key], 0.0, 1.0)
    for key in ("n_steps", "batch_size", "n_epochs", "buffer_size", "learning_starts", "gradient_steps"):
        if key in algo_kwargs:
            low = {"gradient_steps": -1, "learning_starts": 0}.get(key, 1)
            _check_number(key, algo_kwargs[key], low, 1e9, integer=True)
    _check_replay_buffer(algo, algo_kwargs)
    _check_env_kwargs(env_id, env_kwargs)
    return TrainConfig(algo=algo, env_id=env_id, n_timesteps=int(entry["n_timesteps"]), policy=policy,
                       n_envs=int(n_envs), normalize=normalize, env_kwargs=dict(env_kwargs),
                       policy_kwargs=dict(pk), algo_kwargs=algo_kwargs, env_wrapper=wrappers,
                       callback=callbacks)


def _check_arguments(field: str, cls, kwargs: dict, supplied: tuple = ()) -> list[str]:
    """The arguments a config may give ``cls`` (its ``__init__``'s, less ``supplied``: those
    SB3 or the trainer pass); an unknown key is a ConfigError naming ``<field>.<key>``."""
    params = [p for p in inspect.signature(cls.__init__).parameters if p != "self" and p not in supplied]
    extra = sorted(set(kwargs) - set(params))
    if extra:
        raise ConfigError(f"{field}.{extra[0]}", f"unknown argument of {cls.__name__}; allowed: {params}")
    return params


def _check_features_extractor(pk: dict) -> None:
    """``features_extractor_class`` names a class of :mod:`cloth_gym.agents.features`, and
    ``features_extractor_kwargs`` its arguments; ``share_features_extractor`` is a bool."""
    if "share_features_extractor" in pk and not isinstance(pk["share_features_extractor"], bool):
        raise ConfigError("train.policy_kwargs.share_features_extractor",
                          f"must be true or false, got {pk['share_features_extractor']!r}")
    kwargs = pk.get("features_extractor_kwargs")
    if "features_extractor_class" not in pk:
        if kwargs is not None:
            raise ConfigError("train.policy_kwargs.features_extractor_kwargs", "needs a features_extractor_class")
        return
    (name, kw), = _named_classes("policy_kwargs.features_extractor_class", "features extractor",
                                 {pk["features_extractor_class"]: kwargs or {}}, FEATURES_MODULE)
    _check_arguments("train.policy_kwargs.features_extractor_kwargs", _features_class(name), kw,
                     ("observation_space",))


def _features_class(name: str):
    import importlib

    return getattr(importlib.import_module(FEATURES_MODULE), name.rsplit(".", 1)[1])


def _check_replay_buffer(algo: str, algo_kwargs: dict) -> None:
    """``replay_buffer_class`` is a name of :data:`REPLAY_BUFFERS` (off-policy algorithms only), and
    ``replay_buffer_kwargs`` a mapping of that class's arguments."""
    name = algo_kwargs.get("replay_buffer_class")
    kwargs = algo_kwargs.get("replay_buffer_kwargs")
    if name is None:
        if kwargs is not None:
            raise ConfigError("train.replay_buffer_kwargs", "needs a replay_buffer_class")
        return
    if algo not in OFF_POLICY:
        raise ConfigError("train.replay_buffer_class", f"only for the off-policy algorithms {list(OFF_POLICY)}")
    if not isinstance(name, str) or name not in REPLAY_BUFFERS:
        raise ConfigError("train.replay_buffer_class", f"must be one of {list(REPLAY_BUFFERS)} (a name, not "
                          f"evaluated), got {name!r}")
    if kwargs is None:
        return
    if not isinstance(kwargs, dict):
        raise ConfigError("train.replay_buffer_kwargs", f"must be a mapping (strings are not evaluated), got {kwargs!r}")
    _check_arguments("train.replay_buffer_kwargs", _replay_buffer(name), kwargs,
                     ("buffer_size", "observation_space", "action_space", "env", "device", "n_envs"))


def _replay_buffer(name: str):
    import stable_baselines3

    return getattr(stable_baselines3, name)


def _check_env_kwargs(env_id: str, env_kwargs: dict) -> None:
    """``env_kwargs`` names only keyword arguments of ``env_id``'s env (their values are the env's to
    check, when it is made)."""
    import gymnasium
    import inspect as _inspect

    import cloth_gym  # noqa: F401  (registers the ids)

    spec = gymnasium.registry.get(env_id)
    if spec is None or not isinstance(spec.entry_point, str):
        return  # not a cloth_gym id: the env checks its own kwargs
    module, _, name = spec.entry_point.partition(":")
    import importlib

    env_class = getattr(importlib.import_module(module), name)
    valid = []
    for cls in env_class.__mro__:  # an __init__(**kwargs) passes them on to its base's
        if "__init__" not in vars(cls):
            continue
        params = _inspect.signature(cls.__init__).parameters.values()
        valid += [p.name for p in params if p.name not in ("self", "unknown") and p.name not in valid
                  and p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)]
        if not any(p.kind == p.VAR_KEYWORD for p in params):
            break
    unknown = sorted((k for k in env_kwargs if k not in valid), key=str)
    if unknown:
        raise ConfigError(f"train.env_kwargs.{unknown[0]}", f"unknown keyword argument of {name}; valid: {valid}")


def _named_classes(key: str, noun: str, spec, module_name: str) -> tuple:
    """The zoo's ``env_wrapper`` or ``callback`` value (a name, a ``{name: kwargs}`` mapping, or a
    list of them) as ``((name, kwargs), ...)``; names must be classes of ``module_name``'s
    ``__all__`` (looked up by name, never imported from an arbitrary path)."""
    if spec is None:
        return ()
    import importlib

    module = importlib.import_module(module_name)
    out = []
    for item in spec if isinstance(spec, list) else [spec]:
        if isinstance(item, str):
            name, kwargs = item, {}
        elif isinstance(item, dict) and len(item) == 1:
            (name, kwargs), = item.items()
            kwargs = {} if kwargs is None else kwargs
        else:
            raise ConfigError(f"train.{key}", f"each {noun} must be a name or a one-key mapping "
                              f"{{name: kwargs}}, got {item!r}")
        allowed = [f"{module_name}.{c}" for c in module.__all__]
        if module_name == CALLBACK_MODULE and isinstance(name, str) and name.startswith(LEGACY_CALLBACK_MODULE + "."):
            name = CALLBACK_MODULE + name[len(LEGACY_CALLBACK_MODULE):]
        if name not in allowed:
            raise ConfigError(f"train.{key}", f"unknown {noun} {name!r}; allowed: {allowed}")
        if not isinstance(kwargs, dict):
            raise ConfigError(f"train.{key}.{name}", f"kwargs must be a mapping, got {kwargs!r}")
        out.append((name, dict(kwargs)))
    return tuple(out)


def _check_callbacks(algo: str, callbacks: tuple) -> None:
    """Each callback is made once with its kwargs (its own range checks, now rather than when
    training starts); an unknown or missing argument names the callback's signature."""
    from . import callbacks as module

    for name, kwargs in callbacks:
        cls = getattr(module, name.rsplit(".", 1)[1])
        if getattr(cls, "off_policy_only", False) and algo not in OFF_POLICY:
            raise ConfigError(f"train.callback.{name}", f"only for the off-policy algorithms {list(OFF_POLICY)}, "
                              f"not {algo}")
        params = _check_arguments(f"train.callback.{name}", cls, kwargs, ("verbose",))
        try:
            cls(**kwargs)
        except ConfigError as err:
            raise ConfigError(f"train.callback.{err.field}", err.message) from None
        except TypeError as err:  # a required argument is missing
            raise ConfigError(f"train.callback.{name}", f"{err}; arguments: {params}") from None


def parse_overrides(items: list[str] | None) -> dict:
    """``["key=value", ...]`` with YAML values (``n_envs=4``, ``learning_rate=lin_1e-3``,
    ``env_kwargs={sigma: 2.0}``); never evaluated as Python."""
    out = {}
    for item in items or []:
        if not isinstance(item, str):
            raise ConfigTypeError("override", f"expected a 'key=value' string, got {item!r}")
        if "=" not in item:
            raise ConfigError("override", f"expected key=value, got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = yaml.safe_load(v)
        except RecursionError:
            raise ConfigError(f"override.{k.strip()}", "the value is nested too deeply") from None
        except yaml.YAMLError as err:
            raise ConfigError(f"override.{k.strip()}", f"{v!r} is not a YAML value: "
                              f"{getattr(err, 'problem', None) or err}") from None
    return out


def load_train_config(algo: str, env_id: str, path: str | Path | None = None,
                      overrides: dict | None = None) -> TrainConfig:
    """The configuration of ``algo`` on ``env_id`` from ``path`` (default
    ``configs/train/<algo>.yaml``): the env's entry, or ``default``, then ``overrides``."""
    if not isinstance(algo, str):
        raise ConfigTypeError("algo", f"must be one of {list(ALGOS)}, got {algo!r}")
    algo_class(algo)  # validates the name
    if not isinstance(env_id, str):
        raise ConfigTypeError("env", f"must be an env id string, got {env_id!r}")
    path = Path(path) if path is not None else CONFIG_DIR / f"{algo}.yaml"
    if not is_file(path):
        raise ConfigError("conf", f"no such config file: {path}")
    data = read_yaml(path, "conf") or {}
    if not isinstance(data, dict):
        raise ConfigTypeError("conf", f"{path} must map env ids to hyperparameters, got {type(data).__name__}")
    key = env_id if env_id in data else "default"
    if key not in data:
        raise ConfigError("env", f"{path} has no entry for {env_id!r} and no 'default'")
    if not isinstance(data[key], dict):
        raise ConfigTypeError("train", f"the entry {key!r} of {path} must be a mapping of hyperparameters, "
                              f"got {data[key]!r}")
    entry = dict(data[key])
    if overrides is not None and not isinstance(overrides, dict):
        raise ConfigTypeError("override", f"must be a mapping of key to value, got {overrides!r}")
    entry.update(overrides or {})
    return _validate(algo, env_id, entry)


#: the mappings whose single entries a dotted override key may set (``policy_kwargs.net_arch``)
NESTED_KEYS = ("env_kwargs", "policy_kwargs")


def with_overrides(cfg: TrainConfig, overrides: dict) -> TrainConfig:
    """``cfg`` with ``overrides`` applied and validated again. A key is a config key
    (``learning_rate``: the value replaces it) or ``env_kwargs.<name>`` /
    ``policy_kwargs.<name>`` (sets one entry and keeps the others)."""
    if not isinstance(overrides, dict):
        raise ConfigTypeError("override", f"must be a mapping of key to value, got {overrides!r}")
    entry = cfg.to_zoo_dict()
    for key, value in overrides.items():
        if not isinstance(key, str):
            raise ConfigTypeError("override", f"keys must be strings, got {key!r}")
        head, dot, name = key.partition(".")
        if not dot:
            entry[key] = value
        elif head in NESTED_KEYS and name and "." not in name:
            entry[head] = {**entry.get(head, {}), name: value}
        else:
            raise ConfigError(f"override.{key}", f"a dotted key must be one of {[k + '.<name>' for k in NESTED_KEYS]}")
    return _validate(cfg.algo, cfg.env_id, entry)


def replace(cfg: TrainConfig, **changes) -> TrainConfig:
    return dataclasses.replace(cfg, **changes)
