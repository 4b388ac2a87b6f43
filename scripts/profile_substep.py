"""Where an env's step spends its time: the integrator's phase profile, summed over expert-driven steps.

For each env id, ``--steps`` env steps driven by the env's scripted expert (the cloth manipulated
all episode; ``cloth_gym.agents.experts``), episodes reset as they end. Each integrator call reports
its time per phase (``ImplicitEuler.last_profile``: forces, assembly, factor, solve, friction,
collision, ...; read from the CPU's cycle counter); the env's own share is the step's wall time
outside the integrator's call (actions, grippers, rewards, observations). Prints, per phase, the
microseconds per substep and the share of the env step's wall time, then how much of the solves
went to the operator's products and the preconditioner (``ImplicitEuler.last_cg_profile``), and writes
``outputs/profile/profile.json`` (with ``--docs`` also ``docs/data/profile.json``).

    .venv/bin/python scripts/profile_substep.py --ids cloth_gym/CornerLift-v1 cloth_gym/RibbonDrop-v1 --steps 300
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import gymnasium as gym  # noqa: E402

import cloth_gym  # noqa: E402,F401  (registers the ids)
from cloth_gym.reports.options import command_line  # noqa: E402
from cloth_gym.reports.provenance import load_average, stamp, write_results  # noqa: E402

V1_IDS = ["cloth_gym/CornerLift-v1", "cloth_gym/DrapeOntoTable-v1", "cloth_gym/RibbonDrop-v1"]


def profile_env(env_id: str, steps: int, seed: int = 0) -> dict:
    """``steps`` expert-driven env steps of ``env_id``: phase seconds summed over the integrator's
    calls, substeps, the env's own time and the totals."""
    from cloth_gym.agents.experts import make_expert

    env = gym.make(env_id)
    env.reset(seed=seed)
    env.action_space.seed(seed)
    for _ in range(3):  # warm-up: kernels loaded or compiled, first reset
        env.step(env.action_space.sample())
    env.reset(seed=seed + 1)
    expert = make_expert(env)
    phases: dict[str, float] = {}
    cg: dict[str, float] = {}
    substeps = 0
    wall = 0.0
    c = time.process_time()
    for _ in range(steps):
        t = time.perf_counter()
        _, _, term, trunc, _ = env.step(expert.act())
        wall += time.perf_counter() - t
        integ = env.unwrapped.physics.integrator
        prof = integ.last_profile
        if prof is None:
            raise RuntimeError(f"{env_id}: the integrator reports no phase profile on this platform")
        for k, v in prof.items():
            phases[k] = phases.get(k, 0.0) + v
        for k, v in integ.last_cg_profile.items():
            cg[k] = cg.get(k, 0.0) + v
        substeps += len(integ.last_stats)
        if term or trunc:
            env.reset()
            expert = make_expert(env)
    cpu = time.process_time() - c
    env.close()
    env_own = max(0.0, wall - phases["total"])
    return {"env_steps": steps, "substeps": substeps, "wall_s": wall, "cpu_s": cpu,
            "env_steps_per_cpu_s": steps / cpu, "integrator_s": phases.pop("total"), "env_s": env_own,
            "phases_s": phases, "cg_s": cg}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ids", nargs="*", default=V1_IDS, help="env ids (default: the v1 envs)")
    ap.add_argument("--steps", type=int, default=300, help="expert-driven env steps per env")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=ROOT / "outputs", help="writes OUT/profile/profile.json")
    ap.add_argument("--docs", action="store_true", help="also write docs/data/profile.json")
    args = ap.parse_args(argv)

    provenance = stamp(command_line("python scripts/profile_substep.py", sys.argv[1:] if argv is None else argv))
    results = {**provenance,
               "machine": {**provenance["machine"],
                           "load_average_at_start": load_average()},
               "note": "seconds summed over the env steps; phases as ImplicitEuler.last_profile; env_s: the env "
                       "step's wall time outside the integrator's call; cg_s: ImplicitEuler.last_cg_profile, the "
                       "PCG solves' products and preconditioner applies (part of the solve, friction and newton "
                       "phases)",
               "envs": {}}
    for env_id in args.ids:
        row = profile_env(env_id, args.steps, args.seed)
        results["envs"][env_id] = row
        per_sub = 1e6 / max(row["substeps"], 1)
        print(f"{env_id}: {row['env_steps_per_cpu_s']:.1f} env steps per CPU s, "
              f"{row['substeps'] / row['env_steps']:.2f} substeps per env step")
        parts = {**row["phases_s"], "env (outside the integrator)": row["env_s"]}
        for name, sec in sorted(parts.items(), key=lambda kv: -kv[1]):
            if sec > 0.0:
                print(f"    {name:30s} {sec * per_sub:9.1f} us/substep  {100 * sec / row['wall_s']:5.1f} %")
        solves = sum(row["phases_s"][k] for k in ("solve", "friction", "newton"))
        for name, sec in row["cg_s"].items():
            print(f"    of the solves: {name:15s} {sec * per_sub:9.1f} us/substep  {100 * sec / row['wall_s']:5.1f} %"
                  f"  ({100 * sec / max(solves, 1e-12):.0f} % of solve, friction and newton)")
    write_results(results, args.out / "profile" / "profile.json", ROOT / "docs" / "data" / "profile.json" if args.docs else None)
    return results


if __name__ == "__main__":
    main()
