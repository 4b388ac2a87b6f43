#!/usr/bin/env python
"""What each collision feature costs (a scene pays only for what it uses).

Scene: the benchmark's tablecloth (40 cm cotton square dropped on a 20 cm table,
41×41 at σ = 1 cm, implicit Euler at Δt = 1 ms) in four variants: analytic table
(the default: no collision pass at all), the table as a trimesh box instead,
self-collision on, and both. Plus the falling ribbon (thin wool, 30 × 3 cm,
σ = 1 cm) with self-collision, which needs it. Writes
``<out>/collision_cost/collision_cost.{json,md}``.

    python scripts/collision_cost.py [--out outputs] [--duration 0.5] [--sigma 1.0]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

from cloth_gym.reports.options import command_line
from cloth_gym.reports.provenance import stamp, stamp_line
from cloth_gym.scenes import tablecloth
from cloth_gym.sim import Ribbon, build_cloth
from cloth_gym.sim.collision import MeshObstacle
from cloth_gym.sim.implicit import ImplicitEuler
from cloth_gym.sim.obstacles import Box, Plane


def _mesh_table(model):
    obs = []
    for ob in model.obstacles:
        if isinstance(ob, Box):
            box = trimesh.creation.box(extents=2 * np.asarray(ob.half_extents),
                                       transform=trimesh.transformations.translation_matrix(ob.center))
            obs.append(MeshObstacle(box, friction=ob.friction))
        else:
            obs.append(ob)
    return model.with_obstacles(obs)


def _time(model, duration, dt):
    integ = ImplicitEuler(max_dt=dt)
    s = model.state()
    integ.step(model, s, None, dt)  # compile / load
    t0 = time.perf_counter()
    integ.advance(model, s, None, duration, 0.02)
    wall = time.perf_counter() - t0
    return wall, s


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="outputs")
    ap.add_argument("--duration", type=float, default=0.5, help="simulated seconds per variant")
    ap.add_argument("--sigma", type=float, default=1.0)
    ap.add_argument("--dt", type=float, default=1e-3)
    args = ap.parse_args(argv)
    provenance = stamp(command_line("python scripts/collision_cost.py", sys.argv[1:] if argv is None else argv))
    base = tablecloth(sigma=args.sigma)
    R = np.array([[0, 0, 1.0], [0, 1.0, 0], [-1.0, 0, 0]])
    ribbon = build_cloth(Ribbon(30.0, 3.0), "thin_wool", sigma=1.0, rotation=R, origin=(0, 0, 15.6),
                         obstacles=[Plane()])
    variants = [
        ("tablecloth", "analytic table (no collision pass)", base),
        ("tablecloth", "trimesh table", _mesh_table(base)),
        ("tablecloth", "analytic table + self-collision", base.with_collision(self_collision=True)),
        ("tablecloth", "trimesh table + self-collision", _mesh_table(base).with_collision(self_collision=True)),
        ("ribbon", "floor, no self-collision", ribbon),
        ("ribbon", "floor + self-collision", ribbon.with_collision(self_collision=True)),
    ]
    rows = []
    for scene, name, model in variants:
        wall, s = _time(model, args.duration, args.dt)
        row = {"scene": scene, "variant": name, "particles": model.particle_count, "dt_s": args.dt,
               "simulated_s": args.duration, "wall_s": wall, "wall_per_simulated_s": wall / args.duration,
               "lowest_z_cm": float(s.particle_q[:, 2].min())}
        rows.append(row)
        print(json.dumps(row))
    ref = {r["scene"]: r["wall_per_simulated_s"] for r in rows if r is rows[0] or r is rows[4]}
    lines = [stamp_line(provenance), "",
             "| scene | variant | particles | wall / simulated s | relative |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['variant']} | {r['particles']} | {r['wall_per_simulated_s']:.2f} | "
                     f"{r['wall_per_simulated_s'] / ref[r['scene']]:.2f}× |")
    out = Path(args.out) / "collision_cost"
    out.mkdir(parents=True, exist_ok=True)
    doc = {**provenance, "duration_s": args.duration, "rows": rows}
    (out / "collision_cost.json").write_text(json.dumps(doc, indent=2))
    (out / "collision_cost.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
