"""The published trained policies, found and loaded by env id.

Each published policy is a run directory of ``scripts/train.py`` under ``models/`` in a checkout
(shipped in the distribution as the package data ``cloth_gym.models``), listed with its env id,
algorithm, config, training seed and evaluation in ``MANIFEST.json``::

    from cloth_gym.agents.published import load_published
    model, env_kwargs = load_published("cloth_gym/CornerLift-v2")  # a Stable-Baselines3 SAC model
    env = gym.make("cloth_gym/CornerLift-v2", **env_kwargs)      # the options it was trained with
    obs, info = env.reset(seed=1)
    action, _ = model.predict(obs, deterministic=True)

Loading needs Stable-Baselines3 (``pip install 'cloth_gym[train]'``).
"""

from __future__ import annotations

import json
from pathlib import Path

from cloth_gym.errors import ConfigError

__all__ = ["load_published", "models_dir", "published", "published_path"]


def models_dir() -> Path:
    """The folder of the published policies: ``models/`` of a checkout, or the installed package
    data ``cloth_gym.models``."""
    from importlib.resources import files

    return Path(str(files("cloth_gym.models")))


def published() -> list[dict]:
    """Every published policy's ``MANIFEST.json`` entry (``path``, ``env_id``, ``algorithm``,
    ``config``, ``training_seed``, ``command``, ``evaluation``, ...), in the manifest's order."""
    return json.loads((models_dir() / "MANIFEST.json").read_text())["policies"]


def _entry(env_id: str) -> dict:
    """The manifest's last entry published for ``env_id``: trained on it, or listing it under
    ``also_for`` (a later version of its task, with the policy's evaluation there).

    Raises :class:`~cloth_gym.errors.ConfigError` naming ``env_id`` and the ids that have one."""
    entries = published()
    ids = [{p["env_id"], *p.get("also_for", {})} for p in entries]
    for entry, served in zip(reversed(entries), reversed(ids)):
        if env_id in served:
            return entry
    raise ConfigError("env_id", f"no published policy for {env_id!r}; published: {sorted(set().union(*ids))}")


def published_path(env_id: str) -> Path:
    """The run directory of the policy published for ``env_id`` (the manifest's last entry for it).

    Raises :class:`~cloth_gym.errors.ConfigError` naming ``env_id`` and the ids that have one."""
    return models_dir() / Path(_entry(env_id)["path"]).name


def load_published(env_id: str):
    """``(model, env_kwargs)``: the Stable-Baselines3 model published for ``env_id``, ready to
    ``predict`` on the CPU (its replay buffer is not loaded), and the env keyword arguments it was
    trained with, to make its env: ``gym.make(env_id, **env_kwargs)``. A policy trained on an
    earlier version serves a later one where the manifest says so (``also_for``)."""
    from .training import load_run

    entry = _entry(env_id)
    model, _, trained_on, env_kwargs, norm = load_run(models_dir() / Path(entry["path"]).name)
    if trained_on != entry["env_id"] or norm is not None:  # the manifest and the run directory disagree
        raise ConfigError("env_id", f"the policy published for {env_id!r} was trained on {trained_on!r}"
                          + (" with observation normalisation" if norm is not None else ""))
    return model, dict(env_kwargs)
