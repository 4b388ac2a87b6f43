"""Redo the paper's figures: one function per figure, PNGs and a JSON of the numbers each.

    cloth-gym figures [--fig 3 8 10 11 13] [--material NAME_OR_YAML ...] [--fast] [--out outputs/paper]

(``python scripts/paper_figures.py`` takes the same arguments.) ``--material``
replaces the paper's two fabrics (thick cotton, thin wool) by yours: figs. 3, 8
and 10 draw every material given, figs. 11 and 13 (the paper's wool) the last.

* fig. 3: restoring force and torque curves — stretch tension, bending torque, shear torque
  — of Breen's model against the proposed (KES) model, for cotton and wool, at the paper's
  σ = 0.5 cm (``fig3_curves.png``, ``fig3.json``);
* fig. 8: drape test of cotton and wool (the paper's 25.4 cm disc on a 12.7 cm pedestal):
  top views with the outline, perspective views, drape coefficient and node count
  (``fig8_drape.png``, ``fig8.json``);
* fig. 10: the tablecloth (40 cm on a 20 cm table), Breen against proposed, cotton and wool,
  coloured by strain, with the strain at the table's corners (``fig10_tablecloth.png``,
  ``fig10.json``);
* fig. 11: per-particle magnitudes of the stretch, bending and shear forces on the wool
  tablecloth, Breen (top row) against proposed (bottom row), each force on one colour scale
  for both models (``fig11_force_fields.png``, ``fig11.json``);
* fig. 13: the falling ribbon with and without angular momentum in the collision response:
  final poses and an animation (``fig13_ribbon.png``, ``fig13_ribbon.gif``, ``fig13.json``).

``--fast`` runs a coarse version of each (σ = 2–2.5 cm, shorter runs) in under a minute
per figure after compilation; without it the lattice is σ = 1 cm (fig. 13: 0.5 cm), which
takes minutes per figure on one core.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
import numpy as np

from ..errors import MaterialError
from ..materials import load_material
from ..metrics import force_fields
from ..render import Camera, Renderer, colormap, save_gif, save_png
from ..scenes import (drape_metrics, drape_test, ribbon, run_until_settled,
                              table_corner_strain, tablecloth_scene)
from ..sim import ForceOptions
from ..sim import forces as F
from ..sim.diagnostics import particle_max_strain, strain_summary
from ..units import G
from . import figure, options
from .options import PAPER_MATERIALS
from .drape import drape_views

__all__ = ["FIGURES", "PAPER_MATERIALS", "add_arguments", "run_args", "main"]


MODELS = ("breen", "kes")
MODEL_LABEL = {"breen": "Breen", "kes": "proposed (KES)"}


def _write_json(path: Path, data: dict):
    def conv(o):
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, (np.floating, np.integer)):
            return o.item()
        raise TypeError(type(o).__name__)

    path.write_text(json.dumps(data, indent=2, default=conv) + "\n")


# ============================================================================ fig. 3
def fig3(out: Path, fast: bool, materials, cache: dict) -> dict:
    """Restoring force / torque against deformation, Breen vs proposed, per material (σ = 0.5 cm)."""
    sigma = 0.5
    defaults = ForceOptions()  # the simulator's own regularisation and Breen constant
    x0, x0_shear, c0_breen = defaults.sqrt_reg_curvature, defaults.sqrt_reg_shear, defaults.breen_c0
    eps = np.linspace(0.0, 10.0 if not fast else 10.0, 201)  # strain, percent
    psi = np.linspace(0.0, math.pi * 0.999, 181)  # bend angle, rad (0 straight)
    phi = np.radians(np.linspace(0.0, 30.0, 121))  # shear angle, rad
    fig = figure((13, 3.75 * len(materials)))
    axes = fig.subplots(len(materials), 3, squeeze=False)
    data = {"sigma_cm": sigma, "units": {"stretch": "dyne per edge vs strain %", "bending": "dyne*cm vs psi rad",
                                         "shear": "dyne*cm vs phi deg"}, "materials": {}}
    for row, spec in enumerate(materials):
        mat = load_material(spec)
        name = mat.name
        alpha = mat.compression_factor
        rec = {}
        ax = axes[row, 0]
        for d in ("warp", "weft"):
            c = getattr(mat.stretch, d)
            y = np.array([F.kes_stretch_tension(e, c.c1, c.c2, alpha, sigma) for e in eps])
            ax.plot(eps, y, label=f"proposed, {d}")
            rec[f"stretch_kes_{d}_at_1pct_dyne"] = float(F.kes_stretch_tension(1.0, c.c1, c.c2, alpha, sigma))
        yb = np.array([F.breen_stretch_tension(sigma * (1 + e / 100), sigma, c0_breen) for e in eps])
        ax.plot(eps, yb, "k--", label=f"Breen (C0 = {c0_breen:g})")
        rec["stretch_breen_at_1pct_dyne"] = float(F.breen_stretch_tension(sigma * 1.01, sigma, c0_breen))
        rec["stretch_breen_at_10pct_dyne"] = float(F.breen_stretch_tension(sigma * 1.10, sigma, c0_breen))
        ax.set_yscale("symlog", linthresh=1.0)
        ax.set_xlabel("strain ε, %")
        ax.set_ylabel("tension per edge, dyne")
        ax.set_title(f"{name}: stretch")
        ax.legend(fontsize=7)

        ax = axes[row, 1]
        for d in ("warp", "weft"):
            c = getattr(mat.bending, d)
            y = np.array([F.kes_bend_torque(p, c.c0, c.c1, c.c2, sigma, x0) for p in psi])
            ax.plot(np.degrees(psi), y, label=f"proposed, {d}")
            rec[f"bending_kes_{d}_peak_deg"] = float(np.degrees(psi[np.argmax(y)]))
        cm = mat.bending.mean()
        yb = np.array([F.breen_bend_torque(p, cm.c0, cm.c1, cm.c2, sigma, x0) for p in psi])
        ax.plot(np.degrees(psi), yb, "k--", label="Breen (mean)")
        away = psi >= math.radians(20.0)  # Breen's eq. (2) is not 0 when straight: (Gσ/2)(M(0) + M'(0))
        rec["bending_breen_peak_deg"] = float(np.degrees(psi[away][np.argmax(yb[away])]))
        rec["bending_breen_at_straight_dyne_cm"] = float(yb[0])
        ax.set_xlabel("bend angle ψ, degrees (0 = straight)")
        ax.set_ylabel("torque, dyne·cm")
        ax.set_title(f"{name}: bending")
        ax.legend(fontsize=7)

        ax = axes[row, 2]
        cs = mat.shear.mean()
        yk = np.array([F.kes_shear_torque(p, cs.c0, cs.c1, cs.c2, sigma, x0_shear) for p in phi])
        yb = np.array([F.breen_shear_torque(p, cs.c0, cs.c1, cs.c2, sigma, x0_shear) for p in phi])
        ax.plot(np.degrees(phi), yk, label="proposed (mean curve)")
        ax.plot(np.degrees(phi), yb, "k--", label="Breen")
        rec["shear_ratio_kes_over_breen"] = float(yk[-1] / yb[-1])
        ax.set_xlabel("shear angle φ, degrees")
        ax.set_ylabel("torque, dyne·cm")
        ax.set_title(f"{name}: shear")
        ax.legend(fontsize=7)
        data["materials"][name] = rec
    fig.suptitle("Fig. 3: restoring force and torque, Breen vs proposed (σ = 0.5 cm, G = %.2f)" % G)
    fig.tight_layout()
    fig.savefig(out / "fig3_curves.png", dpi=110)
    return data


# ============================================================================ fig. 8
def fig8(out: Path, fast: bool, materials, cache: dict) -> dict:
    """Drape test of each material (proposed model): pictures, DC, node count."""
    sigma = 2.0 if fast else 1.0
    photographs = {"thick_cotton": 5, "thin_wool": 8}  # the paper's photographs of its fabrics
    data = {"sigma_cm": sigma, "geometry": "paper", "paper_photographs_nodes": photographs, "results": {}}
    imgs = []
    for spec in materials:
        sc = drape_test(spec, sigma=sigma, max_time_s=4.0 if fast else 6.0)
        name = sc.model.material.name
        res = run_until_settled(sc)
        meas = drape_metrics(sc, res.state)
        r, dc, nodes = meas["outline_radius_cm"], meas["drape_coefficient"], meas["node_count"]
        data["results"][name] = {"drape_coefficient": dc, "node_count": nodes, "settled": res.settled,
                                 "settle_time_s": res.settle_time_s, "wall_s": res.wall_s,
                                 **strain_summary(sc.model, res.state)}
        f = drape_views(sc, res.state, r, f"{name}: DC = {dc:.3f}, {nodes} nodes (σ = {sigma:g} cm)")
        f.canvas.draw()
        imgs.append(np.asarray(f.canvas.buffer_rgba())[..., :3].copy())
    save_png(out / "fig8_drape.png", np.concatenate(imgs, axis=0))
    return data


# ============================================================================ fig. 10 / 11
def _tablecloth_runs(materials, sigma, max_time, cache: dict):
    """Settled tablecloth (scene, result) per (material, model), computed once per invocation."""
    runs = {}
    for spec in materials:
        name = load_material(spec).name
        for mod in MODELS:
            key = (name, mod, sigma, max_time)
            if key not in cache:
                sc = tablecloth_scene(spec, mod, sigma=sigma, max_time_s=max_time)
                cache[key] = (sc, run_until_settled(sc))
            runs[(name, mod)] = cache[key]
    return runs


def _table_camera(size_cm=40.0):
    return Camera.look_at((0.9 * size_cm, -1.3 * size_cm, 0.9 * size_cm), (0.0, 0.0, -0.25 * size_cm), fov_deg=40.0)


def fig10(out: Path, fast: bool, materials, cache: dict) -> dict:
    """Tablecloth: Breen vs proposed per material, coloured by strain; strain at the table's corners."""
    sigma, max_time = (2.5, 1.5) if fast else (1.0, 4.0)
    runs = _tablecloth_runs(materials, sigma, max_time, cache)
    data = {"sigma_cm": sigma, "max_time_s": max_time, "corner_radius_cm": 4.0, "results": {}}
    vmax = 10.0
    rnd = Renderer(360, 300, camera=_table_camera(), ssaa=2)
    fig = figure((4.5 * len(materials), 8.2))
    axes = fig.subplots(2, len(materials), squeeze=False)
    for i, mod in enumerate(MODELS):
        for j, name in enumerate(load_material(spec).name for spec in materials):
            sc, res = runs[(name, mod)]
            cs = table_corner_strain(sc, res.state)
            data["results"][f"{name}_{mod}"] = {"corner_strain_percent": cs, "settled": res.settled,
                                                "settle_time_s": res.settle_time_s, "wall_s": res.wall_s,
                                                "simulated_s": float(res.times[-1]),
                                                **strain_summary(sc.model, res.state)}
            col = colormap(np.clip(particle_max_strain(sc.model, res.state), 0, None), "viridis", 0.0, vmax)
            ax = axes[i, j]
            ax.imshow(rnd.render_scene(sc.model, res.state, particle_colors=col))
            ax.set_axis_off()
            ax.set_title(f"{name}, {MODEL_LABEL[mod]}\ncorner strain max {cs['max']:.1f} %, "
                         f"mean {cs['mean']:.2f} %", fontsize=9)
    sm = ScalarMappable(cmap="viridis", norm=Normalize(0, vmax))
    fig.colorbar(sm, ax=axes, shrink=0.6, label="edge strain at particle, % (clipped at 10)")
    fig.suptitle(f"Fig. 10: tablecloth 40 cm on a 20 cm table (σ = {sigma:g} cm)")
    fig.savefig(out / "fig10_tablecloth.png", dpi=110)
    return data


def fig11(out: Path, fast: bool, materials, cache: dict) -> dict:
    """Per-particle stretch / bending / shear force magnitudes on the tablecloth of the last material
    (the paper: wool), both models."""
    sigma, max_time = (2.5, 1.5) if fast else (1.0, 4.0)
    name = load_material(materials[-1]).name
    runs = _tablecloth_runs(materials[-1:], sigma, max_time, cache)
    fields = {mod: force_fields(runs[(name, mod)][0].model, runs[(name, mod)][1].state)
              for mod in MODELS}
    data = {"sigma_cm": sigma, "material": name, "units": "dyne", "results": {}}
    cam = Camera.look_at((0.0, -1e-3, 60.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), ortho_half_height=24.0)
    rnd = Renderer(300, 300, camera=cam, ambient=1.0)
    fig = figure((12, 8.4))
    axes = fig.subplots(2, 3)
    for k, force in enumerate(("stretch", "bending", "shear")):
        vmax = max(float(np.percentile(fields[mod][force], 99)) for mod in MODELS) or 1.0
        for i, mod in enumerate(MODELS):
            sc, res = runs[(name, mod)]
            v = fields[mod][force]
            q = res.state.particle_q
            h = sc.table_half_cm
            near = np.zeros(len(q), dtype=bool)
            for sx in (-1, 1):
                for sy in (-1, 1):
                    near |= np.hypot(q[:, 0] - sx * h, q[:, 1] - sy * h) < 4.0
            data["results"][f"{mod}_{force}"] = {"mean": float(v.mean()), "max": float(v.max()),
                                                 "p99": float(np.percentile(v, 99)),
                                                 "mean_near_table_corners": float(v[near].mean()),
                                                 "mean_elsewhere": float(v[~near].mean())}
            ax = axes[i, k]
            ax.imshow(rnd.render_scene(sc.model, res.state, particle_colors=colormap(v, "jet", 0.0, vmax),
                                       show_obstacles=False))
            ax.set_axis_off()
            ax.set_title(f"{MODEL_LABEL[mod]}: {force}\nmean {v.mean():.3g}, max {v.max():.3g} dyne", fontsize=9)
        sm = ScalarMappable(cmap="jet", norm=Normalize(0, vmax))
        fig.colorbar(sm, ax=axes[:, k], shrink=0.6, label=f"|F_{force}|, dyne")
    fig.suptitle(f"Fig. 11: restoring-force fields on the {name} tablecloth, seen from above (σ = {sigma:g} cm)")
    fig.savefig(out / "fig11_force_fields.png", dpi=110)
    return data


# ============================================================================ fig. 13
def fig13(out: Path, fast: bool, materials, cache: dict) -> dict:
    """Falling ribbon of the last material (the paper: wool), angular momentum on / off: final poses and a GIF."""
    sigma, max_time = (1.0, 2.5) if fast else (0.5, 3.0)
    cam = Camera.look_at((32.0, -52.0, 28.0), (2.0, 0.0, 12.0), fov_deg=40.0)
    rnd = Renderer(240, 200, camera=cam, ssaa=1)
    render = lambda m, s: rnd.render_scene(m, s)  # noqa: E731
    data = {"sigma_cm": sigma, "results": {}}
    finals = {}
    frames = {}
    for am in (True, False):
        sc = ribbon(materials[-1], angular_momentum=am, sigma=sigma, max_time_s=max_time)
        res = run_until_settled(sc, render=render, render_every=2)
        finals[am] = (sc, res.state)
        frames[am] = res.frames
        q = res.state.particle_q
        data["results"]["angular_momentum_on" if am else "angular_momentum_off"] = {
            "settled": res.settled, "settle_time_s": res.settle_time_s, "simulated_s": float(res.times[-1]),
            "wall_s": res.wall_s, "max_height_cm": float(q[:, 2].max()), "extent_x_cm": float(np.ptp(q[:, 0])),
            "extent_y_cm": float(np.ptp(q[:, 1])), "centroid_cm": q.mean(axis=0)}
    d = np.linalg.norm(finals[True][1].particle_q - finals[False][1].particle_q, axis=1)
    data["final_pose_difference_cm"] = {"rms": float(np.sqrt(np.mean(d ** 2))), "max": float(d.max())}
    top = Renderer(360, 300, camera=Camera.look_at((8.0, -16.0, 20.0), (2.0, 0.0, 0.0), fov_deg=40.0), ssaa=2)
    fig = figure((9, 4.2))
    axes = fig.subplots(1, 2)
    for ax, am in zip(axes, (True, False)):
        sc, st = finals[am]
        ax.imshow(top.render_scene(sc.model, st, particle_colors=colormap(sc.model.particle_grid[:, 0].astype(float),
                                                                          "viridis")))
        ax.set_axis_off()
        ax.set_title("angular momentum reflected" if am else "angular momentum not reflected", fontsize=9)
    fig.suptitle(f"Fig. 13: falling {finals[True][0].model.material.name} ribbon, final poses (colour: position along the ribbon; "
                 f"rms difference {data['final_pose_difference_cm']['rms']:.2f} cm)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "fig13_ribbon.png", dpi=110)
    n = max(len(frames[True]), len(frames[False]))
    pad = lambda fr, k: fr[min(k, len(fr) - 1)]  # noqa: E731
    gif = [np.concatenate([pad(frames[True], k), np.full((frames[True][0].shape[0], 4, 3), 255, np.uint8),
                           pad(frames[False], k)], axis=1) for k in range(n)]
    save_gif(out / "fig13_ribbon.gif", gif, fps=12.5)
    data["gif_frames"] = n
    return data


FIGURES = {3: fig3, 8: fig8, 10: fig10, 11: fig11, 13: fig13}


add_arguments = options.figures


def run_args(args: argparse.Namespace, command: str) -> dict:
    """Draw the figures ``args.fig`` into ``args.out``; returns {figure number: its JSON data}.

    Figures, their JSON and the runs they share are keyed by material name, so the materials
    must have distinct names (a :class:`~cloth_gym.MaterialError` otherwise)."""
    materials = tuple(args.material)
    names = [load_material(spec).name for spec in materials]  # a bad fabric fails here, before any figure
    if len(set(names)) < len(names):
        raise MaterialError("material", f"the figures need materials with distinct names, got {names} "
                            f"(from {list(materials)}); give each YAML its own 'name:'")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cache: dict = {}
    results = {}
    for n in args.fig:
        t0 = time.perf_counter()
        data = FIGURES[n](out, args.fast, materials, cache)
        data["figure"] = n
        data["fast"] = args.fast
        data["material_names"] = names
        data["command"] = command
        data["wall_s_total"] = time.perf_counter() - t0
        _write_json(out / f"fig{n}.json", data)
        print(f"fig. {n}: {data['wall_s_total']:.1f} s -> {out}/fig{n}*", flush=True)
        results[n] = data
    return results


def main(argv=None, prog: str = "cloth-gym figures") -> dict:
    return options.run("figures", run_args, argv, prog)
