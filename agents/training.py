"""Train a Stable-Baselines3 agent on a cloth_gym env, with everything needed to reproduce it.

A run directory holds:

* ``config.yaml`` — the resolved configuration (the zoo entry), ``command.txt``
  — the command line, ``run.json`` — seed, versions, wall time, env steps;
* ``model.zip`` and, with ``normalize``, ``vecnormalize.pkl`` (the
  observation/return statistics the policy needs at evaluation);
* ``eval/evaluations.npz`` (EvalCallback: returns and success rates),
  ``best/best_model.zip``, ``checkpoints/`` and ``monitor/`` (episode logs),
  ``tb/`` when TensorBoard is installed, and ``learning_curve.png``.

What SB3 already does is used as is: ``make_vec_env``, ``VecNormalize``,
``EvalCallback`` (which syncs the normalisation statistics and records
``is_success``), ``CheckpointCallback`` and the progress bar.

The config's ``callback`` entries (:mod:`cloth_gym.agents.callbacks`) go to ``learn``
before the evaluation and checkpoint callbacks, as the zoo orders them. With
:class:`~cloth_gym.agents.callbacks.ExpertDemos` the scripted expert's episodes go into
the replay buffer before the first env step (as in DDPGfD/SACfD; they stay
there with the agent's own transitions, the buffer being larger than the run);
``run.json`` records their env steps apart from the training's, under
``expert_demos``, and the wall time includes them.

With ``overlap=True`` (``scripts/train.py --overlap``; off-policy algorithms) the learner's
gradient steps run while the envs take their next step (:mod:`cloth_gym.agents.overlap`), each
action chosen by the policy one update behind.
"""

from __future__ import annotations

import json
import platform
import shlex
import subprocess
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from .config import TrainConfig, algo_class

__all__ = ["train", "TrainResult", "load_run", "load_model", "plot_learning_curve", "plot_seed_curves"]


@dataclass(frozen=True)
class TrainResult:
    run_dir: Path
    wall_s: float
    env_steps: int


#: how ``train`` runs its ``n_envs`` envs: one after another (SB3's DummyVecEnv), in processes
#: (SubprocVecEnv), or batched in one process, their physics in parallel threads
#: (:class:`cloth_gym.envs.vector.BatchedVectorEnv` through :class:`~cloth_gym.agents.vec_env.GymnasiumVecEnv`),
#: or in Ray actors, several per actor, on this machine or a cluster (:class:`~cloth_gym.agents.ray_vec_env.RayVecEnv`)
VEC_ENVS = ("dummy", "subproc", "batched", "ray")


def _make_env(cfg: TrainConfig, n_envs: int, seed: int, monitor_dir: Path | None, vec_env: str = "dummy",
              training: bool = True, ray: dict | None = None):
    """The vectorised envs; the config's ``env_wrapper`` wraps training envs only. ``ray``: the
    :class:`~cloth_gym.agents.ray_vec_env.RayVecEnv` options of ``vec_env="ray"``."""
    import cloth_gym  # noqa: F401  (registers the ids)
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    from .vec_env import BatchedVecEnv

    kwargs = {}
    if vec_env == "ray":  # asked for by name: Ray even for one env
        from .ray_vec_env import RayVecEnv

        cls, kwargs = RayVecEnv, dict(ray or {})
    else:
        cls = {"dummy": DummyVecEnv, "subproc": SubprocVecEnv, "batched": BatchedVecEnv}[vec_env] if n_envs > 1 \
            else DummyVecEnv
    return make_vec_env(cfg.env_id, n_envs=n_envs, seed=seed, env_kwargs=dict(cfg.env_kwargs),
                        monitor_dir=str(monitor_dir) if monitor_dir else None,
                        wrapper_class=cfg.wrapper_class() if training else None, vec_env_cls=cls,
                        vec_env_kwargs=kwargs)


def _tensorboard_available() -> bool:
    try:
        import tensorboard  # noqa: F401
    except ImportError:
        return False
    return True


def train(cfg: TrainConfig, run_dir: str | Path, seed: int = 0, eval_freq: int = 5000, n_eval_episodes: int = 10,
          checkpoint_freq: int = 0, progress_bar: bool = False, vec_env: str = "dummy", verbose: int = 0,
          command: str | None = None, torch_threads: int = 1, after_eval=None,
          overlap: bool = False, ray: dict | None = None) -> TrainResult:
    """Train ``cfg`` into ``run_dir`` (created) and return the run's wall time and env steps.

    eval_freq: env steps between evaluations (0: none). checkpoint_freq: env steps between
    checkpoints (0: none). vec_env: how the ``n_envs`` envs run, one of :data:`VEC_ENVS`.
    Seeds: the envs get ``seed + i``, the evaluation env ``seed + 10_000``, the algorithm ``seed``.
    torch_threads: torch's intra-op threads. 1 by default: these networks are small, and on a
    2-core machine shared with the simulator more threads spin against each other (measured:
    half the CPU time in the kernel and a 2× slower run with torch's default).
    after_eval: an SB3 ``BaseCallback`` run after each evaluation (``EvalCallback``'s
    ``callback_after_eval``: its ``parent`` holds the evaluation's results); the sweeps report
    to Ray Tune through it. overlap: take the gradient steps while the envs step
    (:mod:`cloth_gym.agents.overlap`; sac and tqc). ray: with ``vec_env="ray"``, the
    :class:`~cloth_gym.agents.ray_vec_env.RayVecEnv` options (``envs_per_actor``, ``address``,
    ``threads_per_actor``, ``timeout_s``); the evaluation env stays one plain env."""
    import torch
    from stable_baselines3.common.utils import set_random_seed
    from stable_baselines3.common.vec_env import VecNormalize

    if vec_env not in VEC_ENVS:
        from cloth_gym.errors import ConfigError

        raise ConfigError("vec_env", f"must be one of {list(VEC_ENVS)}, got {vec_env!r}")
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(yaml.safe_dump({cfg.env_id: cfg.to_zoo_dict()}, sort_keys=False))
    (run_dir / "command.txt").write_text((command or shlex.join(sys.argv)) + "\n")
    torch.set_num_threads(max(1, int(torch_threads)))
    set_random_seed(seed)
    Algo = algo_class(cfg.algo)
    if overlap:
        from .overlap import OverlappedVecEnv, overlapped

        Algo = overlapped(Algo)  # refuses an on-policy algorithm before any env is made
    env = _make_env(cfg, cfg.n_envs, seed, run_dir / "monitor", vec_env, ray=ray)
    if overlap:
        env = OverlappedVecEnv(env)
    gamma = cfg.algo_kwargs.get("gamma", 0.99)
    if cfg.normalize:
        env = VecNormalize(env, gamma=gamma)
    callbacks, demos, eval_env = _callbacks(cfg, run_dir, seed, gamma, eval_freq, n_eval_episodes, checkpoint_freq,
                                            verbose, after_eval)
    model = Algo(cfg.policy, env, seed=seed, verbose=verbose, device="cpu",
                 tensorboard_log=str(run_dir / "tb") if _tensorboard_available() else None, **cfg.sb3_kwargs())
    t0 = time.perf_counter()
    cpu0 = time.process_time()
    with warnings.catch_warnings():
        # the evaluation env is one plain env on purpose (no curriculum wrapper, one episode at a
        # time), whatever vectorises the training envs; SB3 warns whenever the two classes differ
        warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
        model.learn(total_timesteps=cfg.n_timesteps, callback=callbacks, progress_bar=progress_bar)
    wall = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    model.save(run_dir / "model.zip")
    if cfg.normalize:
        env.save(str(run_dir / "vecnormalize.pkl"))
    import stable_baselines3

    info = {"algo": cfg.algo, "env_id": cfg.env_id, "seed": seed, "wall_s": wall, "cpu_s": cpu,
            "commit": _git_commit(), "env_steps": int(model.num_timesteps),
            "n_envs": cfg.n_envs, "vec_env": vec_env, "ray": dict(ray or {}), "overlap": bool(overlap),
            "python": platform.python_version(), "torch": torch.__version__,
            "stable_baselines3": stable_baselines3.__version__, "machine": platform.machine()}
    if demos is not None:  # wall_s includes the demonstrations and the pretraining
        info["expert_demos"] = demos.stats
    (run_dir / "run.json").write_text(json.dumps(info, indent=2))
    env.close()
    if eval_env is not None:
        eval_env.close()
    if (run_dir / "eval" / "evaluations.npz").exists():
        plot_learning_curve(run_dir)
    return TrainResult(run_dir, wall, int(model.num_timesteps))


def _git_commit() -> str | None:
    """The checkout's commit (with ``+dirty`` when it has uncommitted changes), None outside a git checkout."""
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + ("+dirty" if dirty else "")


def _callbacks(cfg: TrainConfig, run_dir: Path, seed: int, gamma: float, eval_freq: int, n_eval_episodes: int,
               checkpoint_freq: int, verbose: int, after_eval):
    """(callbacks, the expert-demonstrations callback or None, the evaluation env or None) of a
    run: the config's own callbacks, SB3's ``EvalCallback`` every ``eval_freq`` env steps on one
    plain env seeded ``seed + 10_000``, and a ``CheckpointCallback`` every ``checkpoint_freq``."""
    from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback
    from stable_baselines3.common.vec_env import VecNormalize

    from .callbacks import ExpertDemos

    callbacks = cfg.callbacks()
    demos = next((cb for cb in callbacks if isinstance(cb, ExpertDemos)), None)
    eval_env = None
    if eval_freq > 0:
        eval_env = _make_env(cfg, 1, seed + 10_000, None, training=False)
        if cfg.normalize:
            eval_env = VecNormalize(eval_env, training=False, norm_reward=False, gamma=gamma)
        callbacks.append(EvalCallback(eval_env, n_eval_episodes=n_eval_episodes,
                                      eval_freq=max(eval_freq // cfg.n_envs, 1),
                                      log_path=str(run_dir / "eval"), best_model_save_path=str(run_dir / "best"),
                                      deterministic=True, verbose=verbose, callback_after_eval=after_eval))
    if checkpoint_freq > 0:
        callbacks.append(CheckpointCallback(save_freq=max(checkpoint_freq // cfg.n_envs, 1),
                                            save_path=str(run_dir / "checkpoints"),
                                            save_vecnormalize=cfg.normalize))
    return callbacks, demos, eval_env


def load_model(algo: str, path: str | Path):
    """The SB3 model saved at ``path``, for acting: without an env, and with the replay buffer SB3
    picks by default (a ``HerReplayBuffer`` cannot be rebuilt without its env; a policy does not
    need it)."""
    return algo_class(algo).load(path, device="cpu",
                                 custom_objects={"replay_buffer_class": None, "replay_buffer_kwargs": {}})


def load_run(run_dir: str | Path):
    """(model, config dict, env_id, env_kwargs, VecNormalize statistics or None) of a run directory."""
    run_dir = Path(run_dir)
    conf = yaml.safe_load((run_dir / "config.yaml").read_text())
    (env_id, entry), = conf.items()
    run = json.loads((run_dir / "run.json").read_text())
    model = load_model(run["algo"], run_dir / "model.zip")
    norm = None
    if (run_dir / "vecnormalize.pkl").exists():
        import pickle

        with open(run_dir / "vecnormalize.pkl", "rb") as f:
            norm = pickle.load(f)
    return model, entry, env_id, entry.get("env_kwargs", {}), norm


def plot_learning_curve(run_dir: str | Path) -> Path:
    """``learning_curve.png``: evaluation return and success rate against env steps."""
    from cloth_gym.reports import figure  # an Agg canvas of its own: pyplot's backend is left alone

    run_dir = Path(run_dir)
    d = np.load(run_dir / "eval" / "evaluations.npz")
    t, r = d["timesteps"], d["results"]
    fig = figure((6, 3.5))
    ax = fig.subplots()
    marker = "o" if len(t) < 20 else None  # a single evaluation is a point, not an invisible line
    ax.plot(t, r.mean(axis=1), label="return (mean)", marker=marker)
    ax.fill_between(t, r.mean(axis=1) - r.std(axis=1), r.mean(axis=1) + r.std(axis=1), alpha=0.2)
    ax.set_xlabel("env steps")
    ax.set_ylabel("evaluation return")
    if "successes" in d and d["successes"].size:
        ax2 = ax.twinx()
        ax2.plot(t, d["successes"].mean(axis=1), color="C1", label="success rate", marker=marker)
        ax2.set_ylim(-0.05, 1.05)
        ax2.set_ylabel("success rate", color="C1")
    ax.set_title(run_dir.name)
    fig.tight_layout()
    out = run_dir / "learning_curve.png"
    fig.savefig(out, dpi=120)
    return out


def seed_median(curves) -> tuple[np.ndarray, np.ndarray]:
    """Median over runs at each evaluation step of ``curves`` [(steps, values), ...]; a run
    stopped early counts at the steps it reached (the median of the runs evaluated there)."""
    steps = np.unique(np.concatenate([np.asarray(t) for t, _ in curves]))
    grid = np.full((len(curves), len(steps)), np.nan)
    for k, (t, v) in enumerate(curves):
        grid[k, np.searchsorted(steps, t)] = v
    return steps, np.nanmedian(grid, axis=0)


def plot_seed_curves(groups: dict, out: str | Path) -> Path:
    """Evaluation success rate against env steps of several training seeds per config: one thin
    line per run, the median of each group thick. ``groups``: label -> run directories (each
    with ``eval/evaluations.npz``). Shows how much a result depends on the training seed."""
    from cloth_gym.reports import figure

    fig = figure((7, 4))
    ax = fig.subplots()
    for i, (label, runs) in enumerate(groups.items()):
        curves = []
        for r in runs:
            d = np.load(Path(r) / "eval" / "evaluations.npz")
            t, s = d["timesteps"], d["successes"].mean(axis=1)
            ax.plot(t, s, color=f"C{i}", alpha=0.35, lw=1)
            curves.append((t, s))
        steps, med = seed_median(curves)
        ax.plot(steps, med, color=f"C{i}", lw=2.5, label=f"{label} (median of {len(runs)} seeds)")
    ax.set_xlabel("env steps")
    ax.set_ylabel("evaluation success rate")
    ax.set_ylim(-0.03, 1.03)
    ax.axhline(0.8, color="gray", ls=":", lw=1)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=120)
    return out
