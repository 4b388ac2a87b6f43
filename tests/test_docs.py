"""The README and docs/: what a user reads is true, self-contained, and its examples run."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cloth_gym import load_material

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
USER_PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def code_blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"^```{lang}\n(.*?)^```", text, flags=re.S | re.M)


def test_readme_opens_with_the_two_setup_commands_and_stays_short():
    first = code_blocks(README, "sh")[0].splitlines()
    assert [line.split()[:2] for line in first] == [["make", "demo"], ["make", "test"]]
    assert README.index("make demo") < README.index("## ")  # before any section
    assert len(README.splitlines()) <= 150


@pytest.mark.parametrize("page", USER_PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_pages_point_nowhere_outside_the_repository_and_keep_no_diary(page):
    text = page.read_text(encoding="utf-8")
    for bad in ("../shared", "SPEC.md", "SPEC §", "development machine"):
        assert bad not in text, f"{page.name}: {bad!r}"
    assert not re.search(r"\bissue \d+|\(issue", text), page.name
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text), f"{page.name}: a date"


def test_markdown_links_between_pages_resolve():
    for page in USER_PAGES:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text(encoding="utf-8")):
            if "://" in target:
                continue
            assert (page.parent / target).exists(), f"{page.relative_to(ROOT)} links to missing {target}"


def test_the_materials_page_example_loads_and_fits(tmp_path):
    example = code_blocks((ROOT / "docs" / "materials.md").read_text(encoding="utf-8"), "yaml")[0]
    path = tmp_path / "my_fabric.yaml"
    path.write_text(example)
    fabric = load_material(path)
    cotton = load_material("thick_cotton")
    assert fabric.bending == cotton.bending and fabric.stretch.warp == cotton.stretch.warp
    # the weft samples are cotton's weft curve rounded to 0.1 gf/cm: the fit comes back within 1 %
    assert abs(fabric.stretch.weft.c1 / cotton.stretch.weft.c1 - 1) < 0.01
    assert yaml.safe_load(example)["name"] == fabric.name


@pytest.mark.slow
def test_readme_python_examples_run(tmp_path):
    """Every Python block of the README, as a user would paste it (SAC 1,000 steps; a σ = 1 cm drape).
    One torch thread: the suite's workers share the machine's cores."""
    blocks = code_blocks(README, "python")
    assert len(blocks) >= 2
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    for block in blocks:
        run = subprocess.run([sys.executable, "-c", block], capture_output=True, text=True, timeout=1800,
                             cwd=tmp_path, env=env)
        assert run.returncode == 0, block + run.stderr[-3000:]
        assert run.stdout.strip(), block


def _docs_figures():
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_figures", ROOT / "scripts" / "docs_figures.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_throughput_tables_of_the_readme_and_the_envs_page_are_those_of_their_json():
    """The README's and docs/envs/index.md's env steps per CPU second are what
    scripts/docs_figures.py writes from docs/data/env_throughput*.json, stamp line included; a
    figure edited by hand, or a JSON regenerated without rerunning the script, fails here."""
    from cloth_gym.envs import ENV_SPECS

    figures = _docs_figures()
    for page in figures.PAGES:
        text = page.read_text(encoding="utf-8")
        assert text.count(figures.BEGIN) == 1, page.name
        assert figures.update(text) == text, f"{page.name}: run python scripts/docs_figures.py"
        block = text.split(figures.BEGIN)[1].split(figures.END)[0]
        ids = re.findall(r"^\| \[?`(cloth_gym/[A-Za-z]+-v\d+)`", block, flags=re.M)
        assert sorted(ids) == sorted(i for i in ENV_SPECS if "Goal" not in i), (page.name, ids)  # one row per task id
    cornerlift = json.loads((ROOT / "docs" / "data" / "env_throughput.json").read_text())["envs"]["cloth_gym/CornerLift-v0"]
    random_rate = f"{cornerlift['single']['env_steps_per_cpu_s']:,.0f}"
    row = next(line for line in README.splitlines() if line.startswith("| `cloth_gym/CornerLift-v0`"))
    assert row.endswith(f"| {random_rate} / {cornerlift['single_expert']['env_steps_per_cpu_s']:,.0f} |")
    stale = README.replace(row, row.replace(f"| {random_rate} /", "| 4,800 /"))
    assert figures.update(stale) == README  # the script puts the JSON's figure back
