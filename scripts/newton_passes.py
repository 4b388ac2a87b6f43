"""How many of an env's substeps need more than one Newton pass, and what converging them costs.

Each env id's scripted expert runs the same episodes three times: with the env's own implicit
settings, with Newton iterated to ``--newton-tol`` (cm/s, mass-weighted RMS of the nonlinear
residual; at most ``--newton-iters`` passes) and momentum-exact solves, and the same with a line
search on each correction (``line_search=True``). Per id: the share of substeps that took
more than one linear solve, solves per substep, process CPU s per env step side by side (one
process, alternated episode by episode), expert success, largest edge strain.

    python scripts/newton_passes.py --ids cloth_gym/CornerLift-v2 --seeds 100 101 102
    python scripts/newton_passes.py --out docs/data/newton_passes.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from cloth_gym.reports.provenance import stamp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

IDS = ["cloth_gym/CornerLift-v2", "cloth_gym/RibbonDrop-v1", "cloth_gym/DrapeOntoTable-v1"]


def episode(env_id: str, seed: int, sim: dict | None) -> dict:
    import gymnasium as gym

    import cloth_gym  # noqa: F401
    from agents.experts import make_expert
    from cloth_gym.sim.diagnostics import edge_strain

    env = gym.make(env_id, **({"sim": sim} if sim else {}))
    env.reset(seed=seed)
    expert = make_expert(env)
    physics = env.unwrapped.physics
    solves, cpu, strain, info = [], 0.0, 0.0, {}
    while True:
        c0 = time.process_time()
        _, _, term, trunc, info = env.step(expert.act())
        cpu += time.process_time() - c0
        stats = physics.integrator.last_stats
        if stats.shape[1] > 2:
            solves.extend(stats[:, 2].tolist())
        strain = max(strain, float(np.max(edge_strain(physics.model, physics.state))))
        if term or trunc:
            break
    steps = env.unwrapped.elapsed_steps if hasattr(env.unwrapped, "elapsed_steps") else len(solves)
    env.close()
    s = np.asarray(solves) if solves else np.ones(1)
    return {"seed": seed, "success": bool(info.get("is_success", False)), "diverged": bool(info.get("diverged", False)),
            "cpu_s": cpu, "env_steps": int(steps), "substeps": int(s.size),
            "share_more_than_one_solve": float(np.mean(s > 1)), "solves_per_substep": float(np.mean(s)),
            "max_strain_percent": strain}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--ids", nargs="+", default=IDS)
    p.add_argument("--seeds", type=int, nargs="+", default=[100, 101, 102])
    p.add_argument("--newton-tol", type=float, default=0.1, help="cm/s")
    p.add_argument("--newton-iters", type=int, default=10)
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    converged = {"newton_iters": args.newton_iters, "newton_tol": args.newton_tol, "momentum_exact": True}
    settings = {"env": None, "converged": converged, "line_search": {**converged, "line_search": True}}
    out = []
    for env_id in args.ids:
        episode(env_id, args.seeds[0], None)  # compile and warm up
        runs = {name: [] for name in settings}
        for seed in args.seeds:  # alternated, so machine noise falls on all alike
            for name, sim in settings.items():
                runs[name].append(episode(env_id, seed, sim))
        row = {"env_id": env_id}
        for name, eps in runs.items():
            cpu = sum(e["cpu_s"] for e in eps) / sum(e["env_steps"] for e in eps)
            row[name] = {"cpu_s_per_env_step": cpu, "success": sum(e["success"] for e in eps),
                         "diverged": sum(e["diverged"] for e in eps), "episodes": len(eps),
                         "share_more_than_one_solve": float(np.mean([e["share_more_than_one_solve"] for e in eps])),
                         "solves_per_substep": float(np.mean([e["solves_per_substep"] for e in eps])),
                         "max_strain_percent": max(e["max_strain_percent"] for e in eps), "per_episode": eps}
        for name in ("converged", "line_search"):
            row[name]["cpu_ratio"] = row[name]["cpu_s_per_env_step"] / row["env"]["cpu_s_per_env_step"]
        out.append(row)
        for name in ("converged", "line_search"):
            c = row[name]
            print(f"{env_id} {name}: {100 * c['share_more_than_one_solve']:.1f} % of substeps need a Newton "
                  f"correction, {c['solves_per_substep']:.2f} solves/substep; CPU/env step "
                  f"{1e3 * row['env']['cpu_s_per_env_step']:.1f} -> {1e3 * c['cpu_s_per_env_step']:.1f} ms "
                  f"({c['cpu_ratio']:.2f}x); success {row['env']['success']} -> {c['success']} of {c['episodes']}; "
                  f"strain {row['env']['max_strain_percent']:.1f} -> {c['max_strain_percent']:.1f} %", flush=True)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        command = " ".join(["python scripts/newton_passes.py", *(argv if argv is not None else sys.argv[1:])])
        args.out.write_text(json.dumps({"stamp": stamp(command), "settings": settings, "rows": out}, indent=2)
                            + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
