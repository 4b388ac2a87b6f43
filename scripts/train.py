#!/usr/bin/env python
"""Train a Stable-Baselines3 baseline on a cloth_gym env (thin entry point to cloth_gym.agents.training).

    python scripts/train.py --algo sac --env cloth_gym/CornerLift-v2 [--seed 0] [--run-dir runs/...]
        [--conf configs/train/ppo.yaml] [--set n_timesteps=20000 learning_rate=lin_1e-3 ...]
        [--eval-freq 5000] [--eval-episodes 10] [--checkpoint-freq 0] [--n-envs N]
        [--vec-env dummy|subproc|batched|ray [--envs-per-actor k] [--ray-address ADDR]] [--overlap] [--progress]

The hyperparameters come from ``configs/train/<algo>.yaml`` (rl-baselines3-zoo
format); ``--set key=value`` overrides them (values are YAML, never evaluated).
The run directory keeps the resolved config, the command, the model, its
normalisation statistics, evaluations and a learning curve.
"""

from __future__ import annotations

import argparse
import shlex
import sys

from cloth_gym.agents.config import ALGOS, load_train_config, parse_overrides
from cloth_gym.agents.training import VEC_ENVS, train


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", choices=ALGOS, default="ppo")
    ap.add_argument("--env", default="cloth_gym/CornerLift-v2")
    ap.add_argument("--conf", default=None, help="hyperparameter YAML (default configs/train/<algo>.yaml)")
    ap.add_argument("--set", nargs="*", action="extend", default=[], metavar="KEY=VALUE",
                    help="override hyperparameters (repeatable: every --set counts)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--run-dir", default=None, help="default runs/<algo>_<env>_s<seed>")
    ap.add_argument("--eval-freq", type=int, default=5000, help="env steps between evaluations (0: none)")
    ap.add_argument("--eval-episodes", type=int, default=10)
    ap.add_argument("--checkpoint-freq", type=int, default=0, help="env steps between checkpoints (0: none)")
    ap.add_argument("--vec-env", choices=VEC_ENVS, default="dummy",
                    help="how the n_envs envs run: one after another, in subprocesses, or batched in one "
                         "process with their physics in parallel threads")
    ap.add_argument("--subproc", action="store_const", dest="vec_env", const="subproc", help="--vec-env subproc")
    ap.add_argument("--n-envs", type=int, default=None, help="envs stepped together (the config's n_envs)")
    ap.add_argument("--envs-per-actor", type=int, default=1, help="--vec-env ray: sub-envs per Ray actor")
    ap.add_argument("--threads-per-actor", type=int, default=1,
                    help="--vec-env ray: each actor's physics threads (and the CPUs it reserves)")
    ap.add_argument("--ray-address", default=None,
                    help="--vec-env ray: a running Ray cluster (default: a local Ray started for the run)")
    ap.add_argument("--overlap", action="store_true",
                    help="take the gradient steps while the envs step (sac, tqc): the policy acts one update "
                         "behind (cloth_gym.agents.overlap)")
    ap.add_argument("--progress", action="store_true", help="show a progress bar")
    ap.add_argument("--verbose", type=int, default=0)
    return ap


def main(argv=None):
    args = build_parser().parse_args(argv)
    overrides = parse_overrides(args.set)
    if args.n_envs is not None:
        overrides["n_envs"] = args.n_envs
    cfg = load_train_config(args.algo, args.env, args.conf, overrides)
    ray = None
    if args.vec_env == "ray":
        ray = {"envs_per_actor": args.envs_per_actor, "threads_per_actor": args.threads_per_actor,
               "address": args.ray_address}
    run_dir = args.run_dir or f"runs/{args.algo}_{args.env.split('/')[-1]}_s{args.seed}"
    res = train(cfg, run_dir, seed=args.seed, eval_freq=args.eval_freq, n_eval_episodes=args.eval_episodes,
                checkpoint_freq=args.checkpoint_freq, progress_bar=args.progress, vec_env=args.vec_env,
                overlap=args.overlap, verbose=args.verbose, ray=ray,
                command=shlex.join([sys.executable, *sys.argv]) if argv is None else None)
    print(f"trained {res.env_steps} env steps in {res.wall_s:.1f} s -> {res.run_dir}")


if __name__ == "__main__":
    main()
