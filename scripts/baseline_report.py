#!/usr/bin/env python
"""Baseline table: random, scripted expert and trained runs on each env, evaluated alike.

    python scripts/baseline_report.py --runs runs/ppo_CornerLift-v0_s0 runs/sac_CornerLift-v0_s0
        [--envs cloth_gym/CornerLift-v0 ...] [--episodes 20] [--seed 1000] [--out docs/data/baselines]
        [--seed-curves "sac.yaml=runs/sac_CornerLift-v0_s0,runs/sac_CornerLift-v0_s1" ...] [--runs-only]

Every policy is evaluated on the same seeded episodes (seeds seed, seed + 1, ...,
not used in training, whose evaluation env starts at 10000). Writes
``<out>/baselines.json``, ``<out>/baselines.md`` (success rate, return mean ± std,
training env steps and wall time) and copies each run's ``learning_curve.png``. A run
trained with scripted-expert demonstrations (``expert_demos``) says so in its row,
with the demonstrations' env steps; its wall time includes collecting them.
``--seed-curves LABEL=RUN,RUN,...`` (repeatable) also plots the evaluation success
rate of several training seeds per config, ``<out>/seed_curves.png``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository's agents/ package

from cloth_gym.agents.evaluation import evaluate_policy_source  # noqa: E402
from cloth_gym.agents.training import plot_seed_curves  # noqa: E402
from cloth_gym.reports.options import command_line
from cloth_gym.reports.provenance import stamp, stamp_line  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", nargs="*", default=[])
    ap.add_argument("--envs", nargs="*", default=None, help="envs for random/expert (default: the runs' envs)")
    ap.add_argument("--runs-only", action="store_true",
                    help="leave out the random and expert rows (another report has them; runs scored in parallel)")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--out", default="docs/data/baselines")
    ap.add_argument("--seed-curves", nargs="*", action="extend", default=[], metavar="LABEL=RUN,RUN,...",
                    help="plot the evaluation success of these runs, one group per label")
    args = ap.parse_args(argv)
    provenance = stamp(command_line("python scripts/baseline_report.py", sys.argv[1:] if argv is None else argv))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.seed_curves:
        groups = {}
        for item in args.seed_curves:
            label, sep, runs = item.rpartition("=")  # a label may contain "=", a run directory not
            if not sep or not runs:
                ap.error(f"--seed-curves takes LABEL=RUN,RUN,..., got {item!r}")
            groups[label] = runs.split(",")
        print(plot_seed_curves(groups, out / "seed_curves.png"))
    runs = {}
    for r in args.runs:
        conf = yaml.safe_load((Path(r) / "config.yaml").read_text())
        (env_id, entry), = conf.items()
        runs.setdefault(env_id, []).append((r, entry))
    envs = args.envs or list(runs)
    rows = []
    for env_id in envs:
        kwargs = runs[env_id][0][1].get("env_kwargs", {}) if env_id in runs else {}
        for pol in () if args.runs_only else ("random", "expert"):
            res = evaluate_policy_source(pol, env_id, args.episodes, args.seed, kwargs)
            rows.append({"env_id": env_id, "policy": pol, **{k: res[k] for k in (
                "success_rate", "return_mean", "return_std", "diverged")}, "env_steps": 0, "train_wall_s": 0.0, "train_cpu_s": 0.0})
            print(json.dumps(rows[-1]))
        for r, entry in runs.get(env_id, []):
            res = evaluate_policy_source(r, None, args.episodes, args.seed)
            info = json.loads((Path(r) / "run.json").read_text())
            label = f"{info['algo']} ({Path(r).name})"
            demos = info.get("expert_demos")
            if demos:  # say plainly that the policy learnt from the scripted expert's episodes
                label += (f", trained with {demos['episodes']} expert demonstrations "
                          f"({demos['env_steps']} env steps, not counted in training env steps)")
            rows.append({"env_id": env_id, "policy": label, "expert_demos": demos,
                         **{k: res[k] for k in ("success_rate", "return_mean", "return_std", "diverged")},
                         "env_steps": info["env_steps"], "train_wall_s": info["wall_s"],
                         "train_cpu_s": info.get("cpu_s")})
            print(json.dumps(rows[-1]))
            curve = Path(r) / "learning_curve.png"
            if curve.exists():
                shutil.copy(curve, out / f"{Path(r).name}_learning_curve.png")
            shutil.copy(Path(r) / "config.yaml", out / f"{Path(r).name}_config.yaml")
            if (Path(r) / "eval" / "evaluations.npz").exists():
                shutil.copy(Path(r) / "eval" / "evaluations.npz", out / f"{Path(r).name}_evaluations.npz")
    lines = [stamp_line(provenance), "",
             f"Evaluated on {args.episodes} seeded episodes (seeds {args.seed}…{args.seed + args.episodes - 1}).", "",
             "| env | policy | success rate | return (mean ± std) | diverged | training env steps | training wall (min) "
             "| training CPU (min) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['env_id']} | {r['policy']} | {r['success_rate']:.2f} | {r['return_mean']:.1f} ± "
                     f"{r['return_std']:.1f} | {r['diverged']} | {r['env_steps'] or '–'} | "
                     f"{r['train_wall_s'] / 60:.1f} | {_minutes(r['train_cpu_s'])} |" if r["env_steps"] else
                     f"| {r['env_id']} | {r['policy']} | {r['success_rate']:.2f} | {r['return_mean']:.1f} ± "
                     f"{r['return_std']:.1f} | {r['diverged']} | – | – | – |")
    (out / "baselines.json").write_text(json.dumps(rows, indent=2))
    (out / "baselines.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def _minutes(seconds) -> str:
    """CPU seconds as minutes for the table; '–' for a run whose run.json predates the CPU record."""
    return "–" if seconds is None else f"{seconds / 60:.1f}"


if __name__ == "__main__":
    main()
