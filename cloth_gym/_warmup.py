"""Compile every simulator kernel ahead of time (:func:`cloth_gym.warmup`)."""

from __future__ import annotations

import sys
import time

import numpy as np

__all__ = ["warmup"]


def _say(verbose: bool, text: str) -> None:
    if verbose:
        print(f"cloth_gym.warmup: {text}", file=sys.stderr, flush=True)


def _simulator(model_name: str) -> None:
    """Each integrator, obstacle kind, preconditioner family and collision pass (or none) on
    few-particle cloths."""
    import trimesh

    from .scenes import drape_metrics, drape_test, ribbon, run_until_settled, tablecloth_scene
    from .sim import ForceOptions, Rectangle, SymplecticEuler, build_cloth
    from .sim.collision import CollisionOptions, MeshObstacle
    from .sim.implicit import ImplicitEuler
    from .sim.obstacles import Box, Plane

    options = ForceOptions(model=model_name)
    cloth = build_cloth(Rectangle(8, 8), "thick_cotton", sigma=1.0, options=options, origin=(0, 0, 1.0),
                        obstacles=[Plane(), Box((0, 0, -2), (1, 1, 0.5)),
                                   MeshObstacle(trimesh.creation.icosphere(radius=1.0))],
                        collision=CollisionOptions(self_collision=True))
    plain = build_cloth(Rectangle(8, 8), "thick_cotton", sigma=1.0, options=options, origin=(0, 0, 1.0),
                        obstacles=[Plane()])
    for model in (cloth, plain):
        SymplecticEuler(on_unstable="substep").advance(model, model.state(), None, duration=2e-4, dt=1e-4)
        # the implicit step is compiled once per preconditioner family, collision pass or none
        # (cloth_gym.sim.implicit.precondition), one Newton pass or more, and strain limiter or none:
        # the band factor, lines on one level, multigrid; more passes (what a diverged call's retry
        # takes) without the collision pass (RibbonDrop's band factor with it: _envs); the limiter
        # (the envs' FAST_OPTIONS) with the band factor and lines, one pass, no collision pass
        solves = (("euler", 1), ("bdf2", 10)) if model is plain else (("euler", 1),)
        for preconditioner in ("band", "lines", "multigrid"):
            for scheme, newton_iters in solves:
                ImplicitEuler(max_dt=1e-2, scheme=scheme, newton_iters=newton_iters, newton_tol=0.1,
                              preconditioner=preconditioner).advance(model, model.state(), None, duration=2e-2,
                                                                     dt=1e-2)
            if model is plain and preconditioner != "multigrid":
                ImplicitEuler(max_dt=1e-2, preconditioner=preconditioner, strain_limit_percent=1.0).advance(
                    model, model.state(), None, duration=2e-2, dt=1e-2)
    scene = drape_test("thick_cotton", model=model_name, sigma=4.0, max_time_s=0.1)
    result = run_until_settled(scene, max_time_s=0.1)
    drape_metrics(scene, result.state)
    run_until_settled(tablecloth_scene("thick_cotton", model=model_name, sigma=4.0, size_cm=8.0, table_cm=4.0),
                      max_time_s=0.1)
    run_until_settled(ribbon("thin_wool", model=model_name, length_cm=4.0, width_cm=2.0), max_time_s=0.1)


def _envs() -> None:
    """Every registered env: reset, a few random steps, an rgb frame. The older ids are made on
    purpose (their kernels too are compiled), so Gymnasium's "out of date" warning is not shown."""
    import warnings

    import gymnasium as gym

    from .envs import ENV_SPECS

    for env_id in ENV_SPECS:
        for model_name in ("kes", "breen"):
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message=".*is out of date", category=DeprecationWarning)
                env = gym.make(env_id, model=model_name, render_mode="rgb_array")
            env.reset(seed=0)
            env.action_space.seed(0)
            for _ in range(3):
                env.step(env.action_space.sample())
            env.render()
            env.close()


def warmup(envs: bool = True, verbose: bool = True) -> float:
    """Compile the simulator's kernels now, so that no later call waits on the compiler.

    Runs each integrator (explicit; implicit backward Euler and BDF2, with each
    preconditioner family, with and without the collision pass, with one Newton
    pass and, without the collision pass, with more or with the strain limiter), every
    obstacle kind, self-collision, the paper's scenes and their metrics on
    tiny cloths with both force models, and (``envs=True``) resets and steps
    every registered env once with each model and renders a frame. Compiled
    kernels are cached on disk, so this costs about seven minutes of CPU once
    per installed version and a few seconds after that.

    Parameters
    ----------
    envs
        Also run every registered env.
    verbose
        Print one line per stage to stderr.

    Returns
    -------
    float
        The CPU seconds it took.
    """
    start = time.process_time()
    with np.errstate(all="ignore"):  # tiny cloths on coarse steps may overflow harmlessly; nothing is kept
        for model_name in ("kes", "breen"):
            _say(verbose, f"simulator, {model_name} model")
            _simulator(model_name)
        if envs:
            _say(verbose, "environments")
            _envs()
    seconds = time.process_time() - start
    _say(verbose, f"done in {seconds:.0f} CPU s")
    return seconds
