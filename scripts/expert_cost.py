"""What one env's scripted expert costs per episode on one core: CPU seconds, env steps, success, return
and the largest edge strain, episode by episode over a range of seeds.

The per-core figure of an env: whole episodes, reset to ``seed`` and driven by
``cloth_gym.agents.experts`` until they end, in one process on one thread (numba's thread count 1).
The first step of the first episode (compiling or loading the kernels) is not timed. Prints a
table and writes ``outputs/expert_cost/<env>.json`` (``--out``); each episode's return and largest
strain say whether two versions of the code computed the same episodes.

To compare two commits side by side, copy this script into a worktree of the other one and run
both at once, each from its own checkout:

    .venv/bin/python scripts/expert_cost.py --env cloth_gym/DrapeOntoTable-v2 --seeds 100 120
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import gymnasium as gym  # noqa: E402

import cloth_gym  # noqa: E402,F401  (registers the ids)
from cloth_gym.agents.experts import make_expert  # noqa: E402
from cloth_gym.reports.options import command_line  # noqa: E402
from cloth_gym.reports.provenance import stamp, write_results  # noqa: E402
from cloth_gym.sim.diagnostics import edge_strain  # noqa: E402


def episode(env, seed: int) -> dict:
    """One expert episode from ``env.reset(seed=seed)``: its CPU seconds (the steps only), env steps,
    success, return and largest edge strain (%, over every step's end state)."""
    env.reset(seed=seed)
    expert = make_expert(env)
    physics = env.unwrapped.physics
    steps, ret, strain, cpu = 0, 0.0, 0.0, 0.0
    while True:
        action = expert.act()
        c = time.process_time()
        _, reward, term, trunc, info = env.step(action)
        cpu += time.process_time() - c
        steps += 1
        ret += float(reward)
        strain = max(strain, float(edge_strain(physics.model, physics.state).max()))
        if term or trunc:
            return {"seed": seed, "cpu_s": cpu, "env_steps": steps, "success": bool(info["is_success"]),
                    "diverged": bool(info["diverged"]), "return": ret, "max_strain_percent": strain}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env", default="cloth_gym/DrapeOntoTable-v2")
    ap.add_argument("--seeds", type=int, nargs=2, default=[100, 120], metavar=("FIRST", "STOP"),
                    help="seeds FIRST, ..., STOP - 1")
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "expert_cost")
    args = ap.parse_args(argv)

    env = gym.make(args.env)
    env.reset(seed=args.seeds[0])
    env.step(env.action_space.sample())  # kernels compiled or loaded, not timed
    rows = [episode(env, seed) for seed in range(*args.seeds)]
    env.close()
    cpu = sum(r["cpu_s"] for r in rows)
    steps = sum(r["env_steps"] for r in rows)
    print("| seed | env steps | CPU s | success | return | max strain (%) |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['seed']} | {r['env_steps']} | {r['cpu_s']:.2f} | {r['success']} | {r['return']:.6f} "
              f"| {r['max_strain_percent']:.4f} |")
    print(f"{args.env}: {steps} env steps in {cpu:.2f} CPU s ({steps / cpu:.2f} env steps per CPU s), "
          f"{sum(r['success'] for r in rows)} of {len(rows)} succeeded")
    results = {**stamp(command_line("python scripts/expert_cost.py", sys.argv[1:] if argv is None else argv)),
               "env": args.env, "cpu_s": cpu, "env_steps": steps, "episodes": rows}
    write_results(results, args.out / (args.env.replace("/", "_") + ".json"))
    return results


if __name__ == "__main__":
    main()
