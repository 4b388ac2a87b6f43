#!/usr/bin/env python
"""Hyperparameter sweep on Ray Tune over a training config (thin entry point to cloth_gym.agents.sweep).

    python scripts/sweep.py --algo sac --env cloth_gym/CornerLift-v1 \\
        --conf configs/train/sac_curriculum.yaml --space configs/sweep/sac.yaml \\
        [--samples 8] [--set n_timesteps=30000 ...] [--metric success_rate|mean_return]
        [--scheduler asha|fifo] [--cpus 2] [--cpus-per-trial 1] [--address ray://host:10001]
        [--storage s3://bucket/sweeps] [--out runs/sweep_<algo>_<env>]

Each trial trains the config with one sample of the search space applied (a normal run
directory, under ``<out>/tune/<trial>/run``) and reports every evaluation to Tune. Without
``--address`` a Ray with ``--cpus`` CPUs is started here; with it, the trials run on that
cluster (its nodes need cloth_gym installed and ``--out`` or ``--storage`` reachable).
Writes ``<out>/sweep.json`` (every trial) and ``<out>/best.yaml`` (the best config, for
``scripts/train.py --conf``).
"""

from __future__ import annotations

import argparse

from cloth_gym.agents.config import ALGOS, load_train_config, parse_overrides
from cloth_gym.agents.sweep import METRICS, SCHEDULERS, SWEEP_CONFIG_DIR, load_search_space, sweep


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", choices=ALGOS, default="sac")
    ap.add_argument("--env", default="cloth_gym/CornerLift-v1")
    ap.add_argument("--conf", default=None, help="training config YAML (default configs/train/<algo>.yaml)")
    ap.add_argument("--space", default=None, help="search-space YAML (default configs/sweep/<algo>.yaml)")
    ap.add_argument("--set", nargs="*", action="extend", default=[], metavar="KEY=VALUE",
                    help="override the config for every trial (values are YAML)")
    ap.add_argument("--samples", type=int, default=8, help="trials (with grid entries: repeats of the grid)")
    ap.add_argument("--seed", type=int, default=0, help="every trial's training seed")
    ap.add_argument("--eval-freq", type=int, default=5000, help="env steps between evaluations")
    ap.add_argument("--eval-episodes", type=int, default=10)
    ap.add_argument("--metric", choices=METRICS, default="success_rate")
    ap.add_argument("--scheduler", choices=SCHEDULERS, default="asha")
    ap.add_argument("--cpus", type=int, default=2, help="CPUs of the local Ray (ignored with --address)")
    ap.add_argument("--cpus-per-trial", type=int, default=1)
    ap.add_argument("--address", default=None, help="a running Ray cluster (ray://host:10001 or auto)")
    ap.add_argument("--storage", default=None, help="where Tune keeps the trials (default <out>/tune)")
    ap.add_argument("--out", default=None, help="default runs/sweep_<algo>_<env>")
    ap.add_argument("--verbose", type=int, default=0)
    return ap


def main(argv=None):
    args = build_parser().parse_args(argv)
    cfg = load_train_config(args.algo, args.env, args.conf, parse_overrides(args.set))
    space = load_search_space(args.space or SWEEP_CONFIG_DIR / f"{'sac' if args.algo == 'tqc' else args.algo}.yaml")
    out = args.out or f"runs/sweep_{args.algo}_{args.env.split('/')[-1]}"
    res = sweep(cfg, space, out, num_samples=args.samples, seed=args.seed, eval_freq=args.eval_freq,
                n_eval_episodes=args.eval_episodes, metric=args.metric, scheduler=args.scheduler, cpus=args.cpus,
                cpus_per_trial=args.cpus_per_trial, address=args.address, storage=args.storage,
                verbose=args.verbose)
    print(f"{'success':>8} {'return':>9} {'steps':>7}  params")
    for t in res.trials:
        sr = "-" if t["success_rate"] is None else f"{t['success_rate']:.2f}"
        ret = "-" if t["mean_return"] is None else f"{t['mean_return']:.1f}"
        print(f"{sr:>8} {ret:>9} {t['env_steps'] or 0:>7}  {t['params']}")
    print(f"best config -> {res.out_dir / 'best.yaml'}; all trials -> {res.out_dir / 'sweep.json'}")


if __name__ == "__main__":
    main()
