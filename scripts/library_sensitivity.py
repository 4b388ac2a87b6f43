#!/usr/bin/env python
"""Policies on every shipped fabric: success and return per fabric and (env, policy) case.

Each case ``ENV_ID=POLICY`` (POLICY: ``expert``, ``random``, ``published`` or a training run
directory) runs ``--episodes`` seeded episodes on each fabric as measured (``--materials``:
default every shipped material). Writes ``library.json``, ``library.md`` and
``heatmap_success_rate.png`` to ``--out``.

    python scripts/library_sensitivity.py --cases cloth_gym/CornerLift-v2=expert \\
        cloth_gym/CornerLift-v2=published --episodes 10 --out docs/data/sensitivity/library
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository's agents/ package

from cloth_gym.agents.sensitivity import library_sweep, library_variants, write_library_report  # noqa: E402
from cloth_gym.errors import ConfigError  # noqa: E402
from cloth_gym.reports.options import command_line  # noqa: E402
from cloth_gym.reports.provenance import stamp  # noqa: E402


def parse_case(text: str) -> tuple[str, str]:
    env_id, sep, policy = text.partition("=")
    if not sep or not env_id or not policy:
        raise ConfigError("cases", f"each case is ENV_ID=POLICY (expert, random, published or a run directory), "
                          f"got {text!r}")
    return env_id, policy


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", required=True, metavar="ENV_ID=POLICY")
    ap.add_argument("--materials", nargs="+", default=None, help="shipped material names (default: all)")
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seed", type=int, default=1000, help="first episode seed (each cell: seed, seed + 1, ...)")
    ap.add_argument("--backend", choices=["process", "ray"], default="process")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--address", default=None, help="Ray cluster address (default: start a local Ray)")
    ap.add_argument("--out", default="outputs/sensitivity/library")
    args = ap.parse_args(argv)
    cases = [parse_case(c) for c in args.cases]
    variants = library_variants(args.materials)
    meta = {**stamp(command_line("python scripts/library_sensitivity.py", argv)), **vars(args)}
    t0, c0 = time.perf_counter(), time.process_time()
    rows = library_sweep(cases, variants, args.episodes, args.seed, args.backend, args.workers, args.address)
    meta.update(wall_s=time.perf_counter() - t0, parent_cpu_s=time.process_time() - c0)
    files = write_library_report(rows, args.out, meta)
    print(files["md"].read_text())
    print("wrote", ", ".join(str(p) for p in files.values()))
    return rows


if __name__ == "__main__":
    main()
