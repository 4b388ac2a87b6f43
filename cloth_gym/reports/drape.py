"""Drape test (the paper's §5, fig. 8): a disc of cloth on a pedestal, run until it settles.

Writes into ``<out>/<material>_<model>[_cusick]/``:

* ``metrics.json``: ``drape_coefficient``, ``node_count``, settle time, max/mean strain per
  direction, wall time, and the parameters;
* ``drape.png``: top view (the cloth's projected triangles, the outline r(θ) used for the
  node count, the pedestal) beside a perspective view from the headless renderer.

    cloth-gym drape --material thick_cotton [--model kes|breen] [--sigma 1.0]
                    [--geometry paper|cusick] [--out outputs/drape_test]

(``python scripts/drape_test.py`` takes the same arguments.)

σ = 1 cm (505 particles on the paper's 25.4 cm disc) runs in about 10 s on one core after
compilation; σ = 0.5 cm (the paper's spacing, 2,025 particles) in one to three minutes.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..metrics import outline_angles
from ..render import Camera, Renderer
from ..scenes import drape_metrics, drape_test, run_until_settled
from ..sim.diagnostics import strain_summary
from . import figure, options

__all__ = ["drape_views", "run", "add_arguments", "main"]


def drape_views(scene, state, outline_r, title: str, path: Path | None = None, size_px: int = 360):
    """Figure: top view with outline and pedestal | perspective render. Returns the matplotlib figure."""
    m = scene.model
    q = state.particle_q
    fig = figure((9.6, 4.8))
    (ax0, ax1) = fig.subplots(1, 2)
    heights = ax0.tripcolor(q[:, 0], q[:, 1], m.tri_indices, q[:, 2], shading="gouraud", cmap="viridis")
    fig.colorbar(heights, ax=ax0, shrink=0.8, label="height z, cm")
    th = outline_angles(len(outline_r))
    cx, cy = scene.center_xy
    ax0.plot(np.r_[cx + outline_r * np.cos(th), cx + outline_r[0] * np.cos(th[0])],
             np.r_[cy + outline_r * np.sin(th), cy + outline_r[0] * np.sin(th[0])], "r-", lw=1.2, label="outline")
    a = np.linspace(0, 2 * np.pi, 200)
    rp = scene.pedestal_radius_cm
    ax0.plot(cx + rp * np.cos(a), cy + rp * np.sin(a), "m--", lw=1.0, label="pedestal")  # seen on the cloth and the legend
    rc = scene.params.get("cloth_diameter_cm", 2 * outline_r.max()) / 2
    ax0.plot(cx + rc * np.cos(a), cy + rc * np.sin(a), "k:", lw=0.8, label="flat cloth")
    ax0.set_aspect("equal")
    ax0.set_xlabel("x (warp), cm")
    ax0.set_ylabel("y (weft), cm")
    ax0.legend(loc="upper right", fontsize=7)
    ax0.set_title("top view", fontsize=9)
    ext = 1.1 * rc
    cam = Camera.look_at((1.9 * ext, -2.6 * ext, 1.7 * ext), (0.0, 0.0, -0.3 * ext), fov_deg=35.0)
    img = Renderer(size_px, size_px, camera=cam, ssaa=2).render_scene(m, state)
    ax1.imshow(img)
    ax1.set_axis_off()
    ax1.set_title("perspective", fontsize=9)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def run(material: str, model: str = "kes", sigma: float = 1.0, geometry: str = "paper",
        max_time: float = 6.0, seed: int = 0, quiet: bool = False) -> tuple:
    """Run the drape test until it settles; ``(scene, result, measurements, metrics)``: the
    :class:`~cloth_gym.scenes.Scene`, the :class:`~cloth_gym.scenes.SettleResult`, the
    :func:`~cloth_gym.scenes.drape_metrics` of the settled state, and the JSON-ready metrics
    (drape coefficient, node count, settle time, strains, wall time, parameters)."""
    scene = drape_test(material, model=model, sigma=sigma, geometry=geometry, seed=seed, max_time_s=max_time)
    prog = None
    if not quiet:
        def prog(t, e):
            if abs(t / 0.5 - round(t / 0.5)) < 1e-6:
                print(f"  t = {t:4.2f} s  KE = {e:.3g} erg (settled below {scene.ke_threshold_erg:.3g})",
                      file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    res = run_until_settled(scene, progress=prog)
    wall = time.perf_counter() - t0
    meas = drape_metrics(scene, res.state)
    metrics = {
        "drape_coefficient": meas["drape_coefficient"],
        "node_count": meas["node_count"],
        "settled": res.settled,
        "settle_time_s": res.settle_time_s,
        "simulated_s": float(res.times[-1]),
        "final_kinetic_energy_erg": float(res.kinetic_energy[-1]),
        "ke_threshold_erg": scene.ke_threshold_erg,
        **strain_summary(scene.model, res.state),
        "min_z_cm": float(res.state.particle_q[:, 2].min()),
        "wall_s": wall,
        "particles": scene.model.particle_count,
        "integrator": f"{scene.integrator} (max_dt {scene.max_dt:g} s)",
        "parameters": scene.params,
    }
    return scene, res, meas, metrics


add_arguments = options.drape


def writable_folder(field: str, folder: Path) -> None:
    """Make ``folder`` (and its parents) and check that files can be written in it, else a
    :class:`~cloth_gym.errors.ConfigError` naming ``field`` and the folder."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / ".cloth_gym_write_check"
        probe.write_text("")
        probe.unlink()
    except OSError as err:
        raise ConfigError(field, f"cannot write in the output folder {str(folder)!r} ({err.strerror or err}): "
                          "choose a folder you can write to") from None


def run_args(args: argparse.Namespace, command: str) -> dict:
    """Run the drape test for parsed ``args``; write ``metrics.json`` and ``drape.png``; return the
    metrics. With several seeds (``--seed 0 1 2``), each run goes to ``seed_<k>/`` and the summary over them
    (:func:`seed_summary`) to ``seeds.json``, which is returned."""
    name = Path(args.material).stem
    out = Path(args.out) / (f"{name}_{args.model}" + ("" if args.geometry == "paper" else f"_{args.geometry}"))
    writable_folder("out", out)  # before minutes of simulating, not after
    runs = []
    for seed in args.seed:
        scene, res, meas, metrics = run(args.material, args.model, args.sigma, args.geometry, args.max_time,
                                        seed, args.quiet)
        where = out if len(args.seed) == 1 else out / f"seed_{seed}"
        where.mkdir(parents=True, exist_ok=True)
        metrics["command"] = command
        metrics["seed"] = seed
        (where / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
        title = (f"{name}, {args.model}, σ = {args.sigma:g} cm, seed {seed}: DC = {metrics['drape_coefficient']:.3f}, "
                 f"{metrics['node_count']} nodes")
        drape_views(scene, res.state, meas["outline_radius_cm"], title, where / "drape.png")
        settle = (f"settled at {metrics['settle_time_s']} s" if metrics["settled"]
                  else f"not settled within {metrics['simulated_s']:.3g} s")
        print(f"{title}; {settle}, wall {metrics['wall_s']:.1f} s -> {where}", flush=True)
        runs.append(metrics)
    if len(runs) == 1:
        return runs[0]
    summary = {**seed_summary(runs), "command": command, "runs": runs}
    (out / "seeds.json").write_text(json.dumps(summary, indent=2) + "\n")
    counts = ", ".join(f"{k} nodes ×{v}" for k, v in summary["node_counts"].items())
    print(f"{name}, {args.model}, σ = {args.sigma:g} cm over {len(runs)} seeds: {counts}; DC "
          f"{summary['drape_coefficient_mean']:.3f} ± {summary['drape_coefficient_sd']:.3f} (mean ± sd) -> "
          f"{out / 'seeds.json'}")
    return summary


def seed_summary(runs: list[dict]) -> dict:
    """Over the drape runs' metrics: how many gave each node count (``{count: runs}``, by count), and
    the drape coefficient's mean, standard deviation (over the seeds, ddof 0) and range. A drape
    has several stable fold patterns of nearly equal energy; a tiny start perturbation picks one,
    so a distribution says more than one run."""
    counts: dict[int, int] = {}
    for r in runs:
        counts[int(r["node_count"])] = counts.get(int(r["node_count"]), 0) + 1
    dc = np.array([r["drape_coefficient"] for r in runs], dtype=float)
    return {"seeds": [r.get("seed") for r in runs], "node_counts": dict(sorted(counts.items())),
            "drape_coefficient_mean": float(dc.mean()), "drape_coefficient_sd": float(dc.std()),
            "drape_coefficient_min": float(dc.min()), "drape_coefficient_max": float(dc.max()),
            "settled": all(r["settled"] for r in runs)}


def main(argv=None, prog: str = "cloth-gym drape") -> dict:
    return options.run("drape", run_args, argv, prog)
