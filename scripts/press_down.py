"""RibbonDrop pressed onto the floor: the gripper holds the ribbon's end and moves straight down
(action ``[0, 0, -1, 1]``) for 18 control steps, 36 cm, piling the ribbon on the floor under it.

For each id and seed: whether the episode diverged and the largest lattice-edge strain (%) over
its control steps, with self-collision on (the env's) and off (the same episodes with the model's
``self_collision`` switched off, for comparison). docs/numerics.md, "Pressing a ribbon onto the floor".

    python scripts/press_down.py [--ids cloth_gym/RibbonDrop-v1 cloth_gym/RibbonDrop-v2] [--seeds 8] [--sim JSON]
        [--out docs/data/press_down.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PRESS = np.array([0.0, 0.0, -1.0, 1.0], dtype=np.float32)
STEPS = 18


def press_episode(env_id: str, seed: int, self_collision: bool = True, steps: int = STEPS,
                  sim: dict | None = None) -> dict:
    """One pressed episode: ``{"diverged", "steps", "max_strain_percent", "strain_percent_by_step",
    "worst"}``: the largest lattice-edge strain over the control steps reached before a divergence,
    after each of them, and where the largest was (control step, edge, its two particles and their
    heights z, cm; RibbonDrop's floor is z = 0)."""
    import gymnasium as gym

    import cloth_gym  # noqa: F401
    from cloth_gym.sim.diagnostics import edge_strain

    env = gym.make(env_id, **({"sim": sim} if sim else {}))
    env.reset(seed=seed)
    p = env.unwrapped.physics
    if not self_collision:
        p.model = p.model.with_collision(self_collision=False)
    worst, diverged, k, by_step, where = 0.0, False, 0, [], {}
    for k in range(1, steps + 1):
        _, _, _, _, info = env.step(PRESS)
        if info.get("diverged"):
            diverged = True
            break
        strain = edge_strain(p.model, p.state)
        e = int(np.argmax(strain))
        by_step.append(round(float(strain[e]), 3))
        if strain[e] > worst:
            worst = float(strain[e])
            a, b = (int(i) for i in p.model.edge_indices[e])
            z = p.state.particle_q[:, 2]
            where = {"control_step": k, "edge": e, "particles": [a, b],
                     "z_cm": [round(float(z[a]), 3), round(float(z[b]), 3)]}
    env.close()
    return {"diverged": diverged, "steps": k, "max_strain_percent": round(worst, 3),
            "strain_percent_by_step": by_step, "worst": where}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ids", nargs="+", default=["cloth_gym/RibbonDrop-v1", "cloth_gym/RibbonDrop-v2"])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--sim", type=json.loads, default=None, metavar="JSON",
                    help="the env's solver settings to change, e.g. '{\"couple_collisions\": true}'")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    rows = []
    for env_id in args.ids:
        for sc in (True, False):
            t0, c0 = time.perf_counter(), time.process_time()
            eps = [press_episode(env_id, s, sc, sim=args.sim) for s in range(args.seeds)]
            row = {"env_id": env_id, "sim": args.sim, "self_collision": sc, "seeds": f"0-{args.seeds - 1}",
                   "diverged": sum(e["diverged"] for e in eps),
                   "max_strain_percent": max(e["max_strain_percent"] for e in eps), "episodes": eps,
                   "cpu_s": round(time.process_time() - c0, 1), "wall_s": round(time.perf_counter() - t0, 1)}
            rows.append(row)
            print(f"{env_id} self-collision {'on ' if sc else 'off'}: {row['diverged']} of {args.seeds} diverge, "
                  f"largest strain {row['max_strain_percent']:.2f} % (cpu {row['cpu_s']} s)", flush=True)
    if args.out:
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True,
                                text=True).stdout.strip()
        out = {"command": "python scripts/press_down.py " + " ".join(["--ids", *args.ids, "--seeds",
                                                                       str(args.seeds), "--out", args.out])
               + (f" --sim '{json.dumps(args.sim)}'" if args.sim else ""),
               "commit": commit, "machine": platform.machine(), "python": platform.python_version(),
               "action": PRESS.tolist(), "control_steps": STEPS, "rows": rows}
        Path(args.out).write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
