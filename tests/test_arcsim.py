"""The ARCSim material importer against hand values from the source samples and against
ARCSim's hinge energy on real bent meshes."""

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from cloth_gym import load_material
from cloth_gym.arcsim import CURVATURE_PER_CM, GF, convert, parse_arcsim, read_arcsim
from cloth_gym.errors import MaterialError
from cloth_gym.materials import KESFitWarning

DATA = Path(__file__).parent / "data" / "arcsim"
DENIM = DATA / "11oz-black-denim.json"
INTERLOCK = DATA / "gray-interlock.json"


@pytest.fixture(scope="module")
def denim():
    return read_arcsim(DENIM)


@pytest.fixture(scope="module")
def interlock():
    return read_arcsim(INTERLOCK)


def test_reads_the_shipped_source_file_as_stored(denim):
    raw = json.loads(DENIM.read_text())
    assert denim.density == raw["density"] == 0.324
    assert np.array_equal(denim.stretching, raw["stretching"])
    assert np.array_equal(denim.bending, raw["bending"])


@pytest.mark.parametrize("angle, row", [(0.0, 1), (90.0, 5)])
def test_saturated_uniaxial_tension_is_the_stretched_sample_with_free_lateral_stress(denim, angle, row):
    # at 20 % the principal stretch is past 1 + 1/6: the stiffness is the stretched row, doubled
    k0, k1, k2, _ = 2.0 * denim.stretching[row]
    along, across = (k0, k2) if angle == 0.0 else (k2, k0)
    G = (1.2 ** 2 - 1.0) / 2.0
    hand = 1.2 * (along - k1 * k1 / across) * G  # lateral stress zero: G_⊥ = -k1/k_⊥ · G
    assert denim.uniaxial_tension(np.array([0.2]), angle)[0] == pytest.approx(hand, rel=1e-5)


@pytest.mark.parametrize("angle", [0.0, 90.0])
def test_tension_at_zero_strain_rises_with_the_zero_strain_sample(interlock, angle):
    k0, k1, k2, _ = 2.0 * np.maximum(interlock.stretching[0], 0.0)  # interlock's k1 is negative: clipped
    slope = (k0 if angle == 0.0 else k2) - k1 * k1 / (k2 if angle == 0.0 else k0)
    eps = 1e-7
    assert interlock.uniaxial_tension(np.array([eps]), angle)[0] / eps == pytest.approx(slope, rel=1e-5)


def test_runtime_table_rounds_the_blend_at_zero_strain_towards_the_stretched_samples(interlock):
    # ARCSim's table has no node at G00 = G11 = 0: it averages the four nodes at ±1/60. Where a
    # diagonal strain is +1/60 the principal stretch has ramped 6·(√(1 + 1/30) − 1) of the way to
    # the stretched row of its direction (u for (+, −) and for the tie (+, +), v for (−, +))
    G = np.zeros((2, 2))
    ramp = 6.0 * (math.sqrt(1.0 + 1.0 / 30.0) - 1.0)
    r0, r_u, r_v = interlock.stretching[0, 0], interlock.stretching[1, 0], interlock.stretching[5, 0]
    hand = 2.0 * (r0 + ramp * (2.0 * (r_u - r0) + (r_v - r0)) / 4.0)
    assert interlock.table_stiffness(G)[0] == pytest.approx(hand, rel=1e-6)  # ARCSim clips 1e-5 inside its grid
    assert interlock.stiffness(G)[0] == pytest.approx(2.0 * r0, rel=1e-12)


@pytest.mark.parametrize("along", [0, 1])
def test_shear_force_small_angle_slope_is_the_zero_strain_shear_sample(denim, along):
    phi = 1e-4  # degrees
    gamma = math.tan(math.radians(phi))
    hand = 2.0 * denim.stretching[0, 3] * gamma / 2.0  # dW/dγ = k3·γ/2, k3 = 2·C33
    assert denim.shear_force(np.array([phi]), along)[0] == pytest.approx(hand, rel=1e-5)


def test_bending_moment_of_a_constant_hinge_stiffness_is_ke_kappa_over_4():
    mat = parse_arcsim({"density": 0.1, "stretching": [[40, 0, 40, 40]] * 6, "bending": [[20e-6] * 5] * 3})
    kappa = np.array([0.1, 0.5, 2.0])  # 1/cm
    assert np.allclose(mat.bending_moment(kappa, 0), 20e-6 * kappa * 100.0 / 4.0, rtol=1e-12)


# the reference: ARCSim's hinge forces on equilateral meshes wrapped on a cylinder (exact dihedral
# angles of the wrapped vertices), against the closed form of the conversion
@pytest.mark.parametrize("name", ["denim", "interlock"])
@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("kappa", [0.03, 0.17, 0.41, 0.9])
def test_bending_moment_matches_arcsim_hinges_on_bent_meshes_within_1_percent(request, name, axis, kappa):
    mat = request.getfixturevalue(name)
    assert mat.bending_moment(np.array([kappa]), axis)[0] == pytest.approx(mat.mesh_bending_moment(kappa, axis), rel=0.01)


def test_converted_material_loads_with_the_source_density_and_curves(denim):
    data = convert(denim, name="denim_test")
    assert data["areal_density_g_per_cm2"] == pytest.approx(0.0324)
    with pytest.warns(KESFitWarning, match="bending.warp"):  # ARCSim's denim softens past α = 0.15 1/cm
        mat = load_material(data)
    assert mat.name == "denim_test"
    # denim's v axis is the stiffer: it is the warp, and the converted warp samples are v's tension
    warp = data["stretch"]["warp"]
    eps = np.array(warp["strain_percent"]) / 100.0
    assert np.allclose(warp["stress_gf_per_cm"], denim.uniaxial_tension(eps, 90.0) * 1e3 / GF, rtol=1e-5)
    bend = data["bending"]["weft"]  # the u axis
    assert np.allclose(bend["moment_gf_cm_per_cm"], denim.bending_moment(CURVATURE_PER_CM, 0) * 1e5 / GF,
                       rtol=1e-5)
    # the fitted stretch polynomial reproduces the converted samples within 1 % of their range
    fitted = mat.stretch.warp(np.array(warp["strain_percent"]))
    assert np.max(np.abs(fitted - warp["stress_gf_per_cm"])) < 0.01 * max(warp["stress_gf_per_cm"])


def test_warp_axis_can_be_named(denim):
    u_warp = convert(denim, warp="u")
    v_warp = convert(denim, warp="v")
    assert u_warp["stretch"]["warp"] == v_warp["stretch"]["weft"]
    with pytest.raises(MaterialError, match="warp"):
        convert(denim, warp="x")


@pytest.mark.parametrize("data, field", [
    ({"stretching": [[1, 0, 1, 1]] * 6, "bending": [[1e-6] * 5] * 3}, "density"),
    ({"density": -1, "stretching": [[1, 0, 1, 1]] * 6, "bending": [[1e-6] * 5] * 3}, "density"),
    ({"density": 0.1, "bending": [[1e-6] * 5] * 3}, "stretching"),
    ({"density": 0.1, "stretching": [[1, 0, 1, 1]] * 5, "bending": [[1e-6] * 5] * 3}, "stretching"),
    ({"density": 0.1, "stretching": [[1, 0, 1, 1]] * 5 + [[1, 0, 1]], "bending": [[1e-6] * 5] * 3},
     "stretching[5]"),
    ({"density": 0.1, "stretching": [[1, 0, 1, 1]] * 6, "bending": [[1e-6] * 5, [1e-6] * 5, [1e-6, "x", 1, 1, 1]]},
     "bending[2][1]"),
    ({"density": 0.1, "stretching": [[1, 0, 1, float("nan")]] * 6, "bending": [[1e-6] * 5] * 3}, "stretching[0][3]"),
    ({"density": 0.1, "stretching": [[0, 0, 0, 1]] * 6, "bending": [[1e-6] * 5] * 3}, "stretching"),
    ([1, 2], "<arcsim>"),
])
def test_malformed_files_get_typed_errors_naming_the_key(data, field):
    with pytest.raises(MaterialError) as err:
        parse_arcsim(data)
    assert err.value.field == field


def test_reads_comment_lines_and_names_the_file_in_errors(tmp_path):
    good = tmp_path / "commented.json"
    good.write_text("// a comment, as ARCSim's own files have\n" + DENIM.read_text())
    assert read_arcsim(good).density == 0.324
    bad = tmp_path / "bad.json"
    bad.write_text('{"density": 0.1, "stretching": [[1, 0, 1, 1]]}')
    with pytest.raises(MaterialError, match="bad.json") as err:
        read_arcsim(bad)
    assert err.value.field == "stretching"
    broken = tmp_path / "broken.json"
    broken.write_text('{"density": 0.1,')
    with pytest.raises(MaterialError, match="not valid JSON"):
        read_arcsim(broken)


def test_import_material_command_writes_a_loadable_material_with_its_provenance(tmp_path, capsys):
    from cloth_gym.cli import main

    assert main(["import-material", str(DENIM), "--name", "denim_cli", "--out", str(tmp_path),
                 "--terms", "research only"]) == 0
    assert "stretch.warp" in capsys.readouterr().out
    path = tmp_path / "denim_cli.yaml"
    mat = load_material(path)
    assert mat.name == "denim_cli" and mat.areal_density == pytest.approx(0.0324)
    prov = yaml.safe_load(path.read_text())["provenance"]
    assert prov["terms_of_use"] == "research only"
    assert prov["source_sha256"] == hashlib.sha256(DENIM.read_bytes()).hexdigest()
    assert prov["samples"] == {k: v for k, v in convert(read_arcsim(DENIM)).items() if k in ("stretch", "bending", "shear")}
    assert (tmp_path / "denim_cli_fit.png").stat().st_size > 0
    assert main(["import-material", str(DATA / "missing.json"), "--out", str(tmp_path)]) == 2


@pytest.mark.parametrize("source, shipped", [(DENIM, "wang_11oz_black_denim"), (INTERLOCK, "wang_gray_interlock")])
def test_shipped_measured_fabrics_are_their_sources_converted(source, shipped):
    from cloth_gym.materials import materials_dir

    data = yaml.safe_load((materials_dir() / f"{shipped}.yaml").read_text())
    prov = data["provenance"]
    assert prov["source_sha256"] == hashlib.sha256(source.read_bytes()).hexdigest()
    assert prov["samples"] == {k: v for k, v in convert(read_arcsim(source)).items()
                               if k in ("stretch", "bending", "shear")}
    assert "LICENSE-wang2011.txt" in prov["terms_of_use"]
    mat = load_material(shipped)
    assert mat.areal_density == pytest.approx(read_arcsim(source).density * 0.1)
    # each fit's reported error is the fitted polynomial's against the samples
    for kind in ("stretch", "bending", "shear"):
        for d in ("warp", "weft"):
            spec = prov["samples"][kind][d]
            x, y = (np.array(v) for k, v in spec.items() if k != "terms")
            worst = np.max(np.abs(getattr(getattr(mat, kind), d)(x) - y)) / np.max(np.abs(y))
            assert 100.0 * worst == pytest.approx(prov["fit"][f"{kind}.{d}"]["max_error_percent_of_max"], abs=0.01)


def test_every_shipped_measured_fabric_loads_and_records_its_source():
    from cloth_gym.materials import available_materials, materials_dir

    names = [n for n in available_materials() if n.startswith("wang_")]
    assert len(names) == 10
    for name in names:
        prov = yaml.safe_load((materials_dir() / f"{name}.yaml").read_text())["provenance"]
        assert set(prov) >= {"source_file", "source_sha256", "terms_of_use", "conversion", "samples", "fit"}
        mat = load_material(name)
        assert 0.005 < mat.areal_density < 0.05  # g/cm²: 50–500 g/m², the range of apparel fabrics
    assert (materials_dir() / "LICENSE-wang2011.txt").read_text().startswith("Copyright (c)2013 The Regents")
