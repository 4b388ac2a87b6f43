"""The integrators' phase profile (``last_profile``): each part of a call timed where it runs."""

import pytest

from cloth_gym.sim import Rectangle, SymplecticEuler, build_cloth
from cloth_gym.sim.bundles import PHASE_NAMES
from cloth_gym.sim.collision import CollisionOptions
from cloth_gym.sim.implicit import ImplicitEuler
from cloth_gym.sim.obstacles import Plane

IMPLICIT_ONLY = ("prepare", "assembly", "rhs", "factor", "friction", "newton")


def _cloth_on_floor(**kwargs):
    """A 10 cm cotton square lying at the contact thickness on a floor with friction."""
    return build_cloth(Rectangle(10.0, 10.0), "thick_cotton", sigma=1.0, origin=(0, 0, 0.1),
                       obstacles=[Plane((0, 0, 0), (0, 0, 1), friction=0.3)], contact_thickness=0.1, **kwargs)


def _profile(model, integ, dt=0.02):
    s = model.state()
    s.particle_qd[:, 0] = 20.0  # sliding: the solve, the contacts and friction all have work
    integ.step(model, s, None, dt)
    return integ.last_profile


def test_the_profile_accounts_for_the_whole_call():
    integ = ImplicitEuler(max_dt=5e-3, preconditioner="band")
    assert integ.last_profile is None
    prof = _profile(_cloth_on_floor(), integ)
    assert set(prof) == {*PHASE_NAMES, "other", "call", "total"}
    assert all(v >= 0.0 for v in prof.values())
    assert sum(v for k, v in prof.items() if k != "total") == pytest.approx(prof["total"], rel=1e-9)
    for phase in ("forces", "prepare", "assembly", "rhs", "factor", "solve", "friction", "obstacles", "checks"):
        assert prof[phase] > 0.0, phase
    # one Newton pass and no collision pass: nothing ran there
    assert prof["newton"] == 0.0 and prof["collision"] == 0.0


@pytest.mark.parametrize("preconditioner", ["band", "lines", "jacobi"])
def test_the_solves_split_into_products_and_preconditioner_applies_within_their_phases(preconditioner):
    integ = ImplicitEuler(max_dt=5e-3, preconditioner=preconditioner)
    assert integ.last_cg_profile is None
    prof = _profile(_cloth_on_floor(), integ)
    cg = integ.last_cg_profile
    assert set(cg) == {"product", "precondition"}
    assert cg["product"] > 0.0 and cg["precondition"] > 0.0
    # both are timed inside the solves, the band factorisation outside them
    assert cg["product"] + cg["precondition"] < prof["solve"] + prof["friction"] + prof["newton"]


@pytest.mark.parametrize("options, phase, runs", [
    ({"preconditioner": "jacobi"}, "factor", False),
    ({"preconditioner": "band"}, "factor", True),
    ({"friction_resolve": False}, "friction", False),
    ({"newton_iters": 2}, "newton", True),
])
def test_a_phase_is_timed_exactly_when_it_runs(options, phase, runs):
    prof = _profile(_cloth_on_floor(), ImplicitEuler(max_dt=5e-3, **options))
    assert (prof[phase] > 0.0) == runs


def test_the_collision_pass_is_its_own_phase():
    prof = _profile(_cloth_on_floor(collision=CollisionOptions(self_collision=True)), ImplicitEuler(max_dt=5e-3))
    assert prof["collision"] > 0.0


def test_the_explicit_integrator_reports_its_phases_and_none_of_the_solver():
    integ = SymplecticEuler(on_unstable="substep")
    prof = _profile(_cloth_on_floor(), integ, dt=2e-3)
    for phase in ("forces", "solve", "obstacles", "checks"):
        assert prof[phase] > 0.0, phase
    assert all(prof[p] == 0.0 for p in IMPLICIT_ONLY)
    assert integ.last_cg_profile == {"product": 0.0, "precondition": 0.0}
    assert sum(v for k, v in prof.items() if k != "total") == pytest.approx(prof["total"], rel=1e-9)


def test_a_call_that_finds_the_cloth_asleep_costs_nothing():
    m = _cloth_on_floor()
    s = m.state()
    integ = ImplicitEuler(max_dt=1e-2, sleep_speed=1e-3)
    for _ in range(40):
        integ.step(m, s, None, 0.05)
    assert integ.asleep
    assert all(v == 0.0 for v in integ.last_profile.values())
    assert all(v == 0.0 for v in integ.last_cg_profile.values())
