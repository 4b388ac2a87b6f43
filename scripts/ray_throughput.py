#!/usr/bin/env python
"""Env steps per second of N envs in Ray actors (``RayVecEnv``) against the actor count.

For each actor count A in ``--actors`` and thread count T in ``--threads-per-actor`` (default 1):
the N envs of ``--env`` split A ways (N / A per actor, T physics threads each), driven through
SB3's ``VecEnv`` interface with seeded random actions (the same actions for every A), with
sleeping off (``sleep_speed=0``: a cloth left lying would otherwise cost nothing). Each (A, T) is
timed ``--rounds`` times, alternated, after a warm-up (actor start, kernel cache load, first
steps). Reports the median env steps per wall second, CPU seconds (the driver's and every actor
process's), each (A, T)'s speed-up over the first, and the actors' imbalance: the busiest actor's
CPU seconds over the mean (1: the actors did equal work; a vector step waits for the slowest). A
local Ray uses this machine's cores; ``--address`` a cluster.

    python scripts/ray_throughput.py --env cloth_gym/CornerLift-v2 --n-envs 4 --actors 1 2 --steps 100 \\
        --rounds 3 --out docs/data/ray_throughput.json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cloth_gym.reports.options import command_line  # noqa: E402
from cloth_gym.reports.provenance import stamp  # noqa: E402


def measure(env_id: str, n_envs: int, actors: int, steps: int, seed: int, threads: int = 1) -> dict:
    """One round: the envs in ``actors`` actors of ``threads`` threads each, on the Ray already
    started, timed over ``steps``."""
    from stable_baselines3.common.env_util import make_vec_env

    from cloth_gym.agents.ray_vec_env import RayVecEnv

    venv = make_vec_env(env_id, n_envs=n_envs, seed=seed, vec_env_cls=RayVecEnv,
                        vec_env_kwargs={"envs_per_actor": -(-n_envs // actors), "threads_per_actor": threads},
                        env_kwargs={"observation_mode": "keypoints", "sleep_speed": 0.0})
    try:
        rng = np.random.default_rng(seed)
        venv.reset()
        for _ in range(5):  # warm-up: kernels loaded, first solves done
            venv.step(rng.uniform(-1, 1, (n_envs, venv.action_space.shape[0])).astype(np.float32))
        actions = np.random.default_rng(seed + 1).uniform(-1, 1, (steps, n_envs, venv.action_space.shape[0]))
        cpu0, own0, t0 = venv.actor_cpu_seconds(), time.process_time(), time.perf_counter()
        for a in actions.astype(np.float32):
            venv.step(a)
        wall = time.perf_counter() - t0
        driver = time.process_time() - own0
        per_actor = [c1 - c0 for c0, c1 in zip(cpu0, venv.actor_cpu_seconds())]
        cpu = sum(per_actor) + driver
    finally:
        venv.close()
    return {"actors": actors, "threads_per_actor": threads, "envs_per_actor": -(-n_envs // actors),
            "env_steps": steps * n_envs, "wall_s": wall, "cpu_s": cpu, "driver_cpu_s": driver,
            "actor_cpu_s": per_actor, "imbalance": max(per_actor) / statistics.mean(per_actor),
            "steps_per_wall_s": steps * n_envs / wall, "steps_per_cpu_s": steps * n_envs / cpu}


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env", default="cloth_gym/CornerLift-v2")
    ap.add_argument("--n-envs", type=int, default=4)
    ap.add_argument("--actors", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--threads-per-actor", type=int, nargs="+", default=[1],
                    help="physics threads per actor (each value measured with each actor count)")
    ap.add_argument("--steps", type=int, default=100, help="vector steps per round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--address", default=None, help="a Ray cluster (default: a local Ray on this machine)")
    ap.add_argument("--out", default="outputs/ray_throughput.json")
    args = ap.parse_args(argv)

    import ray

    import cloth_gym  # noqa: F401

    configs = [(a, t) for a in args.actors for t in args.threads_per_actor]
    need = max(a * t for a, t in configs)
    # as RayVecEnv starts a local Ray: this machine's cores, oversubscribed where a count needs more
    local = {} if args.address else {"num_cpus": max(os.cpu_count() or 1, need)}
    ray.init(address=args.address, include_dashboard=False, log_to_driver=False, **local)
    rows = []
    try:
        for r in range(args.rounds):
            for a, t in configs:
                row = {"round": r, **measure(args.env, args.n_envs, a, args.steps, args.seed, t)}
                rows.append(row)
                print(f"round {r} actors {a} x {t} threads: {row['steps_per_wall_s']:.1f} env steps/wall s, "
                      f"{row['steps_per_cpu_s']:.1f} /CPU s, actors' imbalance {row['imbalance']:.2f}", flush=True)
        cpus = ray.cluster_resources().get("CPU")
    finally:
        ray.shutdown()
    summary = []
    for a, t in configs:
        mine = [x for x in rows if x["actors"] == a and x["threads_per_actor"] == t]
        summary.append({"actors": a, "threads_per_actor": t, "envs_per_actor": mine[0]["envs_per_actor"],
                        "steps_per_wall_s": statistics.median(x["steps_per_wall_s"] for x in mine),
                        "steps_per_cpu_s": statistics.median(x["steps_per_cpu_s"] for x in mine),
                        "imbalance": statistics.median(x["imbalance"] for x in mine)})
    base = summary[0]["steps_per_wall_s"]
    for s in summary:
        s["speedup"] = s["steps_per_wall_s"] / base
    doc = {"stamp": stamp(command_line("python scripts/ray_throughput.py", argv)), "env_id": args.env,
           "n_envs": args.n_envs, "ray_cpus": cpus, "rows": rows, "summary": summary}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=2) + "\n")
    print("| actors × threads | envs per actor | env steps / wall s | env steps / CPU s | actors' imbalance | speed-up |\n"
          "|---|---|---|---|---|---|")
    for s in summary:
        print(f"| {s['actors']} × {s['threads_per_actor']} | {s['envs_per_actor']} | {s['steps_per_wall_s']:.1f} | "
              f"{s['steps_per_cpu_s']:.1f} | {s['imbalance']:.2f} | {s['speedup']:.2f}× |")
    return doc


if __name__ == "__main__":
    main()
