"""Material sensitivity: variants scale the right parameters; processes and Ray give the same table."""


import numpy as np
import pytest

from cloth_gym.agents.sensitivity import Variant, default_variants, run_sweep, variant_material, write_report
from cloth_gym import ConfigError, load_material


def test_variants_scale_only_their_group():
    base = load_material("thick_cotton")
    m = variant_material(base, "stretch_weft", 2.0)
    assert m.stretch.weft.c1 == pytest.approx(2 * base.stretch.weft.c1)
    assert m.stretch.warp == base.stretch.warp and m.bending == base.bending and m.shear == base.shear
    m = variant_material(base, "areal_mass", 0.5)
    assert m.areal_density == pytest.approx(0.5 * base.areal_density) and m.stretch == base.stretch
    m = variant_material(base, "bending_warp", 4.0)
    assert m.bending.warp.c2 == pytest.approx(4 * base.bending.warp.c2) and m.bending.weft == base.bending.weft
    with pytest.raises(ConfigError, match="group"):
        variant_material(base, "colour", 2.0)
    with pytest.raises(ConfigError, match="factor"):
        variant_material(base, "shear", -1.0)
    v = default_variants(factors=(0.5, 2.0))
    assert [x.label for x in v[:3]] == ["thick_cotton", "thin_wool", "thick_cotton (Breen)"]
    assert len(v) == 3 + 6 * 2


_VOLATILE = ("drape_wall_s", "policy_wall_s")


@pytest.mark.slow
def test_processes_and_a_local_ray_give_the_same_numbers(tmp_path):
    variants = [Variant("thick_cotton"), Variant("cotton stretch_warp x4", "thick_cotton", "stretch_warp", 4.0),
                Variant("cotton areal_mass x0.25", "thick_cotton", "areal_mass", 0.25)]
    drape = {"sigma": 2.54, "max_time_s": 0.4}
    policy = {"policy": "random", "env_id": "cloth_gym/CornerLift-v0", "episodes": 1, "seed": 3, "env_kwargs": {}}
    rows_p = run_sweep(variants, drape, policy, backend="process", workers=2, progress=False)
    rows_r = run_sweep(variants, drape, policy, backend="ray", workers=2, progress=False)
    for a, b in zip(rows_p, rows_r):
        for k in a:
            if k not in _VOLATILE:
                assert a[k] == b[k], k
    # the sweep measured something: scaling the material changes the drape
    dcs = [r["drape_coefficient"] for r in rows_p]
    assert len(set(np.round(dcs, 6))) == 3
    files = write_report(rows_p, tmp_path)
    assert files["csv"].read_text().count("\n") == 4
    md = files["md"].read_text()
    assert "cotton stretch_warp x4" in md and "| settled | diverged |" in md
    assert files["tornado_drape_coefficient"].stat().st_size > 1000


def test_a_user_fabric_gets_its_own_row_and_unsettled_sweeps_say_so(tmp_path):
    labels = [v.label for v in default_variants(base="configs/materials/thin_wool.yaml", factors=(2.0,))]
    assert "configs/materials/thin_wool.yaml" in labels  # the base every scaled row is compared with
    assert [v.label for v in default_variants(factors=(2.0,))].count("thick_cotton") == 1
    rows = [{"label": "a", "model": "kes", "base": "x", "drape_coefficient": 0.5, "settled": False},
            {"label": "b", "model": "kes", "base": "x", "group": "stretch", "factor": 2.0,
             "drape_coefficient": 0.6, "settled": False}]
    write_report(rows, tmp_path)
    assert "**No drape settled**" in (tmp_path / "sensitivity.md").read_text()
    rows[0]["settled"] = True
    write_report(rows, tmp_path)
    text = (tmp_path / "sensitivity.md").read_text()
    assert "No drape settled" not in text and "Not settled within the time allowed" in text and ": b." in text


def test_library_sweep_runs_each_case_on_each_fabric_and_draws_the_grid(tmp_path):
    """Two fabrics × (expert, random) on CornerLift-v2, one episode each: four rows, the expert lifts
    the corner on both fabrics and random on neither; the table and heat map name every cell; the
    random policy's return depends on the fabric (it is simulated with it)."""
    import json

    from cloth_gym.agents.sensitivity import library_sweep, library_variants, write_library_report
    from cloth_gym.materials import available_materials

    assert [v.label for v in library_variants()] == available_materials()
    with pytest.raises(ConfigError, match="materials"):
        library_variants(["thin_wool", "cardboard"])
    fabrics = ["thin_wool", "wang_11oz_black_denim"]
    cases = [("cloth_gym/CornerLift-v2", "expert"), ("cloth_gym/CornerLift-v2", "random")]
    rows = library_sweep(cases, library_variants(fabrics), episodes=1, seed=1000, workers=1)
    assert [(r["policy"], r["label"]) for r in rows] == [(p, f) for _, p in cases for f in fabrics]
    assert [r["success_rate"] for r in rows] == [1.0, 1.0, 0.0, 0.0]
    assert rows[2]["return_mean"] != rows[3]["return_mean"]
    files = write_library_report(rows, tmp_path, {"note": "test"})
    md = files["md"].read_text()
    assert "| thin_wool | 1.00 (" in md and "| wang_11oz_black_denim | 1.00 (" in md
    assert json.loads(files["json"].read_text())["meta"] == {"note": "test"}
    assert files["heatmap"].stat().st_size > 10_000
