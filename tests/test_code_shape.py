"""The code stays easy to change: size limits on modules, functions and docstrings in cloth_gym/
and agents/, and the implicit solver independent of the explicit integrator (docs/layout.md).
Reads the source only (well under a second)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted(p for d in ("cloth_gym", "agents") for p in (ROOT / d).rglob("*.py"))
MAX_MODULE_LINES, MAX_FUNCTION_LINES, MAX_DOCSTRING_LINES = 600, 80, 60


def _too_long(path: Path) -> list[str]:
    src = path.read_text()
    out = []
    if src.count("\n") > MAX_MODULE_LINES:
        out.append(f"module {src.count(chr(10))} lines")
    tree = ast.parse(src)
    nodes = [tree, *(n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)))]
    for node in nodes:
        name = getattr(node, "name", "<module>")
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and \
                node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES:
            out.append(f"function {name} {node.end_lineno - node.lineno + 1} lines")
        doc = ast.get_docstring(node, clean=False)
        if doc and doc.count("\n") + 1 > MAX_DOCSTRING_LINES:
            out.append(f"docstring of {name} {doc.count(chr(10)) + 1} lines")
    return out


def test_the_sources_are_found():
    assert len(SOURCES) > 50 and any(p.name == "step.py" for p in SOURCES)


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_module_function_or_docstring_over_its_limit(path):
    assert not _too_long(path), f"{path.relative_to(ROOT)}: {_too_long(path)}"


def test_the_limits_can_fail(tmp_path):
    long = tmp_path / "long.py"
    long.write_text("def f():\n" + "    x = 1\n" * MAX_FUNCTION_LINES)
    assert _too_long(long) == [f"function f {MAX_FUNCTION_LINES + 1} lines"]


def test_the_implicit_solver_imports_nothing_from_the_explicit_integrator():
    for path in (ROOT / "cloth_gym" / "sim" / "implicit").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                assert "integrators" not in (node.module or ""), f"{path.name} imports {node.module}"


def test_every_package_is_in_the_distribution():
    """Each folder of cloth_gym/ with an __init__.py is listed in pyproject.toml's packages, so the
    wheel ships it (a package left out imports in the checkout and fails once installed)."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "cloth_gym").rglob("__init__.py")}
    assert found <= listed, f"not in pyproject.toml's packages: {sorted(found - listed)}"
