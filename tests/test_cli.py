"""The ``cloth-gym`` command: every subcommand's help, and each run on a tiny case."""

import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from cloth_gym import fit_kes_curve, load_material
from cloth_gym.cli import main
from cloth_gym.materials import materials_dir

SUBCOMMANDS = {"drape": "--material", "figures": "--fig", "fit-kes": "--name", "envs": "", "configs": "--list",
               "warmup": "--no-envs"}


def test_help_of_the_command_and_of_each_subcommand():
    top = subprocess.run([sys.executable, "-m", "cloth_gym.cli", "--help"], capture_output=True, text=True)
    assert top.returncode == 0
    for name, option in SUBCOMMANDS.items():
        assert name in top.stdout
        sub = subprocess.run([sys.executable, "-m", "cloth_gym.cli", name, "--help"], capture_output=True, text=True)
        assert sub.returncode == 0, sub.stderr
        assert f"usage: cloth-gym {name}" in sub.stdout and option in sub.stdout


@pytest.fixture
def raw_fabric(tmp_path):
    """Cotton with three curves replaced by noisy raw samples of known polynomials."""
    rng = np.random.default_rng(0)
    data = yaml.safe_load((materials_dir() / "thick_cotton.yaml").read_text())
    data["name"] = "my_cotton"
    eps = np.linspace(0, 3, 16)
    data["stretch"]["warp"] = {"strain_percent": eps.tolist(),
                               "stress_gf_per_cm": (36.77 * eps + 38.38 * eps ** 2 + rng.normal(0, 2, 16)).tolist()}
    phi = np.linspace(0, 8, 12)
    data["shear"]["warp"] = {"angle_deg": phi.tolist(),
                             "force_gf_per_cm": (1.1 * np.sqrt(phi) + 0.49 * phi + 0.04 * phi ** 2).tolist()}
    path = tmp_path / "raw.yaml"
    path.write_text(yaml.safe_dump(data))
    return path, data


def test_fit_kes_writes_the_fitted_material_plot_and_r_squared(raw_fabric, tmp_path, capsys):
    path, data = raw_fabric
    assert main(["fit-kes", str(path), "--out", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    fitted = load_material(tmp_path / "out" / "raw.yaml")  # files are named after the input's stem
    assert fitted.name == "my_cotton"  # the material keeps its own name
    expect = fit_kes_curve(data["stretch"]["warp"]["strain_percent"], data["stretch"]["warp"]["stress_gf_per_cm"],
                           terms=("c1", "c2"))
    assert fitted.stretch.warp == expect
    np.testing.assert_allclose(fitted.shear.warp.as_array(), [1.1, 0.49, 0.04], rtol=1e-8)  # exact samples
    assert fitted.bending == load_material("thick_cotton").bending  # given as coefficients: unchanged
    report = json.loads((tmp_path / "out" / "raw_fit.json").read_text())
    r2 = {(c["kind"], c["direction"]): c["r_squared"] for c in report["curves"]}
    assert 0.99 < r2[("stretch", "warp")] < 1.0 and r2[("shear", "warp")] == pytest.approx(1.0, abs=1e-12)
    assert r2[("bending", "warp")] is None
    assert "stretch.warp" in printed and f"{r2[('stretch', 'warp')]:.4f}" in printed
    assert (tmp_path / "out" / "raw_fit.png").stat().st_size > 10_000


def test_fit_kes_bad_file_is_an_error_naming_the_file_and_field(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    data = yaml.safe_load((materials_dir() / "thin_wool.yaml").read_text())
    data["stretch"]["weft"] = {"strain_percent": [0, 1, 2], "stress_gf_per_cm": [0, 1]}
    bad.write_text(yaml.safe_dump(data))
    assert main(["fit-kes", str(bad), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "stretch.weft" in err and str(bad) in err


def test_drape_and_figures_take_a_users_fabric(raw_fabric, tmp_path):
    path, _ = raw_fabric
    assert main(["fit-kes", str(path), "--name", "my_cotton", "--out", str(tmp_path / "fit")]) == 0
    mine = str(tmp_path / "fit" / "my_cotton.yaml")
    assert main(["drape", "--material", mine, "--sigma", "2.5", "--max-time", "0.3", "--quiet",
                 "--out", str(tmp_path / "drape")]) == 0
    metrics = json.loads((tmp_path / "drape" / "my_cotton_kes" / "metrics.json").read_text())  # the file's stem
    assert metrics["parameters"]["material"] == "my_cotton" and 0 < metrics["drape_coefficient"] <= 1.0
    assert metrics["command"].startswith("cloth-gym drape --material")
    assert main(["figures", "--fig", "3", "--fast", "--material", mine, "thin_wool", "--out",
                 str(tmp_path / "fig")]) == 0
    fig3 = json.loads((tmp_path / "fig" / "fig3.json").read_text())
    assert fig3["material_names"] == ["my_cotton", "thin_wool"]
    # the fitted warp stretch, not cotton's: the figure's 1 % tension follows the fit
    assert fig3["materials"]["my_cotton"]["stretch_kes_warp_at_1pct_dyne"] != pytest.approx(
        fig3["materials"]["thin_wool"]["stretch_kes_warp_at_1pct_dyne"])


@pytest.mark.parametrize("curve, field", [
    ({"strain_percent": [0, 1, 2, 3], "stress_gf_per_cm": [0, 30, 45, 58], "terms": ["c0", "c1", "c2"]},
     "stretch.weft"),                                                     # stretch has no root term
    ({"strain_percent": [0, 1, 2, 3], "stress_gf_per_cm": [0, 30, 45, 58], "term": ["c1"]}, "stretch.weft.term"),
])
def test_fit_kes_refuses_what_loading_the_file_refuses(tmp_path, capsys, curve, field):
    data = yaml.safe_load((materials_dir() / "thin_wool.yaml").read_text())
    data["stretch"]["weft"] = curve
    path = tmp_path / "mine.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(Exception) as loading:
        load_material(path)
    assert main(["fit-kes", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert field in err and field in str(loading.value)
    assert not (tmp_path / "out" / "mine.yaml").exists()


def test_fit_kes_name_must_be_a_file_name_and_figures_need_distinct_materials(tmp_path, capsys):
    path = materials_dir() / "thin_wool.yaml"
    assert main(["fit-kes", str(path), "--name", "../escape", "--out", str(tmp_path / "out")]) == 2
    assert "name" in capsys.readouterr().err and not (tmp_path / "escape.yaml").exists()
    twin = tmp_path / "twin.yaml"
    twin.write_text(path.read_text())  # a copy that keeps 'name: thin_wool'
    assert main(["figures", "--fig", "3", "--material", "thin_wool", str(twin), "--out", str(tmp_path / "f")]) == 2
    assert "distinct names" in capsys.readouterr().err


def test_warmup_command_compiles_the_simulator(capsys):
    assert main(["warmup", "--no-envs"]) == 0
    err = capsys.readouterr().err
    assert "cloth_gym.warmup: simulator, kes model" in err and "cloth_gym.warmup: done in" in err
    assert "environments" not in err  # --no-envs


def test_drape_over_seeds_reports_the_node_count_distribution(tmp_path):
    """``cloth-gym drape --seed 0 1``: a run per seed in seed_<k>/, and seeds.json with the node
    counts' distribution and the drape coefficient's mean and spread over the runs."""
    assert main(["drape", "--material", "thin_wool", "--sigma", "2.54", "--seed", "0", "1", "--max-time", "0.3",
                 "--quiet", "--out", str(tmp_path)]) == 0
    out = tmp_path / "thin_wool_kes"
    runs = [json.loads((out / f"seed_{k}" / "metrics.json").read_text()) for k in (0, 1)]
    summary = json.loads((out / "seeds.json").read_text())
    assert summary["seeds"] == [0, 1] and [r["seed"] for r in runs] == [0, 1]
    assert sum(summary["node_counts"].values()) == 2
    dc = [r["drape_coefficient"] for r in runs]
    assert summary["drape_coefficient_mean"] == pytest.approx(sum(dc) / 2)
    assert summary["drape_coefficient_sd"] == pytest.approx(abs(dc[0] - dc[1]) / 2)
    assert summary["command"] == f"cloth-gym drape --material thin_wool --sigma 2.54 --seed 0 1 --max-time 0.3 " \
                                 f"--quiet --out {tmp_path}"


def test_seed_summary_hand_values():
    from cloth_gym.reports.drape import seed_summary

    runs = [{"seed": 0, "node_count": 4, "drape_coefficient": 0.5, "settled": True},
            {"seed": 1, "node_count": 5, "drape_coefficient": 0.7, "settled": True},
            {"seed": 2, "node_count": 4, "drape_coefficient": 0.6, "settled": False}]
    s = seed_summary(runs)
    assert s["node_counts"] == {4: 2, 5: 1} and list(s["node_counts"]) == [4, 5]
    assert s["drape_coefficient_mean"] == pytest.approx(0.6)
    assert s["drape_coefficient_sd"] == pytest.approx(np.sqrt(0.02 / 3))
    assert (s["drape_coefficient_min"], s["drape_coefficient_max"]) == (0.5, 0.7) and s["settled"] is False


def test_fit_kes_runs_on_the_shipped_example(tmp_path):
    """The KES-samples example shipped with the package (``$(cloth-gym configs)/examples/my_fabric.yaml``,
    the one docs/materials.md shows) fits: a fitted material, its plot and R² for the sampled curve."""
    from cloth_gym.configs import __file__ as configs_init
    from pathlib import Path

    example = Path(configs_init).parent / "examples" / "my_fabric.yaml"
    docs = (Path(__file__).parents[1] / "docs" / "materials.md").read_text(encoding="utf-8")
    assert example.read_text(encoding="utf-8") in docs  # one example: the page shows the shipped file
    assert main(["fit-kes", str(example), "--out", str(tmp_path)]) == 0
    fitted = load_material(tmp_path / "my_fabric.yaml")
    assert fitted.name == "my_fabric" and (tmp_path / "my_fabric_fit.png").exists()
    assert fitted.stretch.weft == load_material(example).stretch.weft  # the samples' fit, as loading fits them
