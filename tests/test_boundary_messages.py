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


@pytest.mark.parametrize("integrator, advice", [(ImplicitEuler(max_dt=1e-2, retry_diverged=False), "max_travel"),
                                                (SymplecticEuler(on_unstable="substep"), "ImplicitEuler")])
def test_a_divergence_advises_what_the_integrator_in_use_can_change(integrator, advice):
    """The implicit integrator is not told to use the implicit integrator; the hint survives pickling
    (vector-env workers send it across processes)."""
    m = build_cloth(Rectangle(2.0, 2.0), sigma=1.0)
    s = m.state()
    s.particle_qd[3] = (9e4, 0.0, 0.0)  # below the speed guard (1e5 cm/s): the step itself tears the cloth
    with pytest.raises(SimulationDiverged) as info:
        integrator.step(m, s, None, 1e-2)
    assert info.value.reason in ("speed", "strain") and advice in str(info.value) and "use the implicit integrator" not in str(info.value).replace(
        "use the implicit integrator (ImplicitEuler)", "")
    again = pickle.loads(pickle.dumps(info.value))
    assert str(again) == str(info.value) and again.hint == info.value.hint


@pytest.mark.parametrize("field, value", [("particle_q", math.nan), ("particle_qd", math.nan),
                                          ("particle_qd", math.inf), ("particle_qd", 1e300)])
@pytest.mark.parametrize("make", [
    lambda: ImplicitEuler(max_dt=1e-2),
    lambda: ImplicitEuler(max_dt=1e-2, max_travel=0.5),
    lambda: ImplicitEuler(max_dt=1e-2, sleep_speed=1e-3, slow_dt=0.05),
    lambda: ImplicitEuler(max_dt=1e-2, newton_iters=4, newton_tol=0.1, scheme="bdf2"),
    lambda: SymplecticEuler(on_unstable="substep"),
], ids=["implicit", "travel", "sleep-slow", "bdf2-newton", "explicit"])
@pytest.mark.parametrize("table", [False, True], ids=["free", "on-a-table"])
def test_non_finite_input_on_every_integrator_path_is_a_simulation_diverged(make, field, value, table):
    """Every integrator path, free or on a table, with a NaN position or a NaN, infinite or overflowing
    velocity: a SimulationDiverged (and no other error), by step and advance; a NaN or infinite
    input names its particle before anything is computed."""
    from cloth_gym.sim.obstacles import Plane

    m = build_cloth(Rectangle(2.0, 2.0), sigma=1.0, origin=(0, 0, 0.1 if table else 5.0),
                    obstacles=[Plane()] if table else ())
    for call in ("step", "advance"):
        s = m.state()
        getattr(s, field)[4, 2] = value
        with pytest.raises(SimulationDiverged) as info:
            if call == "step":
                make().step(m, s, None, 1e-2)
            else:
                make().advance(m, s, None, 2e-2, 1e-2)
        if not math.isfinite(value):
            assert info.value.particle == 4 and info.value.reason == "non-finite"
