#!/usr/bin/env python
"""The env throughput figures of the README and the environments page, from their JSON.

    python scripts/docs_figures.py            # rewrite the marked tables in place
    python scripts/docs_figures.py --check    # exit 1, naming each, if a table differs from its JSON

A table between ``<!-- figures:env_throughput -->`` and ``<!-- /figures -->`` has an env id in
backticks in its first cell and env steps per CPU second (random actions / scripted expert, one
env on one core) in its last; this script writes that last cell of every row from
``docs/data/env_throughput.json`` (CornerLift-v2 from ``docs/data/env_throughput_cornerlift_v2.json``,
with CornerLift-v1 of the same run), and after the table a line naming each JSON with the command
and commit recorded in it. The JSON come from ``python scripts/env_throughput.py ... --docs``.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "docs" / "data"
PAGES = [ROOT / "README.md", ROOT / "docs" / "envs" / "index.md"]
BEGIN, END = "<!-- figures:env_throughput -->", "<!-- /figures -->"
#: the JSON each id's figures come from (default: env_throughput.json)
SOURCES = {"cloth_gym/CornerLift-v2": "env_throughput_cornerlift_v2.json",
           "cloth_gym/DrapeOntoTable-v2": "env_throughput_drape_v2.json",
           "cloth_gym/RibbonDrop-v2": "env_throughput_ribbondrop_v2.json",
           "cloth_gym/RibbonDrop-v3": "env_throughput_ribbondrop_v3.json",
           "cloth_gym/RibbonDrop-v4": "env_throughput_ribbondrop_v4.json"}
MAIN = "env_throughput.json"


def rate(x: float) -> str:
    """Env steps per second as the pages print them: whole numbers with thousands separators
    from 100 up, one decimal below."""
    return f"{x:,.0f}" if x >= 100 else f"{x:.1f}"


def load(name: str) -> dict:
    return json.loads((DATA / name).read_text(encoding="utf-8"))


def random_expert(doc: dict, env_id: str) -> tuple[float, float]:
    env = doc["envs"][env_id]
    return env["single"]["env_steps_per_cpu_s"], env["single_expert"]["env_steps_per_cpu_s"]


def cell(env_id: str) -> str:
    """The last cell of ``env_id``'s row: random / expert env steps per CPU second."""
    name = SOURCES.get(env_id, MAIN)
    doc = load(name)
    r, e = random_expert(doc, env_id)
    text = f"{rate(r)} / {rate(e)}"
    if name != MAIN:  # a side-by-side run: the older version measured alongside
        others = [i for i in doc["envs"] if i != env_id]
        for other in others:
            r2, e2 = random_expert(doc, other)
            text += f" ({other.split('/')[-1].split('-')[-1]} in the same run: {rate(r2)} / {rate(e2)})"
    return text


def stamp() -> str:
    """The line under each table: where its figures come from."""
    parts = []
    for name in [MAIN, *sorted(set(SOURCES.values()))]:
        doc = load(name)
        which = "" if name == MAIN else " (" + ", ".join(i for i, n in SOURCES.items() if n == name) + ")"
        parts.append(f"`docs/data/{name}`{which}: `{doc['command']}` at commit `{doc['commit']}`")
    return ("Env steps per CPU second, random actions / scripted expert, one env on one core; from "
            + "; ".join(parts) + " (`python scripts/docs_figures.py` writes this table).")


def render(block: str) -> str:
    """The marked block with every row's last cell and the stamp line from the JSON."""
    out = []
    for line in block.splitlines():
        if line.startswith("Env steps per CPU second, random actions / scripted expert"):
            continue
        m = re.match(r"\| \[?`(cloth_gym/[A-Za-z]+-v\d+)`", line)
        if m:
            cells = line.rstrip().rstrip("|").split(" | ")
            cells[-1] = cell(m.group(1))
            line = " | ".join(cells) + " |"
        out.append(line)
    while out and not out[-1].strip():
        out.pop()
    while out and not out[0].strip():
        out.pop(0)
    # blank lines around the table: an HTML comment next to it would swallow it into an HTML block
    return "\n" + "\n".join(out) + "\n\n" + stamp() + "\n\n"


def update(text: str) -> str:
    pattern = re.compile(re.escape(BEGIN) + r"\n(.*?)" + re.escape(END), re.S)
    if not pattern.search(text):
        raise ValueError(f"no {BEGIN} ... {END} block")
    return pattern.sub(lambda m: BEGIN + "\n" + render(m.group(1)) + END, text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="change nothing; exit 1 if a page differs from its JSON")
    args = ap.parse_args(argv)
    stale = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        new = update(text)
        if new != text:
            stale.append(page.relative_to(ROOT))
            if not args.check:
                page.write_text(new, encoding="utf-8")
    verb = "differs from its JSON" if args.check else "rewritten"
    for page in stale:
        print(f"{page}: {verb}")
    return 1 if (args.check and stale) else 0


if __name__ == "__main__":
    sys.exit(main())
