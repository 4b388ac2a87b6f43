"""Soak run: many env steps under randomised materials and adversarial policies, counting what
went wrong.

For each env id, episodes cycle through both force models (KES, Breen) and the policies below,
with the material drawn at every reset from the base fabric with its stretch, bending, shear and
areal density scaled by ×0.25–4 and friction and damping drawn in [0, 1] and [0, 2] /s. Policies
(per gripper, action ``[dx, dy, dz, grip]``):

* ``random``: uniform in [−1, 1]⁴;
* ``plus_one`` / ``minus_one``: every component +1 (close and climb) or −1 (open and dive);
* ``grip_toggle``: random motion, the grip flipping every step;
* ``bang_bang``: every component ±1 at random;
* ``press_down``: closed, full speed down (into the table or floor);
* ``pull_apart``: closed, the grippers at full speed in opposite directions (one gripper: up);
* ``shake``: closed, full amplitude, the sign flipping every step.

Counted per env: steps, episodes, exceptions (by type; an env must not raise on a valid action),
divergences (truncated episodes with ``info["diverged"]``), NaN/inf observations, observations
outside the observation space, penetration (a free particle inside an obstacle by more than
``--depth`` cm, and the deepest) and strain (steps whose most stretched edge is past the grippers'
slip strain, and the largest).

Writes ``<out>/soak.json`` and ``<out>/soak.md`` (``--docs``: ``docs/soak.md`` and
``docs/data/soak.json``) and prints the table::

    .venv/bin/python scripts/soak.py --steps 100000 --docs
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import cloth_gym  # noqa: E402,F401  (registers the ids)
from cloth_gym.envs import ENV_SPECS  # noqa: E402
from cloth_gym.reports.options import command_line
from cloth_gym.reports.provenance import stamp, stamp_line  # noqa: E402
from cloth_gym.sim.diagnostics import edge_strain, obstacle_penetration  # noqa: E402

POLICIES = ("random", "plus_one", "minus_one", "grip_toggle", "bang_bang", "press_down", "pull_apart", "shake")
MODELS = ("kes", "breen")
RANDOMISED = {"stretch_scale": (0.25, 4.0), "bending_scale": (0.25, 4.0), "shear_scale": (0.25, 4.0),
              "areal_density_scale": (0.25, 4.0), "friction": (0.0, 1.0), "damping": (0.0, 2.0)}


def policy_action(name: str, t: int, n_grippers: int, rng: np.random.Generator) -> np.ndarray:
    """The action of policy ``name`` at step ``t`` of an episode, (4·grippers,) in [−1, 1]."""
    a = np.zeros((n_grippers, 4))
    if name == "random":
        a = rng.uniform(-1, 1, a.shape)
    elif name == "plus_one":
        a[:] = 1.0
    elif name == "minus_one":
        a[:] = -1.0
    elif name == "grip_toggle":
        a = rng.uniform(-1, 1, a.shape)
        a[:, 3] = 1.0 if t % 2 == 0 else -1.0
    elif name == "bang_bang":
        a = rng.choice([-1.0, 1.0], a.shape)
    elif name == "press_down":
        a[:, 2] = -1.0
        a[:, 3] = 1.0
    elif name == "pull_apart":
        a[:, 3] = 1.0
        if n_grippers == 1:
            a[0, 2] = 1.0
        else:
            direction = rng.uniform(-1, 1, 3) if t == 0 else None
            direction = np.array([1.0, 0.0, 0.2]) if direction is None else direction
            a[0, :3], a[1, :3] = direction, -direction
    elif name == "shake":
        a[:, :3] = 1.0 if t % 2 == 0 else -1.0
        a[:, 3] = 1.0
    else:
        raise ValueError(f"unknown policy {name!r}; known: {POLICIES}")
    return a.ravel()


def soak_env(env_id: str, steps: int, seed: int, depth_cm: float) -> dict:
    """``steps`` env steps of ``env_id`` over the models and policies (module docstring)."""
    rng = np.random.default_rng(seed)
    envs = {m: gym.make(env_id, model=m, material={"base": "thick_cotton", **RANDOMISED}) for m in MODELS}
    n_grippers = envs["kes"].unwrapped.n_grippers
    slip = envs["kes"].unwrapped.gripper_config.slip_strain_percent
    c = Counter()
    exceptions: Counter = Counter()
    deepest = (0.0, "")
    max_strain = (0.0, "")
    divergences: list[str] = []  # where each diverged episode ended, and why
    episode = 0
    done_steps = 0
    t_cpu, t_wall = time.process_time(), time.perf_counter()
    while done_steps < steps:
        model = MODELS[episode % len(MODELS)]
        policy = POLICIES[(episode // len(MODELS)) % len(POLICIES)]
        env = envs[model]
        tag = f"{model}/{policy}/episode {episode}"
        obs, _ = env.reset(seed=seed * 100_003 + episode)
        episode += 1
        t = 0
        while done_steps < steps:
            action = policy_action(policy, t, n_grippers, rng)
            try:
                obs, reward, terminated, truncated, info = env.step(action)
            except Exception as err:  # a valid action must never raise: count it and go on
                exceptions[f"{type(err).__module__}.{type(err).__name__}"] += 1
                c["exceptions"] += 1
                break
            done_steps += 1
            t += 1
            parts = obs.values() if isinstance(obs, dict) else [obs]  # a goal env's Dict observation
            if not all(np.all(np.isfinite(a)) for a in parts) or not np.isfinite(reward):
                c["non_finite"] += 1
            if not env.observation_space.contains(obs):
                c["outside_space"] += 1
            if info.get("diverged"):  # the env ended the episode; its physics holds the exploded state
                c["diverged"] += 1
                divergences.append(f"{tag}, step {t}: {info.get('divergence', '')}")
                break
            physics = env.unwrapped.physics
            d, p = obstacle_penetration(physics.model, physics.state, free=physics.grippers.held_by < 0)
            if d > depth_cm:
                c["penetrating_steps"] += 1
            if d > deepest[0]:
                deepest = (d, f"{tag}, step {t}, particle {p}")
            eps = float(edge_strain(physics.model, physics.state).max())
            if eps > slip:
                c["over_slip_strain_steps"] += 1
            if eps > max_strain[0]:
                max_strain = (eps, f"{tag}, step {t}")
            if terminated or truncated:
                break
    cpu, wall = time.process_time() - t_cpu, time.perf_counter() - t_wall
    for env in envs.values():
        env.close()
    return {"env_id": env_id, "steps": done_steps, "episodes": episode, "exceptions": c["exceptions"],
            "exception_types": dict(exceptions), "diverged": c["diverged"], "divergences": divergences,
            "non_finite_obs": c["non_finite"],
            "outside_space": c["outside_space"], "penetrating_steps": c["penetrating_steps"],
            "deepest_penetration_cm": deepest[0], "deepest_where": deepest[1],
            "over_slip_strain_steps": c["over_slip_strain_steps"], "slip_strain_percent": slip,
            "max_strain_percent": max_strain[0], "max_strain_where": max_strain[1],
            "cpu_s": cpu, "wall_s": wall}


def table(rows: list[dict], depth_cm: float) -> str:
    head = ("| env | steps | episodes | exceptions | diverged | NaN/inf obs | outside space | "
            f"steps > {depth_cm:g} cm deep | deepest (cm) | steps past slip strain | max strain (%) | CPU s |")
    lines = [head, "|" + "---|" * 12]
    for r in rows:
        lines.append(f"| {r['env_id']} | {r['steps']:,} | {r['episodes']:,} | {r['exceptions']} | {r['diverged']} | "
                     f"{r['non_finite_obs']} | {r['outside_space']} | {r['penetrating_steps']:,} | "
                     f"{r['deepest_penetration_cm']:.2f} | {r['over_slip_strain_steps']:,} | "
                     f"{r['max_strain_percent']:.0f} | {r['cpu_s']:.0f} |")
    return "\n".join(lines)


def docs_page(rows: list[dict], meta: dict) -> str:
    """``docs/soak.md``: the table, what each column counts, and where the worst cases were."""
    worst = "\n".join(f"* {r['env_id']}: deepest penetration {r['deepest_penetration_cm']:.2f} cm "
                      f"({r['deepest_where'] or 'none'}); largest strain {r['max_strain_percent']:.0f} % "
                      f"({r['max_strain_where']}); exceptions {r['exception_types'] or 'none'}"
                      + "".join(f"\n  * diverged: {d}" for d in r.get("divergences", [])) for r in rows)
    scales = ", ".join(f"{k} {lo:g}–{hi:g}" for k, (lo, hi) in meta["randomised"].items())
    return f"""# Soak run

Many env steps per env under randomised materials and adversarial policies, counting what went
wrong.

{stamp_line(meta)}

Each env cycles its episodes through the force models ({', '.join(meta['models'])}) and the
policies {', '.join(f'`{p}`' for p in meta['policies'])} (`scripts/soak.py` says what each does);
the material is drawn at every reset from thick cotton with {scales}.

{table(rows, meta['depth_cm'])}

* **exceptions**: any exception out of `env.step` on a valid action (there should be none).
* **diverged**: episodes truncated with `info["diverged"] = True` (the simulation exploded and the
  env ended the episode with the last finite observation).
* **NaN/inf obs**, **outside space**: observations with a non-finite entry, or not in the
  observation space.
* **steps > {meta['depth_cm']:g} cm deep**: steps that left an ungrasped particle that far inside the
  table, floor or another obstacle; **deepest**: the largest such depth.
* **steps past slip strain**: steps whose most stretched lattice edge is past the grippers' slip
  strain (a grasp slips there); **max strain**: the largest edge strain seen.

Worst cases:

{worst}
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=100_000, help="env steps per env id")
    ap.add_argument("--env", action="append", choices=sorted(ENV_SPECS), help="env ids (default: all)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--depth", type=float, default=0.5, help="penetration counted beyond this depth, cm")
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "soak")
    ap.add_argument("--docs", action="store_true", help="also write docs/soak.md and docs/data/soak.json")
    args = ap.parse_args(argv)
    provenance = stamp(command_line("python scripts/soak.py", sys.argv[1:] if argv is None else argv))
    if args.steps < 1:
        ap.error("--steps must be >= 1")
    rows = []
    for env_id in args.env or sorted(ENV_SPECS):
        rows.append(soak_env(env_id, args.steps, args.seed, args.depth))
        print(table(rows[-1:], args.depth).splitlines()[-1], flush=True)
    meta = {**provenance,
            "policies": list(POLICIES), "models": list(MODELS), "randomised": RANDOMISED, "depth_cm": args.depth}
    report = {"meta": meta, "rows": rows}
    text = table(rows, args.depth)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "soak.json").write_text(json.dumps(report, indent=2))
    (args.out / "soak.md").write_text(text + "\n")
    if args.docs:
        (ROOT / "docs" / "data" / "soak.json").write_text(json.dumps(report, indent=2))
        (ROOT / "docs" / "soak.md").write_text(docs_page(rows, meta))
    bad = sum(r["exceptions"] + r["non_finite_obs"] + r["outside_space"] for r in rows)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
