"""Gymnasium environments (registered when :mod:`cloth_gym` is imported).

| id | entry point | max_episode_steps |
|---|---|---|
| ``cloth_gym/CornerLift-v0`` | :class:`~cloth_gym.envs.corner_lift.CornerLiftEnv` | 100 |
| ``cloth_gym/DrapeOntoTable-v0`` | :class:`~cloth_gym.envs.drape_onto_table.DrapeOntoTableEnv` | 150 |
| ``cloth_gym/RibbonDrop-v0`` | :class:`~cloth_gym.envs.ribbon_drop.RibbonDropEnv` | 200 |
| ``cloth_gym/CornerLift-v1`` | :class:`~cloth_gym.envs.corner_lift.CornerLiftV1Env` | 100 |
| ``cloth_gym/CornerLiftGoal-v1`` | :class:`~cloth_gym.envs.corner_lift.CornerLiftGoalEnv` | 100 |
| ``cloth_gym/CornerLift-v2`` | :class:`~cloth_gym.envs.corner_lift.CornerLiftV2Env` | 100 |
| ``cloth_gym/CornerLiftGoal-v2`` | :class:`~cloth_gym.envs.corner_lift.CornerLiftGoalV2Env` | 100 |
| ``cloth_gym/DrapeOntoTable-v1`` | :class:`~cloth_gym.envs.drape_onto_table.DrapeOntoTableV1Env` | 150 |
| ``cloth_gym/RibbonDrop-v1`` | :class:`~cloth_gym.envs.ribbon_drop.RibbonDropV1Env` | 200 |

Entry points are lazy strings: registering imports neither the simulator nor
numba; ``gymnasium.make`` does. A process that has not imported cloth_gym (a
vector-env worker given only an id) can use the ``"module:id"`` form,
``gymnasium.make("cloth_gym:cloth_gym/CornerLift-v0")``, which imports it first.
"""

from __future__ import annotations

from typing import NamedTuple

class EnvRow(NamedTuple):
    """One registered id: its entry point, ``max_episode_steps`` and the keyword arguments the id
    fixes (a version's defaults, visible in ``gymnasium.spec(id).kwargs``; a user's own override them)."""

    entry_point: str
    max_episode_steps: int
    kwargs: dict


ENV_SPECS = {
    "cloth_gym/DrapeOntoTable-v0": EnvRow("cloth_gym.envs.drape_onto_table:DrapeOntoTableEnv", 150, {}),
    "cloth_gym/RibbonDrop-v0": EnvRow("cloth_gym.envs.ribbon_drop:RibbonDropEnv", 200, {}),
    "cloth_gym/CornerLift-v0": EnvRow("cloth_gym.envs.corner_lift:CornerLiftEnv", 100, {}),
    "cloth_gym/CornerLift-v1": EnvRow("cloth_gym.envs.corner_lift:CornerLiftV1Env", 100, {}),
    "cloth_gym/CornerLiftGoal-v1": EnvRow("cloth_gym.envs.corner_lift:CornerLiftGoalEnv", 100, {}),
    "cloth_gym/CornerLift-v2": EnvRow("cloth_gym.envs.corner_lift:CornerLiftV2Env", 100, {}),
    "cloth_gym/CornerLiftGoal-v2": EnvRow("cloth_gym.envs.corner_lift:CornerLiftGoalV2Env", 100, {}),
    "cloth_gym/DrapeOntoTable-v1": EnvRow("cloth_gym.envs.drape_onto_table:DrapeOntoTableV1Env", 150, {}),
    "cloth_gym/RibbonDrop-v1": EnvRow("cloth_gym.envs.ribbon_drop:RibbonDropV1Env", 200, {}),
}

__all__ = ["ENV_SPECS", "EnvRow", "register_envs"]


def register_envs() -> None:
    """Register the cloth_gym ids with Gymnasium (idempotent)."""
    import gymnasium

    from .vector import batched_entry_point

    for env_id, row in ENV_SPECS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=row.entry_point, max_episode_steps=row.max_episode_steps,
                               kwargs=row.kwargs, vector_entry_point=batched_entry_point(env_id))


register_envs()
