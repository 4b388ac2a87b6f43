"""A non-finite or overflowing velocity reaching the implicit integrator with ``max_travel`` on (the
v1 envs) is a SimulationDiverged naming the step, the time and the particle, not an OverflowError or
ValueError from the substep count; an env reports it as a diverged (truncated) step."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import cloth_gym  # noqa: F401
from cloth_gym import SimulationDiverged
from cloth_gym.sim.implicit import ImplicitEuler
from cloth_gym.sim.lattice import Rectangle, build_cloth


@pytest.mark.parametrize("value, reason", [(np.nan, "non-finite"), (np.inf, "non-finite"), (1e200, "speed")])
def test_travel_substeps_of_a_bad_velocity_diverge_naming_the_particle(value, reason):
    model = build_cloth(Rectangle(4.0, 4.0), material="thick_cotton", sigma=1.0)
    state = model.state()
    state.particle_qd[7, 1] = value
    state.time, state.step = 0.25, 50
    with pytest.raises(SimulationDiverged) as info:
        ImplicitEuler(max_travel=0.5).step(model, state, None, 0.01)
    err = info.value
    assert (err.particle, err.reason, err.step, err.time_s) == (7, reason, 50, 0.25)


def test_an_env_with_max_travel_reports_it_as_divergence():
    env = gym.make("cloth_gym/CornerLift-v1").unwrapped
    assert env.sim.get("max_travel") is not None
    env.reset(seed=0)
    env.physics.state.particle_qd[3] = np.inf
    _, reward, terminated, truncated, info = env.step(np.zeros(4))
    assert truncated and not terminated and info["diverged"] and "particle 3" in info["divergence"]
