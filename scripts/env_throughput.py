"""Env steps per second of each cloth_gym env with random actions, and with its scripted expert.

For every registered id: a single env (one process, one core), and 2 envs in
``gymnasium.vector.SyncVectorEnv`` (one process) and ``AsyncVectorEnv`` (two
worker processes). Env steps count every sub-env's step (a vector step of 2
envs is 2 env steps). Episodes are reset when they end; the timing excludes a
warm-up (numba compile / cache load, first reset). Optionally
(``--sim-dt``) the single-env rate and the divergences under random actions
are measured for several implicit substeps, the data behind each env's
default ``sim_dt``. An env class with ``FAST_OPTIONS`` (CornerLift) is also measured with them.
With ``--batched N``, N envs from ``gymnasium.make_vec(id, N, vectorization_mode="vector_entry_point")``
(one process, the cloths' physics in parallel threads) are timed with the expert and with random
actions and sleeping off, the figures to hold against the single env's, and with the expert on one
thread (the threads' own gain). ``--batched N --rounds K`` measures only the batch's expert (2 threads, 1
thread) and one env's expert over the same episode segments, alternated K times, and reports the
median ratios (``throughput_batched.json``). ``--batched N --lockstep`` steps the batch on one thread and on
numba's threads (``--threads 4 8 16``: on each of these counts) in lockstep over the same expert
episodes: the threads' gain at the same moments of a drifting machine, with the threads' busy share,
a sub-env's step time in a thread and the load imbalance in PCG iterations (``throughput_lockstep.json``).

Random actions rarely grasp: in CornerLift the cloth then lies still on its table and the
implicit integrator lets it *sleep* (``sleep_speed``), so that rate is mostly the env's Python.
Each env is therefore also measured driven by its scripted expert (``cloth_gym.agents.experts``: the
cloth manipulated all episode, the cost of the simulation itself) and with random actions but
sleeping off (``sleep_speed=0``); ``asleep_fraction`` is the share of steps that found the cloth
asleep.

Writes ``outputs/env_throughput/throughput.json`` (and, with ``--docs``,
``docs/data/env_throughput.json``) and prints a table.

    .venv/bin/python scripts/env_throughput.py --steps 300 --docs
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path


ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import cloth_gym  # noqa: E402,F401  (registers the ids)
from cloth_gym.envs import ENV_SPECS  # noqa: E402
from cloth_gym.reports.options import command_line
from cloth_gym.reports.provenance import load_average, stamp, write_results  # noqa: E402


def _out_file(out: Path, name: str) -> Path:
    """``--out``'s file: ``out`` itself where it names a .json file, else ``name`` in the folder ``out``."""
    return out if out.suffix == ".json" else out / name


def _warmed_up(env_id: str, seed: int, **kwargs):
    """``gym.make(env_id, **kwargs)`` after a reset and three random steps (numba's compile or cache
    load, the first reset), its action space seeded with ``seed``."""
    env = gym.make(env_id, **kwargs)
    env.reset(seed=seed)
    env.action_space.seed(seed)
    for _ in range(3):
        env.step(env.action_space.sample())
    return env


def single(env_id: str, steps: int, seed: int = 0, policy: str = "random", **kwargs) -> dict:
    """One env, ``steps`` steps of ``policy`` (``"random"`` or ``"expert"``)."""
    from cloth_gym.agents.experts import make_expert

    env = _warmed_up(env_id, seed, **kwargs)
    env.reset(seed=seed + 1)
    expert = make_expert(env) if policy == "expert" else None
    integ = env.unwrapped.physics.integrator
    diverged = resets = asleep = 0
    c = time.process_time()
    t = time.perf_counter()
    for _ in range(steps):
        _, _, term, trunc, info = env.step(env.action_space.sample() if expert is None else expert.act())
        asleep += bool(getattr(integ, "asleep", False))
        if term or trunc:
            diverged += bool(info["diverged"])
            resets += 1
            env.reset()
            expert = make_expert(env) if policy == "expert" else None
            integ = env.unwrapped.physics.integrator
    wall = time.perf_counter() - t
    cpu = time.process_time() - c
    env.close()
    return {"policy": policy, "env_steps": steps, "wall_s": wall, "env_steps_per_s": steps / wall, "cpu_s": cpu,
            "env_steps_per_cpu_s": steps / cpu, "episodes_ended": resets, "diverged": diverged,
            "asleep_fraction": asleep / steps}


def vector(env_id: str, steps: int, n_envs: int, kind: str, seed: int = 0) -> dict:
    fns = [lambda: gym.make(env_id) for _ in range(n_envs)]
    venv = gym.vector.SyncVectorEnv(fns) if kind == "sync" else gym.vector.AsyncVectorEnv(fns)
    venv.reset(seed=seed)
    venv.action_space.seed(seed)
    for _ in range(3):
        venv.step(venv.action_space.sample())
    n = max(1, steps // n_envs)
    t = time.perf_counter()
    for _ in range(n):
        venv.step(venv.action_space.sample())  # autoreset inside
    wall = time.perf_counter() - t
    venv.close()
    return {"n_envs": n_envs, "vector_steps": n, "env_steps": n * n_envs, "wall_s": wall,
            "env_steps_per_s": n * n_envs / wall}


def batched(env_id: str, steps: int, n_envs: int, policy: str = "random", seed: int = 0,
            threads: int | None = None, **kwargs) -> dict:
    """``gymnasium.make_vec(env_id, n_envs, vectorization_mode="vector_entry_point")``: the sub-envs
    stepped in one call, their physics in parallel threads; ``policy`` drives every sub-env."""
    from gymnasium.vector import AutoresetMode

    from cloth_gym.agents.experts import make_expert

    venv = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point", threads=threads,
                        autoreset_mode=AutoresetMode.SAME_STEP, **kwargs)
    subs = venv.unwrapped.envs
    venv.reset(seed=seed)
    venv.action_space.seed(seed)
    for _ in range(3):  # warm-up
        venv.step(venv.action_space.sample())
    venv.reset(seed=seed + 1)
    experts = [make_expert(e) for e in subs] if policy == "expert" else None
    n = max(1, steps // n_envs)
    diverged = ended = 0
    busy = 0.0
    c = time.process_time()
    t = time.perf_counter()
    for _ in range(n):
        act = venv.action_space.sample() if experts is None else np.stack([x.act() for x in experts])
        _, _, term, trunc, info = venv.step(act)
        busy += float(venv.unwrapped.last_step_seconds.sum())
        for i in np.flatnonzero(term | trunc):
            ended += 1
            diverged += bool(info["final_info"]["diverged"][i])
            if experts is not None:
                experts[i] = make_expert(subs[i])
    wall = time.perf_counter() - t
    cpu = time.process_time() - c
    out = {"policy": policy, "n_envs": n_envs, "threads": venv.unwrapped.threads, "vector_steps": n,
           "env_steps": n * n_envs, "wall_s": wall, "cpu_s": cpu, "env_steps_per_s": n * n_envs / wall,
           "env_steps_per_cpu_s": n * n_envs / cpu, "episodes_ended": ended, "diverged": diverged,
           "threads_busy_share": busy / (venv.unwrapped.threads * wall)}
    venv.close()
    return out


def same_episodes(env_id: str, steps: int, n_envs: int, seed: int = 0) -> dict:
    """One env driven by the expert over the episode segments that :func:`batched` steps with the
    same arguments: ``steps // n_envs`` steps from the start of each of the episodes of seeds
    ``seed + 1 ... seed + n_envs``, one after another (an expert's step costs more in some phases of
    an episode than in others, so a comparison with the batch needs the same segments)."""
    from cloth_gym.agents.experts import make_expert

    env = _warmed_up(env_id, seed)
    k = max(1, steps // n_envs)
    wall = cpu = 0.0
    for i in range(n_envs):
        env.reset(seed=seed + 1 + i)
        expert = make_expert(env)
        c = time.process_time()
        t = time.perf_counter()
        for _ in range(k):
            env.step(expert.act())
        wall += time.perf_counter() - t
        cpu += time.process_time() - c
    env.close()
    return {"policy": "expert", "episodes": n_envs, "env_steps": k * n_envs, "wall_s": wall, "cpu_s": cpu,
            "env_steps_per_s": k * n_envs / wall, "env_steps_per_cpu_s": k * n_envs / cpu}


def alternated(env_id: str, steps: int, n_envs: int, rounds: int) -> dict:
    """``rounds`` rounds, each one env's expert over the batch's episode segments
    (:func:`same_episodes`), then the N-env batch's (numba's threads), then the batch's on one
    thread: on a shared machine whose speed drifts, the ratios within a round are steadier than
    rates measured minutes apart."""
    out = []
    for _ in range(rounds):
        one = same_episodes(env_id, steps, n_envs)
        many = batched(env_id, steps, n_envs, policy="expert")
        serial = batched(env_id, steps, n_envs, policy="expert", threads=1)
        out.append({"single_expert_same_episodes": one, "batched_expert": many, "batched_expert_one_thread": serial})

    def spread(values):
        return {"median": float(np.median(values)), "min": min(values), "max": max(values)}

    rate = lambda r, k: r[k]["env_steps_per_s"]  # noqa: E731
    return {"n_envs": n_envs, "threads": out[0]["batched_expert"]["threads"], "rounds": out,
            "batched_over_single": spread([rate(r, "batched_expert") / rate(r, "single_expert_same_episodes")
                                          for r in out]),
            "threads_over_one_thread": spread([rate(r, "batched_expert") / rate(r, "batched_expert_one_thread")
                                               for r in out]),
            "threads_busy_share": spread([r["batched_expert"]["threads_busy_share"] for r in out])}


def lockstep(env_id: str, steps: int, n_envs: int, thread_counts: list[int] | None = None, seed: int = 0) -> dict:
    """The N-env batch at each of ``thread_counts`` threads (1 among them; default: 1 and the batch's
    default, numba's thread count) stepped in lockstep: the same episodes and expert actions, the
    batches taking turns at going first, so that all meet the machine at the same moments (where
    its speed drifts by tens of percent within minutes, their ratios are steadier than those of
    runs minutes apart). Their observations are checked equal at every step. Per thread count: env
    steps per second and per CPU second, the ratio to one thread, the threads' busy share, a
    sub-env's step time (wall and CPU) in a thread against one thread's, and the load imbalance in
    PCG iterations (per vector step, the busiest thread's sum over the mean thread's)."""
    from gymnasium.vector import AutoresetMode

    from cloth_gym.agents.experts import make_expert

    counts = [1, *sorted(set(thread_counts) - {1})] if thread_counts else [1, None]
    venvs = [gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point", threads=t,
                          autoreset_mode=AutoresetMode.SAME_STEP) for t in counts]
    for v in venvs:
        v.reset(seed=seed + 1)
    subs = venvs[0].unwrapped.envs
    experts = [make_expert(e) for e in subs]
    warm, n, m = 3, max(1, steps // n_envs), len(counts)
    acc = {key: np.zeros(m) for key in ("wall", "cpu", "busy", "busy_cpu", "imbalance")}
    ratios = [[] for _ in counts]
    for k in range(warm + n):
        act = np.stack([x.act() for x in experts])
        out, dt = [None] * m, np.zeros(m)
        for j in np.roll(np.arange(m), -k):  # each batch goes first in turn
            u = venvs[j].unwrapped
            c, t = time.process_time(), time.perf_counter()
            out[j] = venvs[j].step(act)
            dt[j] = time.perf_counter() - t
            if k >= warm:
                acc["wall"][j] += dt[j]
                acc["cpu"][j] += time.process_time() - c
                acc["busy"][j] += float(u.last_step_seconds.sum())
                acc["busy_cpu"][j] += float(u.last_step_cpu_seconds.sum())
                acc["imbalance"][j] += _cg_imbalance(u)
        for j in range(1, m):
            if not np.array_equal(out[0][0], out[j][0]):
                raise RuntimeError(f"{env_id}: the batch on {venvs[j].unwrapped.threads} threads and on one differ "
                                   f"at vector step {k}")
        if k >= warm:
            for j in range(m):
                ratios[j].append(dt[0] / dt[j])
        for i in np.flatnonzero(out[0][2] | out[0][3]):
            experts[i] = make_expert(subs[i])
    rows = []
    for j, v in enumerate(venvs):
        t = v.unwrapped.threads
        v.close()
        rows.append({"threads": t, "wall_s": acc["wall"][j], "cpu_s": acc["cpu"][j],
                     "env_steps_per_s": n * n_envs / acc["wall"][j], "env_steps_per_cpu_s": n * n_envs / acc["cpu"][j],
                     "env_step_thread_ms": 1e3 * acc["busy"][j] / (n * n_envs),
                     "env_step_thread_cpu_ms": 1e3 * acc["busy_cpu"][j] / (n * n_envs),
                     "env_step_not_running_share": 1.0 - acc["busy_cpu"][j] / acc["busy"][j],
                     "threads_busy_share": acc["busy"][j] / (t * acc["wall"][j]),
                     "cg_iterations_busiest_thread_over_mean": acc["imbalance"][j] / n,
                     "over_one_thread": acc["wall"][0] / acc["wall"][j],
                     "per_step_ratio_median": float(np.median(ratios[j])),
                     "env_step_slowdown": acc["busy"][j] / acc["busy"][0],
                     "env_step_cpu_rise": acc["busy_cpu"][j] / acc["busy_cpu"][0]})
    one, many = rows[0], rows[-1]
    return {"policy": "expert", "n_envs": n_envs, "vector_steps": n, "one_thread": one, "threads": many,
            "by_threads": rows, "threads_over_one_thread": many["over_one_thread"],
            "per_step_ratio_median": many["per_step_ratio_median"], "env_step_slowdown": many["env_step_slowdown"],
            "env_step_cpu_rise": many["env_step_cpu_rise"]}


def _cg_imbalance(venv) -> float:
    """The last vector step's PCG iterations summed per thread: the busiest thread's over the mean
    thread's (1: balanced; a sub-env reset in the step counts none)."""
    per_thread = np.zeros(venv.threads)
    for env, thread in zip(venv.envs, venv.last_step_threads):
        stats = getattr(env.unwrapped.physics.integrator, "last_stats", np.zeros((0, 1)))
        per_thread[thread] += float(stats[:, 0].sum()) if len(stats) else 0.0
    mean = per_thread.mean()
    return float(per_thread.max() / mean) if mean > 0 else 1.0


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=300, help="env steps timed per measurement")
    ap.add_argument("--ids", nargs="*", default=list(ENV_SPECS), help="env ids (default: all)")
    ap.add_argument("--n-envs", type=int, default=2)
    ap.add_argument("--no-vector", action="store_true", help="single env only")
    ap.add_argument("--batched", type=int, default=0, metavar="N",
                    help="also time N envs batched (make_vec's vector entry point), with the expert and with "
                         "random actions and sleeping off, next to the single env's same figures")
    ap.add_argument("--rounds", type=int, default=0, metavar="K",
                    help="with --batched N: only measure K alternated rounds of one env's expert over the batch's "
                         "episodes, the batch's and the batch on one thread (the ratios on a noisy machine); writes "
                         "throughput_batched.json (docs/data/env_throughput_batched.json)")
    ap.add_argument("--lockstep", action="store_true",
                    help="with --batched N: only measure the batch on one thread and on numba's threads (or on "
                         "--threads) stepped in lockstep over the same expert episodes; writes "
                         "throughput_lockstep.json")
    ap.add_argument("--threads", type=int, nargs="+", default=None, metavar="T",
                    help="with --lockstep: the thread counts to step in lockstep (one thread is always among them; "
                         "default: numba's thread count)")
    ap.add_argument("--sim-dt", type=float, nargs="*", default=[],
                    help="also measure the single env at these implicit substeps (s)")
    ap.add_argument("--seeds", type=int, default=0,
                    help="also time the single env (default and FAST_OPTIONS) on this many seeds (0, 7, 14, ...): "
                         "how much the random-action rate depends on the episodes drawn")
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "env_throughput",
                    help="a folder (throughput.json, throughput_batched.json in it) or a .json file")
    ap.add_argument("--docs", action="store_true", help="also write docs/data/env_throughput.json")
    args = ap.parse_args(argv)

    provenance = stamp(command_line("python scripts/env_throughput.py", sys.argv[1:] if argv is None else argv))
    results = {
        **provenance,
        "machine": {**provenance["machine"], "cpu_count": os.cpu_count(),
                    "load_average_at_start": load_average()},
        "note": "random actions unless policy is 'expert'; env steps per wall-clock second (and, for the single env, per CPU "
                "second of the process: the one-core rate, less sensitive to a shared machine); "
                "one env = one process on one core; see load_average_at_start",
        "envs": {},
    }
    if args.lockstep:
        if not args.batched:
            ap.error("--lockstep needs --batched N")
        for env_id in args.ids:
            row = results["envs"][env_id] = lockstep(env_id, args.steps, args.batched, args.threads)
            for r in row["by_threads"][1:]:
                print(f"{env_id:32s} {args.batched} batched, {r['threads']} threads / 1 in lockstep: "
                      f"{r['over_one_thread']:.3f} (per vector step, median {r['per_step_ratio_median']:.3f}); "
                      f"a sub-env's step {r['env_step_slowdown']:.3f}x as long in a thread (CPU "
                      f"{r['env_step_cpu_rise']:.3f}x, not running {r['env_step_not_running_share']:.3f}); threads "
                      f"busy {r['threads_busy_share']:.3f} of the time; PCG iterations, busiest thread / mean "
                      f"{r['cg_iterations_busiest_thread_over_mean']:.3f}", flush=True)
        write_results(results, _out_file(args.out, "throughput_lockstep.json"))
        return results
    if args.rounds:
        if not args.batched:
            ap.error("--rounds needs --batched N")
        for env_id in args.ids:
            row = results["envs"][env_id] = alternated(env_id, args.steps, args.batched, args.rounds)
            print(f"{env_id:32s} {args.batched} batched / single expert: median "
                  f"{row['batched_over_single']['median']:.2f} ({row['batched_over_single']['min']:.2f}–"
                  f"{row['batched_over_single']['max']:.2f}); {row['threads']} threads / 1: median "
                  f"{row['threads_over_one_thread']['median']:.2f} ({row['threads_over_one_thread']['min']:.2f}–"
                  f"{row['threads_over_one_thread']['max']:.2f}); threads busy "
                  f"{row['threads_busy_share']['median']:.3f} of the time", flush=True)
        write_results(results, _out_file(args.out, "throughput_batched.json"),
                      ROOT / "docs" / "data" / "env_throughput_batched.json" if args.docs else None)
        return results
    for env_id in args.ids:
        u = gym.make(env_id).unwrapped
        row = {"defaults": {"sigma_cm": u.sigma, "particles": u._model.particle_count,
                            "control_dt_s": u.control_dt, "sim_dt_s": u.sim_dt, "integrator": u.integrator_kind,
                            "max_episode_steps": ENV_SPECS[env_id][1]}}
        row["single"] = single(env_id, args.steps)
        row["single_expert"] = single(env_id, args.steps, policy="expert")
        row["single_no_sleep"] = {"options": {"sleep_speed": 0.0}, **single(env_id, args.steps, sleep_speed=0.0)}
        if not args.no_vector:
            row["sync_vector"] = vector(env_id, args.steps, args.n_envs, "sync")
            row["async_vector"] = vector(env_id, args.steps, args.n_envs, "async")
        if args.batched:
            row["batched_expert"] = batched(env_id, args.steps, args.batched, policy="expert")
            # the same batch on one thread: what the threads gain, apart from what batching costs
            row["batched_expert_one_thread"] = batched(env_id, args.steps, args.batched, policy="expert", threads=1)
            row["batched_no_sleep"] = {"options": {"sleep_speed": 0.0},
                                       **batched(env_id, args.steps, args.batched, sleep_speed=0.0)}
        # a task's FAST_OPTIONS were measured on its v0 lattice: not for the ids that set other kwargs
        fast = None if ENV_SPECS[env_id].kwargs else getattr(type(u), "FAST_OPTIONS", None)
        if fast:  # the env's documented fast integrator options (CornerLift)
            row["single_fast_options"] = {"options": fast, **single(env_id, args.steps, **fast)}
            row["single_fast_options_expert"] = {"options": fast,
                                                 **single(env_id, args.steps, policy="expert", **fast)}
        if args.seeds:
            row["single_per_seed"] = [{"seed": 7 * k, **single(env_id, args.steps, seed=7 * k)}
                                      for k in range(args.seeds)]
            if fast:
                row["single_fast_options_per_seed"] = [{"seed": 7 * k, "options": fast,
                                                        **single(env_id, args.steps, seed=7 * k, **fast)}
                                                       for k in range(args.seeds)]
        if args.sim_dt:
            row["sim_dt_sweep"] = [{"sim_dt_s": dt, **single(env_id, args.steps, sim_dt=dt)} for dt in args.sim_dt]
        results["envs"][env_id] = row
        line = (f"{env_id:32s} N={row['defaults']['particles']:4d}  single {row['single']['env_steps_per_s']:8.1f}/s"
                f" ({row['single']['env_steps_per_cpu_s']:.1f}/CPU-s)")
        if not args.no_vector:
            line += (f"  sync x{args.n_envs} {row['sync_vector']['env_steps_per_s']:8.1f}/s"
                     f"  async x{args.n_envs} {row['async_vector']['env_steps_per_s']:8.1f}/s")
        line += f"  asleep {row['single']['asleep_fraction']:.2f}"
        print(line, flush=True)
        for key, label in (("single_expert", "expert actions"), ("single_no_sleep", "random, sleep off"),
                           ("batched_expert", f"batched x{args.batched} expert"),
                           ("batched_expert_one_thread", f"batched x{args.batched} expert, 1 thread"),
                           ("batched_no_sleep", f"batched x{args.batched} random, sleep off"),
                           ("single_fast_options", "FAST_OPTIONS random"),
                           ("single_fast_options_expert", "FAST_OPTIONS expert")):
            if key in row:
                f = row[key]
                asleep = f"asleep {f['asleep_fraction']:.2f}, " if "asleep_fraction" in f else ""
                print(f"    {label:22s}: {f['env_steps_per_s']:8.1f}/s ({f['env_steps_per_cpu_s']:.1f}/CPU-s), "
                      f"{asleep}diverged {f['diverged']}", flush=True)
        for key in ("single_per_seed", "single_fast_options_per_seed"):
            if key in row:
                rates = [r["env_steps_per_s"] for r in row[key]]
                print(f"    {key}: {min(rates):.0f}–{max(rates):.0f}/s (median {sorted(rates)[len(rates) // 2]:.0f}), "
                      f"asleep {min(r['asleep_fraction'] for r in row[key]):.2f}–"
                      f"{max(r['asleep_fraction'] for r in row[key]):.2f}", flush=True)
        for s in row.get("sim_dt_sweep", []):
            print(f"    sim_dt {s['sim_dt_s']:.4f} s: {s['env_steps_per_s']:8.1f}/s, diverged {s['diverged']}", flush=True)

    write_results(results, _out_file(args.out, "throughput.json"), ROOT / "docs" / "data" / "env_throughput.json" if args.docs else None)
    return results


if __name__ == "__main__":
    main()
