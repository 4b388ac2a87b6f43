"""Bit-for-bit fingerprints of every registered env id's trajectories, to prove a change behaviour-free.

For each id, two short episodes from fixed seeds: one driven by the scripted expert, one by seeded
uniform random actions. Every observation, reward, termination flag, ``info["diverged"]`` and the
final particle positions and velocities go into one SHA-256 digest per (id, policy). Two trees give
the same digests only if they produce the same bits.

    python scripts/trajectory_digests.py                      # print this tree's digests as JSON
    python scripts/trajectory_digests.py --out FILE           # ... and save them (with the CPU they ran on)
    python scripts/trajectory_digests.py --vs COMMIT          # this tree side by side with COMMIT (git worktree)

Digests depend on the CPU (numba compiles for the host's instruction set), so a saved file records
the CPU and the library versions it ran under; ``tests/test_trajectory_digests.py`` compares against
it only where they match, and otherwise runs the recorded commit side by side.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

EXPERT_STEPS = 40  # env steps per expert episode (the grasp and the start of the carry in every task)
RANDOM_STEPS = 20  # env steps per random-action episode
SEED = 123  # episode seed of both episodes


def cpu_signature() -> dict:
    """What decides whether two machines produce the same bits: the CPU model and the compiler stack."""
    import numba
    import numpy

    model = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": model, "machine": platform.machine(), "python": platform.python_version(),
            "numpy": numpy.__version__, "numba": numba.__version__}


def _update(h, *arrays) -> None:
    for a in arrays:
        if isinstance(a, dict):
            for k in sorted(a):
                h.update(k.encode())
                _update(h, a[k])
        else:
            arr = np.ascontiguousarray(np.asarray(a))
            h.update(str(arr.dtype).encode() + str(arr.shape).encode())
            h.update(arr.tobytes())


def episode_digest(env_id: str, policy: str, steps: int, seed: int = SEED) -> str:
    """SHA-256 of one episode's observations, rewards, flags and final particle state."""
    import gymnasium as gym

    import cloth_gym  # noqa: F401  (registers the ids)
    from agents.experts import make_expert

    env = gym.make(env_id)
    h = hashlib.sha256()
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    _update(h, obs)
    expert = make_expert(env) if policy == "expert" else None
    for _ in range(steps):
        action = expert.act() if expert is not None else env.action_space.sample()
        obs, reward, term, trunc, info = env.step(action)
        _update(h, obs, np.float64(reward), np.array([term, trunc, bool(info.get("diverged", False))]))
        if term or trunc:
            break
    state = env.unwrapped.physics.state
    _update(h, state.particle_q, state.particle_qd)
    env.close()
    return h.hexdigest()


def all_digests(ids: list[str] | None = None) -> dict[str, str]:
    """``{"<id> expert": digest, "<id> random": digest}`` for every registered id (or ``ids``)."""
    from cloth_gym.envs import ENV_SPECS

    out = {}
    for env_id in ids or list(ENV_SPECS):
        out[f"{env_id} expert"] = episode_digest(env_id, "expert", EXPERT_STEPS)
        out[f"{env_id} random"] = episode_digest(env_id, "random", RANDOM_STEPS)
    return out


def head_commit(tree: Path = ROOT) -> str:
    return subprocess.run(["git", "-C", str(tree), "rev-parse", "HEAD"], capture_output=True, text=True,
                          check=True).stdout.strip()


def digests_in_tree(tree: Path, ids: list[str] | None = None) -> dict[str, str]:
    """:func:`all_digests` computed by ``tree``'s own code, in a fresh process (its own kernel cache)."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--tree", str(tree)]
    if ids:
        cmd += ["--ids", *ids]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True, cwd=tree)
    return json.loads(out.stdout)["digests"]


def digests_at_commit(commit: str, ids: list[str] | None = None) -> dict[str, str]:
    """:func:`all_digests` of ``commit``, run from a temporary git worktree of this repository."""
    with tempfile.TemporaryDirectory(prefix="cloth_gym_digests_") as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), commit],
                       capture_output=True, check=True)
        try:
            return digests_in_tree(tree, ids)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], capture_output=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, help="save the digests (with the CPU signature and commit) to this JSON file")
    p.add_argument("--vs", metavar="COMMIT", help="compare side by side with COMMIT (a git worktree, fresh process)")
    p.add_argument("--ids", nargs="+", help="only these env ids (default: every registered id)")
    p.add_argument("--tree", type=Path, default=ROOT, help=argparse.SUPPRESS)  # the tree whose code runs
    args = p.parse_args(argv)
    sys.path.insert(0, str(args.tree))
    import cloth_gym

    if not Path(cloth_gym.__file__).resolve().is_relative_to(args.tree.resolve()):
        raise SystemExit(f"cloth_gym imported from {cloth_gym.__file__}, not from the tree {args.tree}")
    digests = all_digests(args.ids)
    record = {"commit": head_commit(args.tree), "signature": cpu_signature(), "expert_steps": EXPERT_STEPS,
              "random_steps": RANDOM_STEPS, "seed": SEED, "digests": digests}
    if args.vs:
        theirs = digests_at_commit(args.vs, args.ids)
        record["vs"] = {"commit": args.vs, "digests": theirs}
        record["differ"] = sorted(k for k in digests if theirs.get(k) != digests[k])
    print(json.dumps(record, indent=2))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(record, indent=2) + "\n")
    return 1 if record.get("differ") else 0


if __name__ == "__main__":
    sys.exit(main())
