"""cloth_gym.reports.provenance: the stamp a results file carries, and its line on a docs page."""

import os
import platform
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from cloth_gym.reports import provenance

ROOT = Path(__file__).resolve().parent.parent
IN_CHECKOUT = shutil.which("git") is not None and subprocess.run(
    ["git", "rev-parse", "--show-toplevel"], cwd=ROOT, capture_output=True, text=True).stdout.strip() == str(ROOT)


@pytest.mark.skipif(not IN_CHECKOUT, reason="needs a git checkout of the repository")
def test_stamp_in_the_checkout_names_head_and_the_changed_files():
    s = provenance.stamp("python scripts/x.py --docs")
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()
    assert s["commit"] == head
    assert s["command"] == "python scripts/x.py --docs"
    porcelain = subprocess.run(["git", "status", "--porcelain", "--untracked-files=all", "--", *provenance.TRACKED_DIRS],
                               cwd=ROOT, capture_output=True, text=True, check=True).stdout.splitlines()
    assert set(s["uncommitted_changes"]) == {line[3:].split(" -> ")[-1].strip('"') for line in porcelain}
    assert all(Path(p).parts[0] in provenance.TRACKED_DIRS for p in s["uncommitted_changes"])
    m = s["machine"]
    assert m["cpus"] == os.cpu_count() and m["python"] == platform.python_version()
    assert m["processor"] and m["platform"] == platform.platform()
    info = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    if "model name" in info:  # x86 Linux: the model the kernel reports, e.g. "AMD EPYC ..." (ARM has none)
        assert m["cpu_model"] and f": {m['cpu_model']}\n" in info
    else:
        assert m["cpu_model"] is None


@pytest.mark.skipif(not IN_CHECKOUT, reason="needs a git checkout of the repository")
def test_a_modified_tracked_file_is_listed(tmp_path, monkeypatch):
    repo = tmp_path / "repo"
    (repo / "cloth_gym").mkdir(parents=True)
    (repo / "docs").mkdir()
    (repo / "cloth_gym" / "a.py").write_text("x = 1\n")
    (repo / "docs" / "page.md").write_text("# page\n")

    def git(*args):
        subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=repo, check=True,
                       capture_output=True)

    git("init", "-q")
    git("add", ".")
    git("commit", "-q", "-m", "one")
    monkeypatch.setattr(provenance, "REPO_ROOT", repo)
    assert provenance.stamp("c")["uncommitted_changes"] == []
    (repo / "cloth_gym" / "a.py").write_text("x = 2\n")
    (repo / "cloth_gym" / "new.py").write_text("")
    (repo / "docs" / "page.md").write_text("# changed, but not code\n")
    s = provenance.stamp("c")
    assert s["uncommitted_changes"] == ["cloth_gym/a.py", "cloth_gym/new.py"]
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=repo, capture_output=True, text=True,
                          check=True).stdout.strip()
    assert s["commit"] == head


def test_outside_a_checkout_the_commit_is_unknown(tmp_path, monkeypatch):
    monkeypatch.setattr(provenance, "REPO_ROOT", tmp_path)
    s = provenance.stamp("python scripts/x.py")
    assert s["commit"] == "unknown" and s["uncommitted_changes"] == []
    assert s["command"] == "python scripts/x.py" and s["machine"]["cpus"] == os.cpu_count()


def test_a_folder_inside_some_other_checkout_is_not_one(monkeypatch):
    """An installed package inside a checkout (a venv's site-packages) must not take its commit."""
    if not IN_CHECKOUT:
        pytest.skip("needs a git checkout of the repository")
    monkeypatch.setattr(provenance, "REPO_ROOT", ROOT / "cloth_gym")
    assert provenance.stamp("c")["commit"] == "unknown"


def test_no_git_on_the_path_never_raises(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))  # no git there
    s = provenance.stamp("python scripts/x.py")
    assert s["commit"] == "unknown" and s["uncommitted_changes"] == []


def test_a_hanging_git_times_out(tmp_path, monkeypatch):
    fake = tmp_path / "git"
    fake.write_text("#!/bin/sh\nexec sleep 30\n")
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ.get('PATH', '')}")  # this git first
    monkeypatch.setattr(provenance, "GIT_TIMEOUT_S", 0.2)
    t0 = time.perf_counter()
    s = provenance.stamp("c")
    assert s["commit"] == "unknown" and s["uncommitted_changes"] == []
    assert time.perf_counter() - t0 < 5


def test_stamp_line_has_the_command_commit_and_machine():
    s = {"commit": "abc1234", "uncommitted_changes": [], "command": "python scripts/x.py --docs",
         "machine": {"system": "Linux", "processor": "x86_64", "cpus": 2, "python": "3.11.7", "platform": "p"}}
    line = provenance.stamp_line(s)
    assert line == "Regenerate with `python scripts/x.py --docs` · commit `abc1234` · Linux x86_64, 2 CPUs, Python 3.11.7"
    assert "\n" not in line
    s["uncommitted_changes"] = ["cloth_gym/a.py", "scripts/x.py"]
    assert "commit `abc1234` (with uncommitted changes to 2 files)" in provenance.stamp_line(s)
    # an older stamp whose machine is a string, and a fresh one
    assert provenance.stamp_line({**s, "machine": "x86_64, 2 CPUs"}).endswith("· x86_64, 2 CPUs")
    fresh = provenance.stamp_line(provenance.stamp("python scripts/y.py"))
    assert "`python scripts/y.py`" in fresh and f"{os.cpu_count()} CPUs" in fresh
