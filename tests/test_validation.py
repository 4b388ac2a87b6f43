"""Bad input at every public entry point: a typed cloth_gym error naming the field, the value and
what is allowed, or the fixed behaviour. One test per case of the reliability review."""

import math
import pickle
import sys
import time
import warnings

import gymnasium as gym
import numpy as np
import pytest
import trimesh
import yaml

import cloth_gym  # noqa: F401  (registers the ids)
from cloth_gym import load_material
from cloth_gym.errors import (ClothGymError, ConfigError, ConfigTypeError, MaterialError, MaterialTypeError,
                              ResetNeeded, SimulationDiverged, SizeError)
from cloth_gym.materials import KESFitWarning, fit_kes_curve, fit_r_squared, materials_dir
from cloth_gym.sim import Disc, ForceOptions, Rectangle, Ribbon, build_cloth
from cloth_gym.sim.collision import CollisionOptions, MeshObstacle
from cloth_gym.sim.implicit import ImplicitEuler
from cloth_gym.sim.integrators import SymplecticEuler
from cloth_gym.sim.lattice import BYTES_PER_PARTICLE
from cloth_gym.sim.obstacles import Box, Cylinder, Plane, Sphere
from cloth_gym.units import G

CORNER = "cloth_gym/CornerLift-v0"


def shipped_yaml(name="thick_cotton"):
    return yaml.safe_load((materials_dir() / f"{name}.yaml").read_text())


# ----------------------------------------------------------------------------- the error types
def test_config_errors_survive_gymnasiums_re_raise_and_pickling():
    err = ConfigTypeError("sigma", "must be a real number, got '1'")
    again = type(err)(f"{err} was raised from the environment creator")  # what gymnasium.make does
    assert again.field == "sigma" and "was raised" in again.message
    assert isinstance(again, TypeError) and isinstance(again, ValueError) and isinstance(again, ClothGymError)
    back = pickle.loads(pickle.dumps(err))
    assert (type(back), back.field, back.message) == (ConfigTypeError, err.field, err.message)
    big = pickle.loads(pickle.dumps(SizeError("sigma", "too many", particles=7, memory_bytes=9.0)))
    assert (big.particles, big.memory_bytes) == (7, 9.0)


# ----------------------------------------------------------------------------- materials
def test_a_plain_material_mapping_with_a_friction_key_is_a_material_not_a_randomisation():
    data = shipped_yaml()
    assert "friction" in data
    env = gym.make(CORNER, material=data)
    assert env.unwrapped._model.material == load_material("thick_cotton")
    data["friction"] = 0.7  # its own value, not a range
    assert gym.make(CORNER, material=data).unwrapped._model.material.friction == 0.7
    env.close()


def test_a_mapping_that_is_neither_material_nor_randomisation_names_both_forms():
    with pytest.raises(ConfigError, match="randomisation dict") as info:
        gym.make(CORNER, material={"strech_scale": (0.5, 2.0)})
    assert info.value.field == "material"


def test_randomisation_ranges_are_checked_at_both_ends_when_the_env_is_made():
    with pytest.raises(ConfigError, match="50.0 makes an invalid material") as info:
        gym.make(CORNER, material={"friction": (0.1, 50.0)})  # μ <= 10
    assert info.value.field == "material.friction"
    with pytest.raises(ConfigTypeError):
        gym.make(CORNER, material={"friction": 0.3})  # a randomisation key needs a (low, high) range


def test_load_material_of_a_number_is_a_typed_error():
    with pytest.raises(MaterialTypeError, match="123") as info:
        load_material(123)
    assert isinstance(info.value, TypeError) and info.value.field == "material"


def test_yaml_syntax_error_names_the_file_and_line(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("name: broken\nstretch: [1, 2\nbending: 3\n")
    with pytest.raises(MaterialError) as info:
        load_material(path)
    msg = str(info.value)
    assert str(path) in msg and "line 3" in msg and "not valid YAML" in msg


def test_a_material_error_from_an_env_names_the_file(tmp_path):
    data = shipped_yaml()
    data["friction"] = -1.0
    path = tmp_path / "sticky.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(MaterialError) as info:
        gym.make(CORNER, material=str(path))
    assert info.value.field == "friction" and str(path) in str(info.value) and info.value.file == str(path)
    assert "-1.0" in str(info.value) and "[0, 10]" in str(info.value)


def test_non_monotonic_kes_samples_warn_with_the_fits_r_squared():
    x, y = [0.0, 1.0, 2.0, 3.0, 4.0], [0.0, 5.0, 1.0, 6.0, 8.0]
    with pytest.warns(KESFitWarning, match=r"fall by 4, 50 % of their range.*R² = ") as rec:
        curve = fit_kes_curve(x, y, fieldname="stretch.warp")
    # R² by hand: 1 − Σ(y − ŷ)² / Σ(y − ȳ)²
    yh = np.array([curve(xi) for xi in x])
    r2 = 1.0 - np.sum((np.array(y) - yh) ** 2) / np.sum((np.array(y) - np.mean(y)) ** 2)
    assert f"{r2:.3f}" in str(rec[0].message) and "stretch.warp" in str(rec[0].message)
    assert fit_r_squared(x, y, curve) == pytest.approx(r2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # rising samples, or dips within noise (< 2 % of the range): no warning
        fit_kes_curve([0.0, 1.0, 2.0, 3.0], [0.0, 1.0, 4.5, 9.5])
        fit_kes_curve([0.0, 1.0, 2.0, 3.0, 4.0], [0.0, 1.0, 0.9, 4.5, 9.5])  # falls 0.1 of 9.5


def test_kes_samples_of_the_wrong_type_are_typed_errors():
    with pytest.raises(MaterialTypeError):
        fit_kes_curve("0 1 2", [0, 1, 2])
    with pytest.raises(MaterialTypeError):
        fit_kes_curve([0, 1, [2, 3]], [0, 1, 2])
    with pytest.raises(MaterialTypeError):
        fit_kes_curve([0, 1, 2], [0, 1, 2], terms="c1")


# ----------------------------------------------------------------------------- env kwargs, actions, resets
def test_unknown_env_kwarg_is_a_typed_error_listing_the_valid_ones():
    with pytest.raises(ConfigTypeError) as info:
        gym.make(CORNER, foo=1)
    assert info.value.field == "foo" and isinstance(info.value, TypeError)
    for valid in ("material", "sigma", "control_dt", "render_mode", "solver_tol"):
        assert valid in info.value.message


@pytest.mark.parametrize("action", ["up", {"dx": 1}, [[1, 2], [3]], np.array([1j, 0, 0, 0]), None,
                                    [1, None, 0, 0], np.array(["1", "2", "3", "4"]), b"abcd"])
def test_actions_of_the_wrong_type_are_typed_errors(action):
    env = gym.make(CORNER)
    env.reset(seed=0)
    with pytest.raises(ConfigTypeError) as info:
        env.step(action)
    assert info.value.field == "action" and "4 numbers" in info.value.message


def test_actions_of_any_real_dtype_work():
    env = gym.make(CORNER)
    env.reset(seed=0)
    for a in (np.zeros(4, dtype=np.int8), np.ones(4, dtype=np.uint16), np.zeros(4, dtype=np.float16),
              np.array([True, False, True, False]), [0, 0.5, -1, 1], np.zeros(4, dtype=object)):
        obs, *_ = env.step(a)
        assert np.all(np.isfinite(obs))


def test_seed_and_options_of_the_wrong_type_are_typed_errors():
    env = gym.make(CORNER)
    with pytest.raises(ConfigTypeError, match="seed"):
        env.reset(seed="a")
    with pytest.raises(ConfigError, match="seed"):
        env.reset(seed=-1)
    with pytest.raises(ConfigTypeError, match="gripper_start"):
        env.reset(options=[1])
    with pytest.raises(ConfigError, match="options.gripper_start"):
        env.reset(options={"gripper_start": ["corner"]})  # unhashable: compared, not hashed
    obs, _ = env.reset(seed=np.int64(3))
    assert np.all(np.isfinite(obs))


def test_a_non_string_render_mode_is_refused_by_the_env():
    from cloth_gym.envs.corner_lift import CornerLiftEnv

    with pytest.raises(ConfigError, match="render_mode"):
        CornerLiftEnv(render_mode=3)


def test_step_before_reset_is_a_typed_error():
    from cloth_gym.envs.corner_lift import CornerLiftEnv

    with pytest.raises(ResetNeeded):
        CornerLiftEnv().step(np.zeros(4))


def test_human_render_mode_without_pygame_is_refused_when_the_env_is_made(monkeypatch):
    """The class names what is missing (through gym.make, an install without pygame does not
    advertise "human" and Gymnasium's HumanRendering says so: tests/test_checkers.py)."""
    from cloth_gym.envs.corner_lift import CornerLiftEnv

    monkeypatch.setitem(sys.modules, "pygame", None)  # import pygame -> ImportError
    with pytest.raises(ConfigError, match="pygame") as info:
        CornerLiftEnv(render_mode="human")
    assert info.value.field == "render_mode"


def test_human_render_mode_shows_the_rgb_frame(monkeypatch):
    pygame = pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    env = gym.make(CORNER, render_mode="human")
    env.reset(seed=0)
    env.step(np.zeros(4))
    shown = pygame.surfarray.array3d(pygame.display.get_surface()).swapaxes(0, 1)
    frame = env.unwrapped._picture_frame(320, 240)
    assert env.render() is None and np.array_equal(shown, frame)
    env.close()
    assert not pygame.display.get_init()


@pytest.mark.parametrize("kwargs, field, kind", [
    (dict(sigma="1"), "sigma", ConfigTypeError),
    (dict(image_size=32.0), "image_size", ConfigTypeError),
    (dict(reward_weights=[1, 2]), "reward_weights", ConfigTypeError),
    (dict(model=["kes"]), "model", ConfigError),
    (dict(render_mode="window"), "render_mode", ConfigError),
    (dict(max_step_cm=math.nan), "max_step_cm", ConfigError),
])
def test_env_kwargs_of_the_wrong_type_or_value(kwargs, field, kind):
    with pytest.raises(kind) as info:
        gym.make(CORNER, **kwargs)
    assert info.value.field == field


# ----------------------------------------------------------------------------- integrators
@pytest.fixture(scope="module")
def tiny():
    return build_cloth(Rectangle(4.0, 4.0), sigma=1.0)


@pytest.mark.parametrize("make", [ImplicitEuler, lambda: SymplecticEuler(on_unstable="substep")])
@pytest.mark.parametrize("dt", [0.0, -1e-3, math.nan, math.inf, 1e9, 1e-12])
def test_advance_with_a_bad_step_is_a_config_error(tiny, make, dt):
    state = tiny.state()
    with pytest.raises(ConfigError) as info:
        make().advance(tiny, state, None, 0.1, dt)
    assert info.value.field == "dt" and "[1e-09, 86400] s" in info.value.message
    assert state.time == 0.0
    with pytest.raises(ConfigError, match="dt"):
        make().step(tiny, state, None, dt)


@pytest.mark.parametrize("make", [ImplicitEuler, SymplecticEuler])
@pytest.mark.parametrize("kwargs, field, kind", [
    (dict(max_speed=math.nan), "max_speed", ConfigError),
    (dict(max_strain_percent=math.nan), "max_strain_percent", ConfigError),
    (dict(max_speed="fast"), "max_speed", ConfigTypeError),
])
def test_divergence_guards_cannot_be_switched_off_by_nan(make, kwargs, field, kind):
    with pytest.raises(kind) as info:
        make(**kwargs)
    assert info.value.field == field


@pytest.mark.parametrize("kwargs, field", [(dict(max_dt=True), "max_dt"), (dict(max_iter=2.0), "max_iter"),
                                           (dict(warm_start=1), "warm_start"), (dict(tol="1e-4"), "tol")])
def test_implicit_options_of_the_wrong_type(kwargs, field):
    with pytest.raises(ConfigTypeError) as info:
        ImplicitEuler(**kwargs)
    assert info.value.field == field


def test_a_call_of_too_many_steps_is_refused_not_run(tiny):
    with pytest.raises(ConfigError, match="MAX_STEPS_PER_CALL"):
        SymplecticEuler(on_unstable="substep").advance(tiny, tiny.state(), None, 86400.0, 1e-3)
    with pytest.raises(ConfigError, match="MAX_STEPS_PER_CALL"):
        ImplicitEuler(max_dt=1e-6).step(tiny, tiny.state(), None, 100.0)


def test_a_foreign_state_is_refused_and_a_non_finite_one_diverges_naming_the_particle(tiny):
    state = tiny.state()
    state.particle_q[3, 1] = math.nan
    with pytest.raises(SimulationDiverged) as info:
        ImplicitEuler().step(tiny, state, None, 0.01)
    assert info.value.particle == 3 and info.value.reason == "non-finite"
    state = tiny.state()
    other = build_cloth(Rectangle(2.0, 2.0), sigma=1.0).state()
    with pytest.raises(ConfigError, match=r"\(25, 3\)"):
        SymplecticEuler(on_unstable="substep").step(tiny, other, None, 0.01)
    with pytest.raises(ConfigTypeError, match="model"):
        ImplicitEuler().step("model", state, None, 0.01)


def test_multigrid_levels_beyond_the_users_spacing_range_build():
    """A 17 × 17 lattice at σ = 20 cm coarsens to 40 and 80 cm, beyond build_cloth's 50 cm."""
    model = build_cloth(Rectangle(320.0, 320.0), sigma=20.0)
    state = model.state()
    ImplicitEuler(preconditioner="multigrid", max_dt=0.01, tol=1e-12).step(model, state, None, 0.01)
    # one backward Euler step from rest: Δv = −g·h for every particle (a translation neither strains
    # nor is damped by the strain-rate damping)
    assert np.allclose(state.particle_qd[:, 2], state.particle_qd[0, 2], rtol=1e-9)
    assert state.particle_qd[0, 2] == pytest.approx(-G * 0.01, rel=1e-6)


# ----------------------------------------------------------------------------- shapes, lattice, size guard
def test_size_guard_refuses_at_once_with_count_and_memory():
    t0 = time.process_time()
    with pytest.raises(SizeError) as info:
        build_cloth(Rectangle(100.0, 100.0), sigma=0.01)
    assert time.process_time() - t0 < 1.0  # refused before anything is allocated
    assert info.value.particles == 10001 ** 2
    assert info.value.memory_bytes == 10001 ** 2 * BYTES_PER_PARTICLE
    assert "100,020,001 particles" in str(info.value) and "GiB" in str(info.value)
    with pytest.raises(SizeError):
        gym.make(CORNER, sigma=0.02)


def test_size_guard_is_an_option():
    with pytest.raises(SizeError, match="121 particles"):
        build_cloth(Rectangle(10.0, 10.0), sigma=1.0, max_particles=120)
    assert build_cloth(Rectangle(10.0, 10.0), sigma=1.0, max_particles=121).particle_count == 121


@pytest.mark.parametrize("diameter, sigma", [(10.0, 1.0), (7.3, 0.5), (30.0, 1.0), (2.0, 1.0), (36.0, 0.7)])
def test_disc_counts_its_particles_without_building(diameter, sigma):
    assert Disc(diameter).particle_count(sigma) == build_cloth(Disc(diameter), sigma=sigma).particle_count


@pytest.mark.parametrize("make, field", [
    (lambda: Rectangle("a", 10), "Rectangle.warp_cm"),
    (lambda: Ribbon(10, None), "Ribbon.weft_cm"),
    (lambda: Disc(True), "Disc.diameter_cm"),
    (lambda: build_cloth("square"), "shape"),
    (lambda: build_cloth(Rectangle(4, 4), sigma=1.0, origin="000"), "origin"),
    (lambda: build_cloth(Rectangle(4, 4), sigma=1.0, rotation=[["a"] * 3] * 3), "rotation"),
    (lambda: build_cloth(Rectangle(4, 4), sigma=1.0, pinned=[0.5]), "pinned"),
    (lambda: build_cloth(Rectangle(4, 4), sigma=1.0, obstacles=Plane()), "obstacles"),
])
def test_shapes_and_builder_arguments_of_the_wrong_type(make, field):
    with pytest.raises(ConfigTypeError) as info:
        make()
    assert info.value.field == field


# ----------------------------------------------------------------------------- obstacles
@pytest.mark.parametrize("make, field", [
    (lambda: Plane(normal=(0, 0, 0)), "Plane.normal"),
    (lambda: Box((0, 0, 0), (1, -1, 1)), "Box.half_extents"),
    (lambda: Sphere((0, 0, 0), math.inf), "Sphere.radius"),
    (lambda: Cylinder((0, 0, 0), 1.0, 2.0, friction=math.nan), "Cylinder.friction"),
    (lambda: CollisionOptions(iterations=True), "collision.iterations"),
])
def test_obstacles_are_checked_when_made(make, field):
    with pytest.raises(ConfigError) as info:
        make()
    assert info.value.field == field


def test_open_and_zero_area_meshes_are_refused():
    sheet = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]])
    with pytest.raises(ConfigError, match="not closed"):
        MeshObstacle(sheet)
    flat = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    v = np.array(flat.vertices)
    v[:, 2] = 0.0  # squashed to zero thickness: every side face has zero area
    with pytest.raises(ConfigError, match="zero-area"):
        MeshObstacle(trimesh.Trimesh(vertices=v, faces=flat.faces, process=False))
    MeshObstacle(trimesh.creation.box(extents=(1.0, 1.0, 1.0)))  # closed: fine


# ----------------------------------------------------------------------------- a hostile user's inputs
def _cloth():
    return build_cloth(Rectangle(4.0, 4.0), sigma=1.0)


def _bad_state(**change):
    m = _cloth()
    s = m.state()
    for k, v in change.items():
        setattr(s, k, v)
    return m, s


@pytest.mark.parametrize("call", [
    lambda: build_cloth(Rectangle(4, 4), sigma=10**400),                      # an int beyond the float range
    lambda: build_cloth(Rectangle(4, 4), sigma=5e-324),                        # overflows the particle count
    lambda: build_cloth(Disc(4), sigma=1e-300),
    lambda: build_cloth(Rectangle, sigma=1.0),                                 # the class, not a shape
    lambda: build_cloth(Rectangle(4, 4), sigma=1.0, obstacles=[Plane]),
    lambda: build_cloth(Rectangle(4, 4), sigma=1.0, rotation=np.eye(3) * (1 + 0j)),
    lambda: Box(["1", "2", "3"], (1, 1, 1)),                                  # numeric strings are strings
    lambda: ForceOptions(model=np.array(["kes", "breen"])),
    lambda: SymplecticEuler(on_unstable=np.array(["raise"])),
    lambda: load_material("x" * 5000),                                         # a name too long for a path
    lambda: cloth_gym.sim.model.Control(wind=[10**400, 0, 0]),
    lambda: fit_kes_curve([10**400, 1, 2], [1, 2, 3]),
    lambda: fit_kes_curve([0, 5e-324, 1e-323], [0, 1, 2], terms=["c1", "c2"]),  # infinite coefficients
    lambda: load_material("thick_cotton").replace(foo=1),
    lambda: cloth_gym.Material.from_dict({**shipped_yaml(), "name": [1, 2]}),
])
def test_hostile_arguments_raise_cloth_gym_errors(call):
    """One-line cases of an adversarial review: each raised another exception type or was accepted."""
    with pytest.raises(ClothGymError):
        out = call()
        if isinstance(out, cloth_gym.sim.model.Control):  # a Control is checked when it is used
            ImplicitEuler().step(_cloth(), _cloth().state(), out, 0.01)


@pytest.mark.parametrize("change, field", [
    (dict(time="abc"), "state.time"), (dict(step=1.5), "state.step"), (dict(time=math.nan), "state.time"),
    (dict(obstacle_offset=[[0, 0, 0]]), "state.obstacle_offset"), (dict(solver=None), "state.solver"),
])
def test_state_fields_are_checked_by_both_integrators(change, field):
    for integ in (ImplicitEuler(), SymplecticEuler(on_unstable="substep")):
        m, s = _bad_state(**change)
        with pytest.raises(ClothGymError) as info:
            integ.step(m, s, None, 0.01)
        assert info.value.field == field


def test_obstacles_may_come_in_any_iterable():
    model = build_cloth(Rectangle(4, 4), sigma=1.0, obstacles=np.array([Plane(), Plane(point=(0, 0, -5))]))
    assert model.obstacle_arrays[0].tolist() == [0, 0]
    assert build_cloth(Rectangle(4, 4), sigma=1.0, obstacles=np.array([])).obstacle_arrays[0].size == 0


def test_a_read_only_state_is_refused_before_compiling_anything():
    m = _cloth()
    from cloth_gym.sim.model import State

    with pytest.raises(ConfigError, match="writeable"):
        ImplicitEuler().step(m, State(m.particle_q0, np.zeros((m.particle_count, 3))), None, 0.01)


@pytest.mark.parametrize("control, field", [
    (dict(wind=[1e200, 0, 0]), "Control.wind"), (dict(wind=["1", "2", "3"]), "Control.wind"),
    (dict(obstacle_velocity="abc"), "Control.obstacle_velocity"), (dict(kinematic=[[True], [True, False]]),
                                                                   "Control.kinematic"),
])
def test_control_inputs_are_checked(control, field):
    m = _cloth()
    with pytest.raises(ClothGymError) as info:
        ImplicitEuler().step(m, m.state(), cloth_gym.sim.model.Control(**control), 0.01)
    assert info.value.field == field


@pytest.mark.parametrize("make", [ImplicitEuler, lambda: SymplecticEuler(on_unstable="substep")])
def test_advance_over_less_than_one_step_takes_one_short_step(make):
    m = _cloth()
    s = m.state()
    assert make().advance(m, s, None, 1e-6, 0.01) >= 1
    assert s.time == pytest.approx(1e-6)


@pytest.mark.parametrize("err", [SimulationDiverged(1, 2.0, 3, "speed", 4.0), cloth_gym.StabilityError(1.0, 2.0, "m"),
                                 cloth_gym.InsideObstacle(5, 1, 2.5, 0.1, "Box")])
def test_simulation_errors_pickle(err):
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is type(err) and str(back) == str(err) and back.__dict__ == err.__dict__


def test_env_options_a_hostile_user_tried():
    with pytest.raises(ConfigError, match="implicit integrator only"):
        gym.make(CORNER, integrator="explicit", sim_dt=1e-3)
    with pytest.raises(ConfigError, match="substeps per control step"):
        gym.make(CORNER, sim_dt=1e-6, control_dt=1.0)
    with pytest.raises(ConfigError, match="reward_weights.reach"):
        gym.make(CORNER, reward_weights={"reach": 1e308})
    with pytest.raises(ConfigError) as info:
        gym.make(CORNER, material={"areal_density_scale": (1, 1e4)})
    assert info.value.field == "material.areal_density_scale"
    with pytest.raises(ConfigError) as info:
        gym.make(CORNER, material={"base": {"friction": (0, 1)}})
    assert info.value.field == "material.base"
    env = gym.make(CORNER)
    with pytest.raises(ConfigError, match="options.gripper_start"):
        env.reset(options={"gripper_start": np.array(["corner", "held"])})


def test_training_config_inputs_a_hostile_user_tried(tmp_path):
    from cloth_gym.agents.config import load_train_config, parse_overrides

    with pytest.raises(ConfigTypeError):
        parse_overrides([1])
    with pytest.raises(ConfigError):
        parse_overrides(["k=" + "[" * 20000 + "]" * 20000])
    with pytest.raises(ConfigTypeError):
        load_train_config("ppo", 5)
    with pytest.raises(ConfigError):
        load_train_config("ppo", CORNER, "/tmp/" + "x" * 5000)
    for bad in ({"n_timesteps": 10**400}, {"batch_size": 0}, {"learning_rate": "lin_inf"},
                {"env_kwargs": {"sigmaa": 1.0}}):
        with pytest.raises(ConfigError):
            load_train_config("ppo", CORNER, overrides=bad)
