#!/usr/bin/env python
"""Train a Stable-Baselines3 baseline on a cloth_gym env (thin entry point to cloth_gym.agents.training).

    python scripts/train.py --algo sac --env cloth_gym/CornerLift-v2 [--seed 0] [--run-dir runs/...]
        [--conf configs/train/ppo.yaml] [--set n_timesteps=20000 learning_rate=lin_1e-3 ...]
        [--eval-freq 5000] [--eval-episodes 10] [--checkpoint-freq 0] [--vec-env dummy|subproc|batched]
        [--overlap] [--progress]

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
    ap.add_argument("--overlap", action="store_true",
                    help="take the gradient steps while the envs step (sac, tqc): the policy acts one update "
                         "behind (cloth_gym.agents.overlap)")
    ap.add_argument("--progress", action="store_true", help="show a progress bar")
    ap.add_argument("--verbose", type=int, default=0)
    return ap


def main(argv=None):
    args = build_parser().parse_args(argv)
    cfg = load_train_config(args.algo, args.env, args.conf, parse_overrides(args.set))
    run_dir = args.run_dir or f"runs/{args.algo}_{args.env.split('/')[-1]}_s{args.seed}"
    res = train(cfg, run_dir, seed=args.seed, eval_freq=args.eval_freq, n_eval_episodes=args.eval_episodes,
                checkpoint_freq=args.checkpoint_freq, progress_bar=args.progress, vec_env=args.vec_env,
                overlap=args.overlap, verbose=args.verbose,
                command=shlex.join([sys.executable, *sys.argv]) if argv is None else None)
    print(f"trained {res.env_steps} env steps in {res.wall_s:.1f} s -> {res.run_dir}")


if __name__ == "__main__":
    main()
