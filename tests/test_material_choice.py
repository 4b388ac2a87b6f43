"""Episodes whose fabric is drawn from several materials (``material="library"``, a list of
materials, or ``{"choose": [...], <ranges>}``): the draw is seeded and uniform, reported in
``info["material"]``, replays and snapshots stay exact, and bad choices name their field."""

import gymnasium as gym
import numpy as np
import pytest

import cloth_gym  # noqa: F401  (registers the env ids)
from cloth_gym import ConfigError, load_material
from cloth_gym.errors import SnapshotError
from cloth_gym.envs.settings import material_choices, resolve_material
from cloth_gym.materials import available_materials
from replay import play, same

ENV = "cloth_gym/RibbonDrop-v2"


def test_library_is_every_shipped_material_drawn_uniformly():
    names = [m.name for m in material_choices("library")]
    assert names == available_materials() and len(names) >= 12
    rng = np.random.default_rng(7)
    counts = {n: 0 for n in names}
    draws = 2400
    for _ in range(draws):
        counts[resolve_material("library", rng).name] += 1
    # each count ~ Binomial(2400, 1/12): mean 200, sd 13.5; 5 sd either side
    assert all(130 < c < 270 for c in counts.values()), counts
    # the drawn material is the shipped one itself, coefficient for coefficient
    assert resolve_material("library", np.random.default_rng(1)) == load_material(
        names[int(np.random.default_rng(1).integers(len(names)))])


def test_the_episode_fabric_follows_the_seed_and_is_reported_in_info():
    env = gym.make(ENV, material="library").unwrapped
    seen = {}
    for seed in range(10):
        _, info = env.reset(seed=seed)
        assert info["material"] == env.physics.model.material.name
        assert env.physics.model.material == load_material(info["material"])
        seen[seed] = info["material"]
        _, _, _, _, step_info = env.step(env.action_space.sample())
        assert step_info["material"] == info["material"]
    assert len(set(seen.values())) >= 4  # ten seeds over twelve fabrics
    twin = gym.make(ENV, material="library").unwrapped
    for seed in (3, 0, 9):
        assert twin.reset(seed=seed)[1]["material"] == seen[seed]
    # one material: no "material" key (nothing is drawn)
    assert "material" not in gym.make(ENV).unwrapped.reset(seed=0)[1]


def test_a_list_of_names_with_ranges_scales_the_chosen_fabric():
    spec = {"choose": ["thin_wool", "wang_gray_interlock"], "bending_scale": (0.5, 2.0), "friction": (0.1, 0.2)}
    env = gym.make(ENV, material=spec).unwrapped
    names = set()
    for seed in range(8):
        _, info = env.reset(seed=seed)
        m, ref = env.physics.model.material, load_material(info["material"])
        names.add(m.name)
        scale = m.bending.warp.c1 / ref.bending.warp.c1
        assert 0.5 <= scale <= 2.0 and 0.1 <= m.friction <= 0.2
        assert m.bending.weft.c1 == pytest.approx(scale * ref.bending.weft.c1, rel=1e-12)
        assert m.stretch == ref.stretch and m.areal_density == ref.areal_density
    assert names == {"thin_wool", "wang_gray_interlock"}


def test_snapshots_of_a_chosen_fabric_replay_bit_for_bit_and_refuse_other_choices():
    env = gym.make(ENV, material=["thick_cotton", "wang_11oz_black_denim", "wang_white_swim_solid"]).unwrapped
    seed = next(s for s in range(20) if env.reset(seed=s)[1]["material"] != "thick_cotton")
    env.reset(seed=seed)
    rng = np.random.default_rng(0)
    actions = [rng.uniform(-1, 1, 4).astype(np.float32) for _ in range(16)]
    play(env, actions[:6])
    snap = env.get_state()
    first = play(env, actions[6:])
    env.set_state(snap)
    same(first, play(env, actions[6:]))
    twin = gym.make(ENV, material=["thick_cotton", "wang_11oz_black_denim", "wang_white_swim_solid"]).unwrapped
    twin.set_state(snap)
    same(first, play(twin, actions[6:]))
    other = gym.make(ENV, material=["thick_cotton", "thin_wool"]).unwrapped
    with pytest.raises(SnapshotError) as err:
        other.set_state(snap)
    assert err.value.field == "snapshot.model.material"


@pytest.mark.parametrize("spec, field", [
    ([], "material"),
    (["thin_wool", "no_such_fabric"], "material[1]"),
    ({"choose": "everything"}, "material.choose"),
    ({"choose": ["thin_wool"], "base": "thin_wool"}, "material.choose"),
    ({"choose": ["thin_wool"], "colour": "red"}, "material.colour"),
    ({"choose": ["thin_wool", {"stretch": 1}]}, "material.choose[1].areal_density_g_per_cm2"),
    ({"choose": "library", "friction": (0.5, 20.0)}, "material.friction"),
])
def test_bad_choices_name_their_field(spec, field):
    with pytest.raises(ConfigError) as err:
        gym.make(ENV, material=spec)
    assert err.value.field == field
