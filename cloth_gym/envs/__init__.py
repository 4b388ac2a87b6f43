"""Gymnasium environments (registered when :mod:`cloth_gym` is imported).

| id | entry point | max_episode_steps |
|---|---|---|
| ``cloth_gym/CornerLift-v0`` | :class:`~cloth_gym.envs.corner_lift.CornerLiftEnv` | 100 |
| ``cloth_gym/DrapeOntoTable-v0`` | :class:`~cloth_gym.envs.drape_onto_table.DrapeOntoTableEnv` | 150 |
| ``cloth_gym/RibbonDrop-v0`` | :class:`~cloth_gym.envs.ribbon_drop.RibbonDropEnv` | 200 |
| ``cloth_gym/CornerLift-v1``, ``-v2`` | :class:`~cloth_gym.envs.corner_lift.CornerLiftEnv` | 100 |
| ``cloth_gym/CornerLiftGoal-v1``, ``-v2`` | :class:`~cloth_gym.envs.corner_lift.CornerLiftGoalEnv` | 100 |
| ``cloth_gym/DrapeOntoTable-v1``, ``-v2`` | :class:`~cloth_gym.envs.drape_onto_table.DrapeOntoTableEnv` | 150 |
| ``cloth_gym/RibbonDrop-v1``, ``-v2``, ``-v3`` | :class:`~cloth_gym.envs.ribbon_drop.RibbonDropEnv` | 200 |

A version is its task's class with other keyword arguments, as Gymnasium's FrozenLake8x8-v1 is
FrozenLake-v1 with another map: each row of :data:`ENV_SPECS` lists what its id sets
(``gymnasium.spec(id).kwargs``); a user's own keyword arguments override them.
:data:`V1` is what every v1 id changes over v0: the real fabric resolution (σ = 1 cm), the
simulator's own lattice conventions (each particle's mass and each element's width from the
fabric area it stands for; the material's damping acting on deformation rates only), float32
observations, orange target markers, no re-grasp of a particle that slipped from a closed
gripper until it opens, observation Boxes that bound the gripper entries, and substeps short
enough that no free particle moves more than half a lattice spacing in one (``max_travel``).

:data:`CURRENT_IDS` names each task's current version (what the README, the docs and ``make demo``
use); the older ids stay registered, unchanged, for the results measured on them. Gymnasium warns
("out of date, consider upgrading") when an older id is made.

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


#: the keyword arguments every v1 id sets (``sim_defaults``: ImplicitEuler's defaults, under its names)
V1 = {"sigma": 1.0, "mass_lumping": "area", "damping_model": "strain-rate", "observation_dtype": "float32",
      "target_rgb": (250, 150, 20), "regrasp_slipped": False, "bounded_observations": True,
      "sim_defaults": {"max_travel": 0.5}}
#: CornerLift-v1: V1 with 5 ms substeps and the band preconditioner; v2: the same with 10 ms substeps
CORNER_LIFT_V1 = {**V1, "sim_defaults": {"max_dt": 5e-3, "preconditioner": "band", "max_travel": 0.5}}
CORNER_LIFT_V2 = {**V1, "sim_defaults": {"max_dt": 1e-2, "preconditioner": "band", "max_travel": 0.5}}
#: RibbonDrop-v1: V1 with 5 ms substeps and no strain limiter
RIBBON_DROP_V1 = {**V1, "sim_defaults": {"max_dt": 5e-3, "strain_limit_percent": None, "max_travel": 0.5}}
#: RibbonDrop-v2: v1 tilted 0.5° out of its plane at the start, BDF2 with converged Newton passes
RIBBON_DROP_V2 = {**RIBBON_DROP_V1, "start_tilt_deg": 0.5,
                  "sim_defaults": {**RIBBON_DROP_V1["sim_defaults"], "scheme": "bdf2", "newton_iters": 10,
                                   "newton_tol": 0.1, "momentum_exact": True}}
#: RibbonDrop-v3: v2 with the collision response coupled to the implicit solve
RIBBON_DROP_V3 = {**RIBBON_DROP_V2, "sim_defaults": {**RIBBON_DROP_V2["sim_defaults"], "couple_collisions": True}}
#: RibbonDrop-v4: v3 with a control step whose strain jumps by 0.3 percentage points run again in 4× the substeps
RIBBON_DROP_V4 = {**RIBBON_DROP_V3, "sim_defaults": {**RIBBON_DROP_V3["sim_defaults"], "refine_strain_rise": 0.3}}
#: DrapeOntoTable-v2: v1 with a control step that diverges run again with Newton converged
DRAPE_ONTO_TABLE_V2 = {**V1, "sim_defaults": {**V1["sim_defaults"], "retry_diverged": True}}

_CORNER, _GOAL = "cloth_gym.envs.corner_lift:CornerLiftEnv", "cloth_gym.envs.corner_lift:CornerLiftGoalEnv"
_DRAPE, _RIBBON = "cloth_gym.envs.drape_onto_table:DrapeOntoTableEnv", "cloth_gym.envs.ribbon_drop:RibbonDropEnv"

ENV_SPECS = {
    "cloth_gym/DrapeOntoTable-v0": EnvRow(_DRAPE, 150, {}),
    "cloth_gym/RibbonDrop-v0": EnvRow(_RIBBON, 200, {}),
    "cloth_gym/CornerLift-v0": EnvRow(_CORNER, 100, {}),
    "cloth_gym/CornerLift-v1": EnvRow(_CORNER, 100, CORNER_LIFT_V1),
    "cloth_gym/CornerLiftGoal-v1": EnvRow(_GOAL, 100, CORNER_LIFT_V1),
    "cloth_gym/CornerLift-v2": EnvRow(_CORNER, 100, CORNER_LIFT_V2),
    "cloth_gym/CornerLiftGoal-v2": EnvRow(_GOAL, 100, CORNER_LIFT_V2),
    "cloth_gym/DrapeOntoTable-v1": EnvRow(_DRAPE, 150, V1),
    "cloth_gym/DrapeOntoTable-v2": EnvRow(_DRAPE, 150, DRAPE_ONTO_TABLE_V2),
    "cloth_gym/RibbonDrop-v1": EnvRow(_RIBBON, 200, RIBBON_DROP_V1),
    "cloth_gym/RibbonDrop-v2": EnvRow(_RIBBON, 200, RIBBON_DROP_V2),
    "cloth_gym/RibbonDrop-v3": EnvRow(_RIBBON, 200, RIBBON_DROP_V3),
    "cloth_gym/RibbonDrop-v4": EnvRow(_RIBBON, 200, RIBBON_DROP_V4),
}

#: each task's current version (CornerLift's goal-conditioned twin included)
CURRENT_IDS = ("cloth_gym/CornerLift-v2", "cloth_gym/CornerLiftGoal-v2", "cloth_gym/DrapeOntoTable-v2",
               "cloth_gym/RibbonDrop-v4")

__all__ = ["CURRENT_IDS", "ENV_SPECS", "EnvRow", "V1", "CORNER_LIFT_V1", "CORNER_LIFT_V2", "DRAPE_ONTO_TABLE_V2",
           "RIBBON_DROP_V1", "RIBBON_DROP_V2", "RIBBON_DROP_V3", "RIBBON_DROP_V4", "register_envs"]


def register_envs() -> None:
    """Register the cloth_gym ids with Gymnasium (idempotent)."""
    import gymnasium

    from .vector import batched_entry_point

    for env_id, row in ENV_SPECS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=row.entry_point, max_episode_steps=row.max_episode_steps,
                               kwargs=row.kwargs, vector_entry_point=batched_entry_point(env_id))


register_envs()
