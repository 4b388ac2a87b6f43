"""The integrators keep their memory between calls in the state: a copy continues exactly.

BDF2's history, the contact record and the sleep record live in ``State.solver``; a copied state
advanced by a fresh integrator object must reproduce the original bit for bit. Each case is one
that differs without that memory: BDF2 restarts with a backward-Euler step, a cloth resting on a
table loses its contact record, a sleeping cloth wakes and is solved again.
"""

import copy
import pickle

import numpy as np
import pytest

from cloth_gym.sim import Rectangle, build_cloth
from cloth_gym.sim.implicit import ImplicitEuler
from cloth_gym.sim.obstacles import Box


def _hanging_cloth():
    m = build_cloth(Rectangle(8.0, 8.0), "thick_cotton", sigma=1.0)
    return m.with_pinned([m.index(0, -1), m.index(-1, -1)])


def _cloth_over_table():
    return build_cloth(Rectangle(20.0, 20.0), "thick_cotton", sigma=2.0, origin=(0, 0, 3.0),
                       obstacles=[Box((0, 0, -10.0), (12.0, 12.0, 10.0))], contact_thickness=0.1)


def _continue(model, state, make, calls, dt):
    s = state
    integ = make()
    for _ in range(calls):
        integ.step(model, s, None, dt)
    return s, integ


@pytest.mark.parametrize("scheme", ["euler", "bdf2"])
def test_a_copied_state_continues_bit_identically_under_a_fresh_integrator(scheme):
    m = _hanging_cloth()
    make = lambda: ImplicitEuler(max_dt=2e-3, scheme=scheme)  # noqa: E731
    s, _ = _continue(m, m.state(), make, 5, 0.01)
    twin = s.copy()
    a, _ = _continue(m, s, make, 5, 0.01)
    b, _ = _continue(m, twin, make, 5, 0.01)
    assert np.array_equal(a.particle_q, b.particle_q) and np.array_equal(a.particle_qd, b.particle_qd)
    if scheme == "bdf2":
        # the history is what makes the difference: without it the copy restarts with backward Euler
        bare = s.copy()
        bare.solver.clear()
        c, _ = _continue(m, bare, make, 5, 0.01)
        assert not np.array_equal(a.particle_q, c.particle_q)


def test_bdf2_history_is_used_only_at_the_step_and_dt_it_was_written_for():
    m = _hanging_cloth()
    s, _ = _continue(m, m.state(), lambda: ImplicitEuler(max_dt=2e-3, scheme="bdf2"), 3, 0.01)
    mem = s.solver
    assert mem.bdf2_x is not None and mem.bdf2_step == s.step and mem.bdf2_h == pytest.approx(2e-3)
    # another substep length: the history does not fit, BDF2 restarts (and records the new h)
    _continue(m, s, lambda: ImplicitEuler(max_dt=1e-3, scheme="bdf2"), 1, 0.01)
    assert s.solver.bdf2_h == pytest.approx(1e-3)
    # backward Euler leaves no BDF2 history behind
    _continue(m, s, lambda: ImplicitEuler(max_dt=1e-3), 1, 0.01)
    assert s.solver.bdf2_x is None


def test_a_copied_state_resting_on_a_table_continues_bit_identically():
    m = _cloth_over_table()
    make = lambda: ImplicitEuler(max_dt=5e-3)  # noqa: E731
    s, _ = _continue(m, m.state(), make, 30, 0.02)  # dropped 3 cm: lands, the rim drapes over the edge
    assert (s.solver.contacts >= 0).sum() > 10
    twin = pickle.loads(pickle.dumps(s))
    a, _ = _continue(m, s, make, 10, 0.02)
    b, _ = _continue(m, twin, make, 10, 0.02)
    assert np.array_equal(a.particle_q, b.particle_q) and np.array_equal(a.particle_qd, b.particle_qd)


def test_a_sleeping_cloth_copied_stays_asleep_under_a_fresh_integrator():
    m = _cloth_over_table()
    make = lambda: ImplicitEuler(max_dt=0.01, vtol=1e-4, sleep_speed=1e-3)  # noqa: E731
    s, integ = _continue(m, m.state(), make, 80, 0.05)
    assert integ.asleep and s.solver.asleep
    twin = copy.deepcopy(s)
    a, ia = _continue(m, s, make, 3, 0.05)
    b, ib = _continue(m, twin, make, 3, 0.05)
    assert ia.asleep and ib.asleep
    assert np.array_equal(a.particle_q, b.particle_q) and a.step == b.step and a.time == b.time
    # an outside edit of the positions wakes it: the record no longer matches the state
    b.particle_q[0, 2] += 1e-3
    ImplicitEuler(max_dt=0.01, vtol=1e-4, sleep_speed=1e-3).step(m, b, None, 0.05)
    assert not b.solver.asleep


def test_state_copy_owns_its_memory():
    m = _hanging_cloth()
    s, _ = _continue(m, m.state(), lambda: ImplicitEuler(max_dt=2e-3, scheme="bdf2"), 2, 0.01)
    twin = s.copy()
    twin.solver.bdf2_x[:] = 0.0
    assert np.any(s.solver.bdf2_x != 0.0)


def test_warm_start_needs_fewer_iterations_and_lands_where_a_cold_start_does():
    """Each step's solve starts from the previous step's Δv (kept in State.solver across calls):
    a falling cloth's Δv barely changes from step to step, so the warm solves need fewer CG
    iterations, and end within the solver tolerance of the cold-started run."""
    m = build_cloth(Rectangle(10.0, 10.0), "thick_cotton", sigma=1.0, origin=(0, 0, 5.0),
                    obstacles=[Box((0, 0, -10.0), (6.0, 6.0, 10.0))])
    runs = {}
    for warm in (False, True):
        s = m.state()
        its = []
        for _ in range(20):  # falls 5 cm onto the box (0.1 s), then drapes over its edges
            integ = ImplicitEuler(max_dt=2e-3, tol=1e-6, warm_start=warm)  # fresh each call: memory in the state
            integ.step(m, s, None, 0.01)
            its.append(integ.last_stats[:, 0].sum())
        runs[warm] = (s.particle_q.copy(), np.array(its))
    (q_cold, its_cold), (q_warm, its_warm) = runs[False], runs[True]
    assert its_warm[:5].sum() < 0.6 * its_cold[:5].sum()  # free fall
    assert its_warm.sum() < its_cold.sum()
    assert np.abs(q_warm - q_cold).max() < 1e-3  # cm
    assert s.solver.warm_dv is not None and s.solver.warm_step == s.step


def test_warm_start_is_validated():
    from cloth_gym import ConfigError

    with pytest.raises(ConfigError, match="warm_start"):
        ImplicitEuler(warm_start=1)
