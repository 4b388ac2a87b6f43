"""Where a results file comes from: the git commit, uncommitted changes, the machine and the command.

The results-writing scripts (``scripts/benchmark.py``, ``scripts/soak.py``, ...) put
:func:`stamp` into the JSON they write, and :func:`stamp_line` gives the one Markdown line a
docs page shows above a table, such as::

    Regenerate with `python scripts/soak.py --steps 100000 --docs` · commit `1aebd49` · Linux x86_64, 2 CPUs, Python 3.11.7

The commit is that of the git checkout this package is imported from; from an installed wheel (no
checkout around the package) it is ``"unknown"``. Git is asked with a timeout and never makes
:func:`stamp` raise: no git, a broken repository or a slow file system give ``"unknown"`` and no
changes.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
from pathlib import Path

__all__ = ["REPO_ROOT", "TRACKED_DIRS", "machine", "stamp", "stamp_line"]

#: The directory holding the ``cloth_gym`` package: a git checkout's root when run from one.
REPO_ROOT = Path(__file__).resolve().parents[2]
#: The directories whose uncommitted changes can change a result (code, configs, the scripts).
TRACKED_DIRS = ("cloth_gym", "agents", "configs", "scripts")
GIT_TIMEOUT_S = 10.0


def _git(root: Path, *args: str) -> str | None:
    """``git args`` run in ``root``: its stdout, or None if git is missing, fails or times out."""
    try:
        out = subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, timeout=GIT_TIMEOUT_S,
                             env={**os.environ, "GIT_OPTIONAL_LOCKS": "0"})  # status takes no index lock
    except (OSError, subprocess.SubprocessError, ValueError):
        return None
    return out.stdout if out.returncode == 0 else None


def _checkout(root: Path) -> bool:
    """Whether ``root`` is the top of a git work tree (not merely a folder inside some other one,
    such as a virtual environment's site-packages inside a checkout)."""
    top = _git(root, "rev-parse", "--show-toplevel")
    if not top or not top.strip():
        return False
    try:
        return Path(top.strip()).resolve() == Path(root).resolve()
    except OSError:
        return False


def _changes(root: Path) -> list[str]:
    """Files under :data:`TRACKED_DIRS` that differ from HEAD: modified, added, deleted, renamed,
    untracked (``git status --porcelain``), as paths relative to the checkout."""
    out = _git(root, "status", "--porcelain", "-z", "--untracked-files=all", "--", *TRACKED_DIRS)
    if not out:
        return []
    entries = out.split("\0")
    files: list[str] = []
    i = 0
    while i < len(entries):
        entry = entries[i]
        i += 1
        if len(entry) < 4:
            continue
        code, path = entry[:2], entry[3:]
        if "R" in code or "C" in code:
            i += 1  # a rename or copy: the next entry is the original path
        files.append(path)
    return sorted(dict.fromkeys(files))


def cpu_model() -> str | None:
    """The CPU's model name from ``/proc/cpuinfo`` (None where it names none, as on ARM or macOS):
    the project's timings come from more than one kind of machine, so each names the CPU it ran on."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return None
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "model name" and value.strip():
            return value.strip()
    return None


def machine() -> dict:
    """The machine a result was measured on: platform, processor and its model, logical CPUs, Python."""
    return {"system": platform.system(), "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(), "cpu_model": cpu_model(),
            "cpus": os.cpu_count(), "python": platform.python_version()}


def stamp(command: str) -> dict:
    """Provenance of a result produced now by ``command``.

    ``{"commit": short hash of HEAD or "unknown", "uncommitted_changes": [paths], "machine": {...},
    "command": command}``. ``uncommitted_changes`` lists the files under ``cloth_gym/``,
    ``agents/``, ``configs/`` and ``scripts/`` that differ from that commit (empty outside a
    checkout), so a stamp says when the commit alone does not reproduce the numbers.
    """
    root = Path(REPO_ROOT)
    commit, changes = "unknown", []
    if _checkout(root):
        head = _git(root, "rev-parse", "--short", "HEAD")
        if head and head.strip():
            commit = head.strip()
            changes = _changes(root)
    return {"commit": commit, "uncommitted_changes": changes, "machine": machine(), "command": command}


def load_average() -> list[float] | None:
    """The machine's 1, 5 and 15 minute load averages (None where the platform has none): a timing
    result records them at its start and end, to say how busy the machine was."""
    return list(os.getloadavg()) if hasattr(os, "getloadavg") else None


def write_results(results: dict, path: Path, docs_path: Path | None = None) -> None:
    """Write a stamped timing result as JSON to ``path`` (its folder created), after recording the load
    average at its end in ``results["machine"]``; the same text to ``docs_path`` when given."""
    results["machine"]["load_average_at_end"] = load_average()
    text = json.dumps(results, indent=2)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    if docs_path is not None:
        docs_path.write_text(text)
    print(f"wrote {path}")


def _machine_text(m) -> str:
    if isinstance(m, str):
        return m
    if not isinstance(m, dict):
        return ""
    head = " ".join(str(m[k]) for k in ("system", "processor") if m.get(k))
    cpus = m.get("cpus", m.get("cpu_count"))
    parts = [head] if head else []
    if cpus:
        parts.append(f"{cpus} CPUs")
    if m.get("python"):
        parts.append(f"Python {m['python']}")
    return ", ".join(parts)


def stamp_line(stamp: dict) -> str:
    """One Markdown line for a docs page: the command that regenerates the result, the commit it was
    run at (and how many tracked files differed from it) and the machine."""
    parts = [f"Regenerate with `{stamp.get('command', '')}`"]
    commit = stamp.get("commit") or "unknown"
    changed = stamp.get("uncommitted_changes") or []
    parts.append(f"commit `{commit}`" + (f" (with uncommitted changes to {len(changed)} file"
                                          f"{'s' if len(changed) != 1 else ''})" if changed else ""))
    where = _machine_text(stamp.get("machine"))
    if where:
        parts.append(where)
    return " · ".join(parts)
