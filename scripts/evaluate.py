#!/usr/bin/env python
"""Evaluate a policy: a training run directory, the scripted ``expert``, or ``random`` actions.

    python scripts/evaluate.py RUN_DIR|expert|random [--env ID] [--episodes 10] [--seed 1000]
        [--gif outputs/eval/episode.gif] [--out outputs/eval/result.json] [--env-kwargs '{sigma: 2.0}']

Prints and writes the success rate, return mean ± std and episode lengths
(episodes use seeds seed, seed + 1, ...: every policy sees the same starts).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import yaml

from cloth_gym.agents.evaluation import evaluate_policy_source


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("policy", help="a run directory, 'expert' or 'random'")
    ap.add_argument("--env", default=None, help="env id (a run directory knows its own)")
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seed", type=int, default=1000, help="first episode seed (training evaluates at 10000+)")
    ap.add_argument("--env-kwargs", default=None, help="YAML mapping of env constructor arguments")
    ap.add_argument("--gif", default=None, help="write a GIF of the first episode here")
    ap.add_argument("--out", default=None, help="JSON result path (default outputs/eval/<policy>_<env>.json)")
    args = ap.parse_args(argv)
    kwargs = yaml.safe_load(args.env_kwargs) if args.env_kwargs else None
    name = Path(args.policy).name if args.policy not in ("expert", "random") else args.policy
    out = args.out or f"outputs/eval/{name}_{(args.env or 'run').split('/')[-1]}.json"
    res = evaluate_policy_source(args.policy, args.env, args.episodes, args.seed, kwargs, args.gif, out)
    res.pop("per_episode")
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
