#!/usr/bin/env python
"""Accuracy and speed of each env's implicit substep: the data behind the default ``sim_dt``.

For every env id, implicit substep (``--sim-dt``) and strain limiter setting
(``--limiter``: ``none``, i.e. off whatever the env's default, or a percent), runs the scripted expert for
``--episodes`` seeded episodes (seeds 100, 101, ...) and records, per episode,
the largest edge strain (percent; the accurate solution's is far below 1 % for
cotton) and success, plus the mean CG iterations and env steps per CPU second.
With ``--reference-dt``, the expert's actions of each episode are first recorded
at that (small) substep, then replayed open loop in every setting: the cloth's
position error against the reference run (cm; RMS over particles and steps, and
the largest) measures what a setting costs in accuracy. ``--tol`` adds solver
tolerances (the env's ``solver_tol``) and ``--vtol`` absolute CG floors (``solver_vtol``, cm/s) to
the sweep, and ``--sim`` further integrator settings (JSON mappings of ``ImplicitEuler``'s
arguments, the env's ``sim``: ``'{"scheme": "bdf2"}'``, ``'{"newton_iters": 2}'``; ``'{}'`` is
the env's own). The reference runs use ``solver_vtol=0`` (the relative test alone).

Writes ``<out>/env_substeps/env_substeps.json`` and prints a table.

    .venv/bin/python scripts/env_substeps.py --ids cloth_gym/CornerLift-v0 --sim-dt 0.01 0.025 --limiter none 2
    .venv/bin/python scripts/env_substeps.py --ids cloth_gym/CornerLift-v0 --sim-dt 0.01 0.05 --limiter none 1 \
        --tol 1e-4 1e-3 --reference-dt 0.001
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import gymnasium as gym  # noqa: E402

import cloth_gym  # noqa: E402,F401  (registers the ids)
from cloth_gym.agents.experts import make_expert  # noqa: E402
from cloth_gym.envs import ENV_SPECS  # noqa: E402
from cloth_gym.reports.options import command_line
from cloth_gym.reports.provenance import stamp  # noqa: E402
from cloth_gym.sim.diagnostics import edge_strain  # noqa: E402


REFERENCE_TOL = 1e-5  # solver tolerance of the reference runs (no strain limiter)


def record_reference(env_id: str, ref_dt: float, episodes: int) -> dict:
    """{seed: (actions, positions after each step)} of the expert at substep ``ref_dt`` s."""
    env = gym.make(env_id, sim_dt=ref_dt, strain_limiter_percent=0, solver_tol=REFERENCE_TOL, solver_vtol=0.0)
    out = {}
    for ep in range(episodes):
        env.reset(seed=100 + ep)
        expert = make_expert(env)
        actions, positions = [], []
        while True:
            a = np.asarray(expert.act(), dtype=np.float64)
            _, _, term, trunc, _ = env.step(a)
            actions.append(a)
            positions.append(env.unwrapped.physics.state.particle_q.copy())
            if term or trunc:
                break
        out[100 + ep] = (actions, positions)
    env.close()
    return out


def replay_error(env, reference: dict) -> tuple[float, float]:
    """(RMS, max) position error, cm, of ``env`` replaying the reference actions open loop."""
    sq, n, worst = 0.0, 0, 0.0
    for seed, (actions, positions) in reference.items():
        env.reset(seed=seed)
        for a, q_ref in zip(actions, positions):
            _, _, term, trunc, info = env.step(a)
            if info.get("diverged", False):
                return math.inf, math.inf
            d = np.linalg.norm(env.unwrapped.physics.state.particle_q - q_ref, axis=1)
            sq += float(np.sum(d * d))
            n += d.size
            worst = max(worst, float(d.max()))
            if term or trunc:
                break
    return math.sqrt(sq / max(n, 1)), worst


def measure(env_id: str, sim_dt: float, limiter: float | None, episodes: int, tol: float | None = None,
            reference: dict | None = None, vtol: float | None = None, sim: dict | None = None) -> dict:
    # limiter None: off (0), whatever the env's default
    env = gym.make(env_id, sim_dt=sim_dt, strain_limiter_percent=0 if limiter is None else limiter, solver_tol=tol,
                   solver_vtol=vtol, **({"sim": sim} if sim else {}))
    env.reset(seed=0)
    env.step(env.action_space.sample())  # warm-up: numba cache load
    strains, successes, diverged, its, steps = [], [], 0, [], 0
    c0 = time.process_time()
    for ep in range(episodes):
        env.reset(seed=100 + ep)
        expert = make_expert(env)
        worst = 0.0
        while True:
            _, _, term, trunc, info = env.step(expert.act())
            steps += 1
            u = env.unwrapped
            worst = max(worst, float(edge_strain(u.physics.model, u.physics.state).max()))
            its.append(float(u.physics.integrator.last_stats[:, 0].mean()))
            if term or trunc:
                break
        strains.append(worst)
        successes.append(bool(info["is_success"]))
        diverged += bool(info.get("diverged", False))
    cpu = time.process_time() - c0
    row = {"env": env_id, "sim_dt_s": sim_dt, "strain_limiter_percent": limiter, "sim": dict(env.unwrapped.sim),
           "solver_tol": env.unwrapped.solver_tol, "solver_vtol_cm_s": env.unwrapped.solver_vtol,
           "episodes": episodes,
           "max_strain_percent": strains, "successes": int(sum(successes)), "diverged": diverged,
           "cg_iterations_mean": float(np.mean(its)), "env_steps_per_cpu_s": steps / cpu}
    if reference is not None:
        row["replay_error_rms_cm"], row["replay_error_max_cm"] = replay_error(env, reference)
    env.close()
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ids", nargs="*", default=list(ENV_SPECS))
    ap.add_argument("--sim-dt", type=float, nargs="+", required=True, help="implicit substeps, s")
    ap.add_argument("--limiter", nargs="+", default=["none"], help="'none' or strain limits in percent")
    ap.add_argument("--tol", type=float, nargs="+", default=[None], help="solver tolerances (default: the env's)")
    ap.add_argument("--vtol", type=float, nargs="+", default=[None],
                    help="absolute CG floors, cm/s (default: the env's solver_vtol)")
    ap.add_argument("--sim", type=json.loads, nargs="+", default=[{}], metavar="JSON",
                    help="integrator settings over the env's (the env's sim mapping), e.g. '{\"scheme\": \"bdf2\"}'")
    ap.add_argument("--reference-dt", type=float, default=None,
                    help="record the expert at this substep (s) and report each setting's replay error")
    ap.add_argument("--episodes", type=int, default=5)
    ap.add_argument("--out", type=Path, default=ROOT / "outputs")
    args = ap.parse_args(argv)
    provenance = stamp(command_line("python scripts/env_substeps.py", sys.argv[1:] if argv is None else argv))
    rows = []
    for env_id in args.ids:
        ref = None if args.reference_dt is None else record_reference(env_id, args.reference_dt, args.episodes)
        for dt in args.sim_dt:
            for lim in args.limiter:
                for tol, vtol, sim in [(t, vt, sm) for t in args.tol for vt in args.vtol for sm in args.sim]:
                    row = measure(env_id, dt, None if lim == "none" else float(lim), args.episodes, tol, ref, vtol,
                                  sim)
                    rows.append(row)
                    err = ("" if ref is None else f", replay error RMS {row['replay_error_rms_cm']:.3f} cm "
                           f"max {row['replay_error_max_cm']:.2f} cm")
                    print(f"{env_id:30s} sim_dt {dt:.4f} {json.dumps(sim) if sim else ''} limiter {lim:>5s} "
                          f"tol {row['solver_tol']:.0e} "
                          f"vtol {row['solver_vtol_cm_s']:.0e}: strain "
                          f"{min(row['max_strain_percent']):.1f}–{max(row['max_strain_percent']):.1f} %, "
                          f"success {row['successes']}/{row['episodes']}, diverged {row['diverged']}, "
                          f"CG {row['cg_iterations_mean']:.1f}, {row['env_steps_per_cpu_s']:.0f} steps/CPU-s{err}",
                          flush=True)
    out = args.out / "env_substeps"
    out.mkdir(parents=True, exist_ok=True)
    doc = {**provenance, "reference_dt_s": args.reference_dt, "rows": rows}
    (out / "env_substeps.json").write_text(json.dumps(doc, indent=2))
    print(f"wrote {out / 'env_substeps.json'}")


if __name__ == "__main__":
    main()
