"""An env under a jerk policy on randomised materials: every gripper commands ±1 on every axis,
the sign flipping every control step, grippers closed, for a whole episode; each episode's
fabric is thick cotton with its stretch, bending and shear curves each scaled by a factor drawn
uniformly from 0.25-4 (the env's ``material`` randomisation, drawn from the episode seed).
``--policy random``: uniformly random actions instead (the action space seeded with the episode
seed), on the env's own material.

For each seed: whether the episode diverged (the env's guard truncates it with
``info["diverged"]``), the control steps run, the largest lattice-edge strain (%) over them, and
the control steps whose integrator call diverged and was run again (``retry_diverged``) or was
run again in shorter substeps (``refine_strain_rise``). docs/numerics.md, "Shaking a cloth".

    python scripts/jerk.py [--id cloth_gym/DrapeOntoTable-v1] [--seeds 0 20] [--sim JSON]
        [--policy jerk|random] [--no-self-collision] [--out docs/data/jerk.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from cloth_gym.reports.provenance import stamp

#: the env's material option: cotton with each curve scaled ×0.25–4 at every reset
MATERIAL = {"base": "thick_cotton", "stretch_scale": (0.25, 4.0), "bending_scale": (0.25, 4.0),
            "shear_scale": (0.25, 4.0)}


def jerk_action(space, k: int) -> np.ndarray:
    """Control step ``k``'s action: +1 (even k) or −1 (odd k) on every gripper's motion axes, every
    gripper's grip entry (each gripper's last) +1, closed."""
    n = space.shape[0] // 4
    a = np.full((n, 4), 1.0 if k % 2 == 0 else -1.0, dtype=space.dtype)
    a[:, 3] = 1.0
    return a.reshape(-1)


def jerk_episode(env_id: str, seed: int, sim: dict | None = None, self_collision: bool = True,
                 policy: str = "jerk") -> dict:
    """One jerked episode (the env's solver settings updated by ``sim``; with ``self_collision``
    False, the model's self-collision switched off after the reset; ``policy="random"``: seeded
    random actions on the env's own material): ``{"seed", "diverged", "steps",
    "max_strain_percent", "divergence", "retried_steps", "refined_steps", "cpu_s"}`` (the strain
    over the control steps reached before a divergence, if any; the guard's message; the control
    steps whose integrator call was run again: after diverging, ``retry_diverged``, or in shorter
    substeps, ``refine_strain_rise``)."""
    import gymnasium as gym

    import cloth_gym  # noqa: F401
    from cloth_gym.sim.diagnostics import edge_strain

    kwargs = {"material": MATERIAL} if policy == "jerk" else {}
    env = gym.make(env_id, **kwargs, **({"sim": sim} if sim else {}))
    _, info = env.reset(seed=seed)
    env.action_space.seed(seed)
    p = env.unwrapped.physics
    if not self_collision:
        p.model = p.model.with_collision(self_collision=False)
    worst, diverged, k, done, retried, refined = 0.0, False, 0, False, [], []
    c0 = time.process_time()
    while not done:
        action = jerk_action(env.action_space, k) if policy == "jerk" else env.action_space.sample()
        _, _, terminated, truncated, info = env.step(action)
        if getattr(p.integrator, "retried", False):
            retried.append(k)
        if getattr(p.integrator, "refined", False):
            refined.append(k)
        k += 1
        done = terminated or truncated
        if info.get("diverged"):
            diverged = True
            break
        worst = max(worst, float(edge_strain(p.model, p.state).max()))
    env.close()
    return {"seed": seed, "diverged": diverged, "steps": k, "max_strain_percent": round(worst, 3),
            "divergence": info.get("divergence") if diverged else None, "retried_steps": retried,
            "refined_steps": refined, "cpu_s": round(time.process_time() - c0, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--id", default="cloth_gym/DrapeOntoTable-v1")
    ap.add_argument("--seeds", type=int, nargs=2, default=[0, 20], metavar=("FIRST", "STOP"),
                    help="episode seeds FIRST..STOP-1")
    ap.add_argument("--sim", type=json.loads, default=None, metavar="JSON",
                    help='the env\'s solver settings to change, e.g. \'{"retry_diverged": true}\'')
    ap.add_argument("--policy", choices=("jerk", "random"), default="jerk",
                    help="jerk (materials ×0.25–4) or seeded random actions (the env's material)")
    ap.add_argument("--no-self-collision", action="store_true", help="the same episodes with the cloth's "
                    "self-collision switched off, for comparison")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    command = f"python scripts/jerk.py --id {args.id} --seeds {args.seeds[0]} {args.seeds[1]}" + (
        f" --sim '{json.dumps(args.sim)}'" if args.sim else "") + (
        " --policy random" if args.policy == "random" else "") + (
        " --no-self-collision" if args.no_self_collision else "") + (f" --out {args.out}" if args.out else "")
    provenance = stamp(command)  # the code the episodes run, read before they start
    t0, c0 = time.perf_counter(), time.process_time()
    eps = []
    for s in range(*args.seeds):
        eps.append(jerk_episode(args.id, s, args.sim, not args.no_self_collision, args.policy))
        e = eps[-1]
        print(f"seed {s}: {'DIVERGED ' if e['diverged'] else ''}{e['steps']} steps, largest strain "
              f"{e['max_strain_percent']:.2f} %, retried steps {e['retried_steps']}, "
              f"{len(e['refined_steps'])} refined, {e['cpu_s']} CPU s", flush=True)
    row = {"env_id": args.id, "sim": args.sim, "policy": args.policy, "self_collision": not args.no_self_collision,
           "seeds": f"{args.seeds[0]}-{args.seeds[1] - 1}",
           "diverged": sum(e["diverged"] for e in eps),
           "max_strain_percent": max(e["max_strain_percent"] for e in eps),
           "cpu_s": round(time.process_time() - c0, 1), "wall_s": round(time.perf_counter() - t0, 1)}
    print(f"{args.id}: {row['diverged']} of {len(eps)} diverge, largest strain {row['max_strain_percent']:.2f} % "
          f"(cpu {row['cpu_s']} s, wall {row['wall_s']} s)")
    if args.out:
        out = {"stamp": provenance, "material": MATERIAL if args.policy == "jerk" else "the env's", **row,
               "episodes": eps}
        Path(args.out).write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
