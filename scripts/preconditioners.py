#!/usr/bin/env python
"""CG iterations per implicit step for each preconditioner (41×41 cotton hung by two corners).

Prints a markdown table and writes ``<out>/preconditioners/preconditioners.{json,md}``.

    python scripts/preconditioners.py [--out outputs] [--duration 0.2]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from cloth_gym.reports.options import command_line
from cloth_gym.reports.provenance import stamp, stamp_line
from cloth_gym.scenes import hanging_cloth
from cloth_gym.sim.implicit import ImplicitEuler


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="outputs")
    ap.add_argument("--duration", type=float, default=0.2)
    ap.add_argument("--size", type=float, default=40.0)
    args = ap.parse_args(argv)
    provenance = stamp(command_line("python scripts/preconditioners.py", sys.argv[1:] if argv is None else argv))
    rows = []
    for pc in ("jacobi", "lines", "multigrid"):
        for dt in (1e-3, 2e-3, 5e-3):
            m = hanging_cloth("thick_cotton", args.size, 1.0)
            s = m.state()
            integ = ImplicitEuler(max_dt=dt, preconditioner=pc, tol=1e-4, max_iter=200)
            integ.step(m, s, None, dt)  # compile / warm up
            t0 = time.perf_counter()
            info = integ.step(m, s, None, args.duration)
            rows.append({"preconditioner": pc, "dt_s": dt, "cg_iterations_mean": info.cg_iterations_mean,
                         "cg_iterations_max": info.cg_iterations_max, "residual_max": info.residual_max,
                         "wall_per_simulated_s": (time.perf_counter() - t0) / args.duration,
                         "particles": m.particle_count})
            print(json.dumps(rows[-1]), flush=True)
    md = [stamp_line(provenance), "",
          "| preconditioner | Δt (s) | mean CG its | max CG its | worst residual | wall s per simulated s |",
          "|---|---|---|---|---|---|"]
    md += [f"| {r['preconditioner']} | {r['dt_s']:.0e} | {r['cg_iterations_mean']:.1f} | {r['cg_iterations_max']} | "
           f"{r['residual_max']:.1e} | {r['wall_per_simulated_s']:.1f} |" for r in rows]
    out = Path(args.out) / "preconditioners"
    out.mkdir(parents=True, exist_ok=True)
    (out / "preconditioners.json").write_text(json.dumps(rows, indent=2))
    (out / "preconditioners.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
