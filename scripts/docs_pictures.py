#!/usr/bin/env python
"""The docs' pictures: each task's scripted expert as a short GIF, and the colour legend on each env page.

    python scripts/docs_pictures.py            # about a CPU minute once the kernels are compiled

Writes ``docs/img/<Env>-vN.gif``: one episode of the scripted expert on each task's current id
(``cloth_gym.envs.CURRENT_IDS``; CornerLiftGoal-v2 shares CornerLift-v2's scene and expert, so it
has no GIF of its own), from the episode seed ``make demo`` shows (``scripts/demo.py``,
``DEMO_SEEDS``), at the envs' ``render()`` size of 320 × 240, at most :data:`MAX_FRAMES` frames
(every k-th control step), played in real time. The docs home (``docs/hooks/site.py``) and each
env page open with them. Rewrites the legend of ``cloth_gym.envs.palette`` between the
``<!-- legend -->`` and ``<!-- /legend -->`` lines of each env page (``docs/envs/*.md``).
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from demo import DEMO_SEEDS  # noqa: E402

MAX_FRAMES = 80
#: the env page of each task (the ids whose GIF heads it)
PAGES = {"CornerLift": "corner_lift.md", "DrapeOntoTable": "drape_onto_table.md", "RibbonDrop": "ribbon_drop.md"}
LEGEND = re.compile(r"(<!-- legend -->\n)(?:.*?\n)?(<!-- /legend -->)", re.S)


def expert_gif(env_id: str, out: Path) -> dict:
    """One expert episode of ``env_id`` as a GIF at ``out``: its frame count, size and the episode's success."""
    import gymnasium as gym

    from cloth_gym.agents.experts import make_expert
    from cloth_gym.render import save_gif

    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=DEMO_SEEDS.get(env_id, 0))
    expert = make_expert(env)
    stride = math.ceil((env.spec.max_episode_steps + 1) / MAX_FRAMES)
    frames, step, done, info = [env.render()], 0, False, {}
    while not done:
        _, _, terminated, truncated, info = env.step(expert.act())
        step += 1
        done = terminated or truncated
        if step % stride == 0 or done:
            frames.append(env.render())
    save_gif(out, frames, fps=env.metadata["render_fps"] / stride)
    return {"frames": len(frames), "bytes": out.stat().st_size, "success": bool(info.get("is_success"))}


def write_legends(pages: list[Path]) -> None:
    """Put the palette's legend table between the legend markers of each page."""
    from cloth_gym.envs.palette import legend_markdown

    for page in pages:
        text = page.read_text(encoding="utf-8")
        if not LEGEND.search(text):
            raise SystemExit(f"{page}: no '<!-- legend -->' ... '<!-- /legend -->' lines")
        text = LEGEND.sub(lambda m: m.group(1) + legend_markdown() + "\n" + m.group(2), text)
        page.write_text(text, encoding="utf-8")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--docs", default=str(ROOT / "docs"), help="the docs folder (img/ and envs/ under it)")
    ap.add_argument("--no-gifs", action="store_true", help="only rewrite the legends")
    args = ap.parse_args(argv)
    docs = Path(args.docs)
    from cloth_gym.envs import CURRENT_IDS

    write_legends([docs / "envs" / page for page in PAGES.values()])
    if args.no_gifs:
        return
    for env_id in CURRENT_IDS:
        name = env_id.split("/")[-1]
        if name.split("-")[0] not in PAGES:  # a variant that shares its task's scene (CornerLiftGoal)
            continue
        s = expert_gif(env_id, docs / "img" / f"{name}.gif")
        print(f"{env_id}: {s['frames']} frames, {s['bytes'] / 1e6:.2f} MB, expert success {s['success']}")


if __name__ == "__main__":
    main()
