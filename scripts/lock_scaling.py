"""How far the interpreter lock lets a batch of cloths scale with threads, measured on any machine.

A batched env (``gymnasium.make_vec(id, N, vectorization_mode="vector_entry_point")``) steps its
cloths on several threads; each cloth's implicit kernel runs without the interpreter lock, the
rest of an env step holds it (actions into grippers, observations, rewards, ``info``, passing the
kernel its arguments). With one core per thread, the lock and the schedule's idle tail are what is
left to bound the batch. This script measures that bound on a machine with fewer cores than
threads:

1. it steps the batch on one thread over the scripted experts' episodes and records, per sub-env,
   every call of the implicit kernel: its wall time, its return value and the arrays it wrote
   (positions, velocities, the solver's carry and statistics); then it times, per sub-env, a call
   of the kernel for no substep on its last arguments: the part of a call that holds the lock
   (passing the arguments and the return value), with the kernel's set-up, which does not (an
   upper bound);
2. it replays the same episodes on 1, and on each of ``--threads``, threads with every recorded
   kernel call replaced by a spin holding the lock for as long as that call for no substep, then a
   sleep for the rest of the call's recorded time (the lock released, no core used), and the
   recorded arrays written back. Everything else an env step does runs as in training, and the
   replay's observations are checked equal to the recorded ones at every step.

The replay's speed-up over one thread is then what the batch reaches with a core per thread and
nothing shared but the lock: no memory bandwidth, caches or clock shared between cores. The
measured batch on a many-core machine (``scripts/env_throughput.py --lockstep``) can only be
slower. Per thread count the JSON has the speed-up, the threads' busy share, a sub-env step's
share spent waiting (not in its sleep and not running: the lock, or a sleep's overshoot) and the
share of a sub-env step that holds the lock (its CPU time over its wall time on one thread).
``--processes 2 4`` also replays each thread count T as P forked processes of N/P envs on T/P
threads each, started together: the layout of Ray actors (``RayVecEnv`` with
``threads_per_actor``), each process with a lock of its own.

    .venv/bin/python scripts/lock_scaling.py --ids cloth_gym/CornerLift-v2 --batched 64 --threads 4 8 16 \
        --processes 1 2 4 --steps 8320
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
from gymnasium.vector import AutoresetMode  # noqa: E402

import cloth_gym  # noqa: E402,F401  (registers the ids)
from cloth_gym.agents.experts import make_expert  # noqa: E402
from cloth_gym.envs.vector import BatchedVectorEnv  # noqa: E402
from cloth_gym.reports.options import command_line  # noqa: E402
from cloth_gym.reports.provenance import load_average, stamp, write_results  # noqa: E402
from cloth_gym.sim.bundles import PROFILE_SIZE  # noqa: E402
from cloth_gym.sim.implicit.step import run_implicit  # noqa: E402
from cloth_gym.sim.solver import SolverBase  # noqa: E402


def _written(args) -> list[np.ndarray]:
    """The arrays ``run_implicit(n, h, q, qd, inv_mass, wind, stats, options, guard, carry, ...)``
    writes: positions, velocities, per-substep statistics and the carry's arrays."""
    return [args[2], args[3], args[6], *args[9]]


class KernelTape:
    """Per sub-env, the implicit kernel's calls in order, recorded or replayed by
    :meth:`recording` / :meth:`replaying` (which patch ``SolverBase._timed`` and
    ``BatchedVectorEnv._step_one`` for the duration)."""

    def __init__(self, n_envs: int):
        self.calls: list[list] = [[] for _ in range(n_envs)]  # (seconds, return, arrays) per call
        self.held = np.zeros(n_envs)  # seconds of a call that hold the lock, per sub-env (:meth:`time_held`)
        self._last_args: list = [None] * n_envs
        self.next = np.zeros(n_envs, dtype=np.int64)
        self.slept = np.zeros(n_envs)  # seconds each sub-env's last step slept in replayed kernels
        self._local = threading.local()

    def _record(self, i, solver, kernel, args):
        prof = np.zeros(PROFILE_SIZE, dtype=np.int64)
        t = time.perf_counter()
        out = kernel(*args, prof)
        wall = time.perf_counter() - t
        solver._profile = (prof, wall)
        self.calls[i].append((wall, out, [a.copy() for a in _written(args)]))
        self._last_args[i] = args
        return out

    def time_held(self, repeats: int = 5) -> None:
        """Per sub-env, the fastest of ``repeats`` kernel calls for no substep on copies of its last
        call's arguments: :attr:`held`."""
        for i, args in enumerate(self._last_args):
            if args is None:
                continue
            copies = [a.copy() for a in _written(args)]
            call = (0, args[1], copies[0], copies[1], args[4], args[5], copies[2], args[7], args[8],
                    type(args[9])(*copies[3:]), *args[10:])
            best = np.inf
            for _ in range(repeats):
                prof = np.zeros(PROFILE_SIZE, dtype=np.int64)
                t = time.perf_counter()
                run_implicit(*call, prof)
                best = min(best, time.perf_counter() - t)
            self.held[i] = best
        self._last_args = [None] * len(self._last_args)

    def _replay(self, i, solver, args):
        wall, out, arrays = self.calls[i][self.next[i]]
        self.next[i] += 1
        held = min(wall, self.held[i])
        end = time.perf_counter() + held
        while time.perf_counter() < end:  # passing the arguments and the return value, holding the lock
            pass
        time.sleep(wall - held)
        self.slept[i] += wall - held
        for dst, src in zip(_written(args), arrays):
            dst[...] = src
        solver._profile = None
        return out

    @contextmanager
    def _patched(self, replay: bool):
        timed, step_one, tape = SolverBase._timed, BatchedVectorEnv._step_one, self

        def patched_timed(solver, kernel, *args):
            i = getattr(tape._local, "env", None)
            if i is None or kernel is not run_implicit:
                return timed(solver, kernel, *args)
            return tape._replay(i, solver, args) if replay else tape._record(i, solver, kernel, args)

        def patched_step_one(venv, i, action, mode):
            tape._local.env = i
            tape.slept[i] = 0.0
            try:
                return step_one(venv, i, action, mode)
            finally:
                tape._local.env = None

        SolverBase._timed, BatchedVectorEnv._step_one = patched_timed, patched_step_one
        try:
            yield self
        finally:
            SolverBase._timed, BatchedVectorEnv._step_one = timed, step_one

    def recording(self):
        return self._patched(replay=False)

    def replaying(self):
        self.next[:] = 0
        return self._patched(replay=True)


def _batch(env_id: str, n_envs: int, threads: int, seed: int, first: int = 0):
    """A batch of ``n_envs`` whose sub-env i is seeded as the recorded batch's sub-env ``first + i``."""
    venv = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point", threads=threads,
                        autoreset_mode=AutoresetMode.SAME_STEP)
    venv.reset(seed=seed + 1 + first)
    return venv


def record(env_id: str, n_envs: int, steps: int, seed: int = 0):
    """The batch's expert episodes on one thread: (tape, actions per vector step, observations per
    vector step, wall seconds per vector step)."""
    venv = _batch(env_id, n_envs, 1, seed)
    subs = venv.unwrapped.envs
    experts = [make_expert(e) for e in subs]
    tape = KernelTape(n_envs)
    actions, observations, walls = [], [], []
    with tape.recording():
        for _ in range(steps):
            act = np.stack([x.act() for x in experts])
            t = time.perf_counter()
            obs, _, terminated, truncated, _ = venv.step(act)
            walls.append(time.perf_counter() - t)
            actions.append(act)
            observations.append(obs.copy())
            for i in np.flatnonzero(terminated | truncated):
                experts[i] = make_expert(subs[i])
    tape.time_held()
    venv.close()
    return tape, actions, observations, np.array(walls)


def replay(env_id: str, tape: KernelTape, actions, observations, threads: int, warm: int, seed: int = 0,
           first: int = 0, start=None) -> dict:
    """The recorded episodes on ``threads`` threads with the kernel calls slept: wall and CPU time
    after ``warm`` vector steps, the threads' busy share and a sub-env step's waiting share.
    ``first``: the recorded sub-env the tape's first is (a slice of the recording); ``start``: called
    before the first timed step (the processes of :func:`replay_in_processes` wait for each other)."""
    n_envs = len(tape.calls)
    venv = _batch(env_id, n_envs, threads, seed, first)
    u = venv.unwrapped
    acc = dict(wall=0.0, cpu=0.0, busy=0.0, busy_cpu=0.0, slept=0.0)
    with tape.replaying():
        for k, act in enumerate(actions):
            if k == warm and start is not None:
                start()
            c, t = time.process_time(), time.perf_counter()
            obs = venv.step(act)[0]
            wall = time.perf_counter() - t
            if not np.array_equal(obs, observations[k]):
                raise RuntimeError(f"{env_id}: the replay on {threads} threads differs from the recording at vector "
                                   f"step {k}")
            if k >= warm:
                acc["wall"] += wall
                acc["cpu"] += time.process_time() - c
                acc["busy"] += float(u.last_step_seconds.sum())
                acc["busy_cpu"] += float(u.last_step_cpu_seconds.sum())
                acc["slept"] += float(tape.slept.sum())
    venv.close()
    n = (len(actions) - warm) * n_envs
    return {"threads": threads, "wall_s": acc["wall"], "cpu_s": acc["cpu"], "env_steps_per_s": n / acc["wall"],
            "threads_busy_share": acc["busy"] / (threads * acc["wall"]),
            "env_step_ms": 1e3 * acc["busy"] / n, "env_step_cpu_ms": 1e3 * acc["busy_cpu"] / n,
            "env_step_slept_ms": 1e3 * acc["slept"] / n,
            "env_step_lock_share": acc["busy_cpu"] / acc["busy"],
            "env_step_waiting_share": 1.0 - (acc["busy_cpu"] + acc["slept"]) / acc["busy"]}


def _slice(tape: KernelTape, first: int, m: int) -> KernelTape:
    """Sub-envs ``first`` … ``first + m − 1`` of ``tape``."""
    part = KernelTape(m)
    part.calls, part.held = tape.calls[first:first + m], tape.held[first:first + m].copy()
    return part


def replay_in_processes(env_id: str, tape: KernelTape, actions, observations, threads: int, processes: int,
                        warm: int, seed: int = 0) -> dict:
    """The recorded episodes as ``processes`` forked processes, each replaying N / ``processes`` of
    the sub-envs on ``threads / processes`` threads, the processes' timed steps started together:
    the layout of Ray actors of k envs on a few threads each (each process its own interpreter
    lock). Wall time is the slowest process's; the per-step shares are the processes' means."""
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    n_envs = len(tape.calls)
    m, t = n_envs // processes, threads // processes
    barrier, results = ctx.Barrier(processes), ctx.Queue()

    def run(k: int) -> None:  # in process k: its result, or its error (the others then stop at the barrier)
        sl = slice(k * m, (k + 1) * m)
        try:
            row = replay(env_id, _slice(tape, k * m, m), [a[sl] for a in actions], [o[sl] for o in observations],
                         t, warm, seed, first=k * m, start=barrier.wait)
            results.put((k, row, None))
        except BaseException as err:
            barrier.abort()
            results.put((k, None, f"{type(err).__name__}: {err}"))

    procs = [ctx.Process(target=run, args=(k,)) for k in range(processes)]
    for p in procs:
        p.start()
    answers = sorted((results.get() for _ in procs), key=lambda a: (a[2] is None, a[0]))
    for p in procs:
        p.join()
    if answers[0][2] is not None:  # the first real error, not a BrokenBarrierError it caused elsewhere
        first = next((a for a in answers if a[2] and not a[2].startswith("BrokenBarrierError")), answers[0])
        raise RuntimeError(f"{env_id}: replay process {first[0]} (sub-envs {first[0] * m}–{(first[0] + 1) * m - 1}): "
                           f"{first[2]}")
    rows = [a[1] for a in answers]
    wall = max(r["wall_s"] for r in rows)
    means = {k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k.startswith("env_step")}
    busy_s = sum(r["threads_busy_share"] * r["threads"] * r["wall_s"] for r in rows)
    return {**means, "threads": threads, "processes": processes, "wall_s": wall,
            "cpu_s": sum(r["cpu_s"] for r in rows), "env_steps_per_s": (len(actions) - warm) * n_envs / wall,
            "threads_busy_share": busy_s / (threads * wall)}


def lock_scaling(env_id: str, n_envs: int, steps: int, thread_counts: list[int], seed: int = 0, warm: int = 2,
                 process_counts: tuple[int, ...] = (1,)) -> dict:
    """Record the batch's expert episodes on one thread, replay them on 1 and on each of
    ``thread_counts`` threads, in one process and split over each of ``process_counts`` processes
    (where they divide the envs and the threads); rows with ``speed_up`` (over the replay on one
    thread) and ``efficiency`` (speed-up / threads)."""
    n = max(warm + 1, steps // n_envs + warm)
    tape, actions, observations, walls = record(env_id, n_envs, n, seed)
    rows = []
    for t in [1, *sorted(set(thread_counts) - {1})]:
        for p in sorted(set(process_counts) | ({1} if t == 1 else set())):
            if p == 1:
                rows.append({**replay(env_id, tape, actions, observations, t, warm, seed), "processes": 1})
            elif t % p == 0 and n_envs % p == 0 and t > 1:
                rows.append(replay_in_processes(env_id, tape, actions, observations, t, p, warm, seed))
    for r in rows:
        r["speed_up"] = rows[0]["wall_s"] / r["wall_s"]
        r["efficiency"] = r["speed_up"] / r["threads"]
    kernel = np.array([c[0] for calls in tape.calls for c in calls])
    return {"policy": "expert", "n_envs": n_envs, "vector_steps": n - warm,
            "recorded_env_steps_per_s": (n - warm) * n_envs / walls[warm:].sum(),
            "kernel_calls": int(kernel.size), "kernel_call_ms_mean": 1e3 * float(kernel.mean()) if kernel.size else 0.0,
            "kernel_call_held_ms_median": 1e3 * float(np.median(tape.held)), "by_threads": rows}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ids", nargs="+", default=["cloth_gym/CornerLift-v2", "cloth_gym/DrapeOntoTable-v2"])
    ap.add_argument("--batched", type=int, default=64, metavar="N", help="sub-envs in the batch")
    ap.add_argument("--threads", type=int, nargs="+", default=[4, 8, 16], metavar="T",
                    help="thread counts to replay on (one thread is always among them)")
    ap.add_argument("--processes", type=int, nargs="+", default=[1], metavar="P",
                    help="also replay each thread count T as P processes of N/P envs on T/P threads each (where P "
                         "divides N and T): Ray actors' layout, a lock per process")
    ap.add_argument("--steps", type=int, default=1280, help="env steps replayed (all sub-envs together)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "lock_scaling" / "lock_scaling.json",
                    help="the JSON file written")
    args = ap.parse_args(argv)
    for name, values in (("--batched", [args.batched]), ("--threads", args.threads), ("--steps", [args.steps]),
                         ("--processes", args.processes)):
        if min(values) < 1:
            ap.error(f"{name} must be at least 1")
    provenance = stamp(command_line("python scripts/lock_scaling.py", sys.argv[1:] if argv is None else argv))
    results = {**provenance,
               "machine": {**provenance["machine"], "cpu_count": os.cpu_count(),
                           "load_average_at_start": load_average()},
               "note": "the batch with its implicit kernel calls replaced by sleeps of their recorded length: the "
                       "speed-up threads reach with a core each, bound only by the interpreter lock and the schedule",
               "envs": {}}
    for env_id in args.ids:
        row = results["envs"][env_id] = lock_scaling(env_id, args.batched, args.steps, args.threads, args.seed,
                                                     process_counts=tuple(args.processes))
        one = row["by_threads"][0]
        print(f"{env_id}: {args.batched} envs, a sub-env step {one['env_step_ms']:.2f} ms on one thread, "
              f"{one['env_step_lock_share']:.3f} of it holding the lock; a kernel call "
              f"{row['kernel_call_ms_mean']:.3f} ms, {row['kernel_call_held_ms_median']:.3f} ms of it holding the lock",
              flush=True)
        for r in row["by_threads"][1:]:
            where = f"{r['threads']:3d} threads in {r['processes']} process" + ("es" if r["processes"] > 1 else "")
            print(f"    {where}: speed-up {r['speed_up']:6.2f} (efficiency {r['efficiency']:.3f}), "
                  f"threads busy {r['threads_busy_share']:.3f}, a sub-env step waiting "
                  f"{r['env_step_waiting_share']:.3f} of its time", flush=True)
    write_results(results, args.out)
    return results


if __name__ == "__main__":
    main()
