"""Messages at the boundary say what the user can still change: a drape run refuses an output folder
it cannot write before simulating, and a divergence names the settings of the integrator in use."""

from __future__ import annotations

import math
import pickle
import time

import pytest

from cloth_gym.errors import ConfigError, SimulationDiverged
from cloth_gym.sim import Rectangle, SymplecticEuler, build_cloth
from cloth_gym.sim.implicit import ImplicitEuler


def test_drape_refuses_an_unwritable_output_folder_before_simulating(tmp_path):
    from cloth_gym.reports.drape import main

    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    t0 = time.process_time()
    with pytest.raises(ConfigError, match="out"):
        main(["--material", "thin_wool", "--sigma", "2.54", "--max-time", "0.5", "--out", str(blocker / "sub"), "--quiet"])
    assert time.process_time() - t0 < 2.0  # refused at once: no kernel compiled, nothing simulated


@pytest.mark.parametrize("integrator, advice", [(ImplicitEuler(max_dt=1e-2), "max_travel"),
                                                (SymplecticEuler(on_unstable="substep"), "ImplicitEuler")])
def test_a_divergence_advises_what_the_integrator_in_use_can_change(integrator, advice):
    """The implicit integrator is not told to use the implicit integrator; the hint survives pickling
    (vector-env workers send it across processes)."""
    m = build_cloth(Rectangle(2.0, 2.0), sigma=1.0)
    s = m.state()
    s.particle_q[3, 1] = math.nan
    with pytest.raises(SimulationDiverged) as info:
        integrator.step(m, s, None, 1e-2)
    assert advice in str(info.value) and "use the implicit integrator" not in str(info.value).replace(
        "use the implicit integrator (ImplicitEuler)", "")
    again = pickle.loads(pickle.dumps(info.value))
    assert str(again) == str(info.value) and again.hint == info.value.hint
