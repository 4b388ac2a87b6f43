"""Material YAML files that never lie: a key given twice or a coefficient left out is a
MaterialError naming the key path and the file; the optional keys' defaults are the documented ones."""

from __future__ import annotations

from pathlib import Path

import pytest

from cloth_gym import MaterialError, load_material
from cloth_gym.materials import Material, materials_dir

COTTON = (materials_dir() / "thick_cotton.yaml").read_text()


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "fabric.yaml"
    path.write_text(text)
    return path


def test_the_shipped_file_loads_from_a_copy(tmp_path):
    assert load_material(_write(tmp_path, COTTON)) == load_material("thick_cotton")


@pytest.mark.parametrize("old, new, field", [
    ("friction: 0.3", "friction: 0.3\nfriction: 0.9", "friction"),
    ("  warp: {c1: 36.77, c2: 38.38}", "  warp: {c1: 36.77, c2: 38.38, c1: 1.0}", "stretch.warp.c1"),
    ("shear:\n", "shear:\n  weft: {c0: 1.0, c1: 0.46, c2: 0.62}\n", "shear.weft"),
])
def test_a_duplicate_key_names_its_path_the_file_and_both_lines(tmp_path, old, new, field):
    assert old in COTTON
    path = _write(tmp_path, COTTON.replace(old, new, 1))
    with pytest.raises(MaterialError) as info:
        load_material(path)
    assert info.value.field == field
    assert str(path) in str(info.value) and "duplicate key" in str(info.value) and "first given at line" in str(info.value)


@pytest.mark.parametrize("old, new, field", [
    ("  weft: {c0: 1.0, c1: 0.46, c2: 0.62}", "  weft: {c1: 0.46, c2: 0.62}", "shear.weft.c0"),
    ("  warp: {c1: 36.77, c2: 38.38}", "  warp: {c1: 36.77}", "stretch.warp.c2"),
    ("  warp: {c0: 0.097, c1: 0.082, c2: 0.0008}", "  warp: {c0: 0.097, c2: 0.0008}", "bending.warp.c1"),
])
def test_a_missing_coefficient_names_its_path_and_the_file(tmp_path, old, new, field):
    assert old in COTTON
    path = _write(tmp_path, COTTON.replace(old, new, 1))
    with pytest.raises(MaterialError) as info:
        load_material(path)
    assert info.value.field == field and info.value.file == str(path)
    assert "missing coefficient" in str(info.value)


def test_a_missing_coefficient_in_a_mapping_is_refused_too():
    data = load_material("thick_cotton").to_dict()
    del data["shear"]["weft"]["c0"]
    with pytest.raises(MaterialError, match="shear.weft.c0: missing coefficient"):
        Material.from_dict(data)


def test_the_optional_keys_take_the_documented_defaults(tmp_path):
    keep = [line for line in COTTON.splitlines() if not line.split(":")[0] in
            ("compression_factor", "restitution", "air_drag", "damping_per_s", "strain_damping_s", "friction")]
    m = load_material(_write(tmp_path, "\n".join(keep) + "\n"))
    assert (m.compression_factor, m.restitution, m.air_drag, m.damping, m.strain_damping, m.friction) == \
        (0.1, 0.2, 0.3e-4, 0.5, 2.0e-5, 0.3)
    doc = (Path(__file__).resolve().parents[1] / "docs" / "materials.md").read_text()
    for row in ("| `compression_factor` | 0.1 |", "| `restitution` | 0.2 |", "| `air_drag` | 0.3e-4 g/cm³ |",
                "| `damping_per_s` | 0.5 /s |", "| `strain_damping_s` | 2.0e-5 s |", "| `friction` | 0.3 |"):
        assert row in doc
