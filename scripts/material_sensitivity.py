#!/usr/bin/env python
"""Material sensitivity sweep (thin entry point to :mod:`cloth_gym.agents.sensitivity`).

For cotton, wool, Breen's model and each KES parameter group (areal mass,
stretch warp/weft, bending warp/weft, shear) scaled by each factor: the drape
test's DC and node count, and a policy's success rate and return. Writes a
CSV, a markdown table, a JSON and tornado charts to ``--out``.

    python scripts/material_sensitivity.py [--jobs drape policy] [--factors 0.25 0.5 2 4]
        [--groups stretch_warp ...] [--policy expert|random|RUN_DIR] [--env cloth_gym/CornerLift-v0]
        [--episodes 10] [--sigma 1.0] [--drape-time 4.0] [--backend process|ray] [--workers 2]
        [--address ray://host:10001] [--out outputs/sensitivity]

With ``--backend ray`` and no ``--address`` a single-node Ray is started on this machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository's agents/ package

from cloth_gym.agents.sensitivity import GROUPS, default_variants, run_sweep, write_report  # noqa: E402
from cloth_gym.reports.options import command_line
from cloth_gym.reports.provenance import stamp  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--jobs", nargs="+", choices=["drape", "policy"], default=["drape", "policy"])
    ap.add_argument("--base", default="thick_cotton")
    ap.add_argument("--factors", type=float, nargs="+", default=[0.25, 0.5, 2.0, 4.0])
    ap.add_argument("--groups", nargs="+", choices=list(GROUPS), default=None)
    ap.add_argument("--policy", default="expert", help="expert, random or a training run directory")
    ap.add_argument("--env", default=None,
                    help="env id (default: a training run's own env; cloth_gym/CornerLift-v0 for expert/random)")
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--sigma", type=float, default=1.0, help="drape test lattice spacing, cm")
    ap.add_argument("--drape-time", type=float, default=4.0, help="longest drape simulation, s")
    ap.add_argument("--backend", choices=["process", "ray"], default="process")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--address", default=None, help="Ray cluster address (default: start a local Ray)")
    ap.add_argument("--out", default="outputs/sensitivity")
    args = ap.parse_args(argv)
    variants = default_variants(args.base, args.factors, args.groups)
    drape = {"sigma": args.sigma, "max_time_s": args.drape_time} if "drape" in args.jobs else None
    env_id = args.env or (None if args.policy not in ("expert", "random") else "cloth_gym/CornerLift-v0")
    policy = ({"policy": args.policy, "env_id": env_id, "episodes": args.episodes, "seed": args.seed,
               "env_kwargs": {}} if "policy" in args.jobs else None)
    provenance = stamp(command_line("python scripts/material_sensitivity.py", sys.argv[1:] if argv is None else argv))
    t0 = time.perf_counter()
    rows = run_sweep(variants, drape, policy, backend=args.backend, workers=args.workers,
                     ray_address=args.address)
    meta = {**provenance, **vars(args), "wall_s": time.perf_counter() - t0}
    files = write_report(rows, args.out, meta)
    print((Path(args.out) / "sensitivity.md").read_text())
    print(json.dumps({k: str(v) for k, v in files.items()}, indent=2))


if __name__ == "__main__":
    main()
