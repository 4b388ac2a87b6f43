#!/usr/bin/env python
"""Error against run time, for each integrator (and the spatial side: a static metric against σ).

Temporal: a 20 cm cotton square hanging from two corners (σ = 1 cm), and a 40 cm
tablecloth dropping onto a 20 cm table (σ = 2 cm). A reference solution at a
tiny Δt (explicit, 1/8 of its stability limit), then for each integrator
(explicit; implicit backward Euler and BDF2 with one linearised Newton pass, BDF2 with two
passes, and both with Newton iterated to 0.1 cm/s and momentum-exact solves) a sweep of Δt:
position error (RMS and max over particles, cm) at fixed times against wall and process CPU time. Spatial: the sag (cm) of the hanging square after it
settles (damping raised to 5/s, 2 s, implicit Δt = 2 ms) for σ = 4 … 0.25 cm: the dip of the
middle of the held edge below the two held corners.

Writes ``<out>/work_precision/{work_precision.csv, work_precision.md, work_precision.png}``.

    python scripts/work_precision.py [--out outputs] [--quick]
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from cloth_gym import ClothGymError, load_material  # noqa: E402
from cloth_gym.reports.options import command_line
from cloth_gym.reports.provenance import stamp, stamp_line  # noqa: E402
from cloth_gym.scenes import hanging_cloth, tablecloth  # noqa: E402
from cloth_gym.sim import SymplecticEuler, explicit_stability_limit  # noqa: E402
from cloth_gym.sim.implicit import ImplicitEuler  # noqa: E402

#: Newton iterated until the next correction's mass-weighted RMS is within 0.1 cm/s (at most 10 passes),
#: momentum-exact solves: RibbonDrop-v2's setting (docs/numerics.md, "Rotation and the Newton solve")
CONVERGED = {"newton_iters": 10, "newton_tol": 0.1, "momentum_exact": True}
#: each integrator's name in the table and its plot marker
MARKERS = {"explicit": "o", "implicit": "s", "implicit bdf2": "^", "implicit bdf2 x2 newton": "v",
           "implicit converged": "D", "implicit bdf2 converged": "P"}

SCENES = {
    "hanging (20 cm, sigma 1)": lambda: hanging_cloth("thick_cotton", 20.0, 1.0),
    "tablecloth (40 cm, sigma 2)": lambda: tablecloth(sigma=2.0),
}


def simulate(build, integ, times, frame=0.01):
    """Positions at each of ``times``, and the wall and process CPU time (s) of the whole run
    (compilation excluded: one throw-away step on another copy of the scene first)."""
    warm = build()
    integ.step(warm, warm.state(), None, frame)
    m = build()
    s = m.state()
    out = []
    t0, c0 = time.perf_counter(), time.process_time()
    t = 0.0
    for target in times:
        while t < target - 1e-12:
            integ.step(m, s, None, frame)
            t += frame
        out.append(s.particle_q.copy())
    return out, time.perf_counter() - t0, time.process_time() - c0


def temporal(quick):
    times = [0.25, 0.5] if not quick else [0.1]
    rows = []
    for scene, build in SCENES.items():
        lim = explicit_stability_limit(build()).dt_limit_s
        ref, ref_wall, _ = simulate(build, SymplecticEuler(safety=0.125, on_unstable="substep"), times)
        print(f"{scene}: reference (explicit, dt = {lim / 8:.2e} s) took {ref_wall:.1f} s", flush=True)
        sweeps = [("explicit", SymplecticEuler(safety=f, on_unstable="substep"), f * lim) for f in (0.5, 0.25)]
        dts = (1e-2, 5e-3, 2e-3, 1e-3, 5e-4) if not quick else (5e-3, 1e-3)
        sweeps += [("implicit", ImplicitEuler(max_dt=dt), dt) for dt in dts]
        sweeps += [("implicit bdf2", ImplicitEuler(max_dt=dt, scheme="bdf2"), dt) for dt in dts]
        sweeps += [("implicit bdf2 x2 newton", ImplicitEuler(max_dt=dt, scheme="bdf2", newton_iters=2), dt)
                   for dt in dts]
        sweeps += [(name, ImplicitEuler(max_dt=dt, scheme=scheme, **CONVERGED), dt)
                   for name, scheme in (("implicit converged", "euler"), ("implicit bdf2 converged", "bdf2"))
                   for dt in dts]
        for name, integ, dt in sweeps:
            try:
                pos, wall, cpu = simulate(build, integ, times)
            except ClothGymError as err:
                print(f"  {name} dt={dt:.2e}: {err}")
                rows.append({"scene": scene, "integrator": name, "dt_s": dt, "time_s": times[-1], "wall_s": float("nan"),
                             "cpu_s": float("nan"), "err_rms_cm": float("nan"), "err_max_cm": float("nan"),
                             "error": f"{type(err).__name__}: {err}"})
                continue
            for t, p, r in zip(times, pos, ref):
                err = np.linalg.norm(p - r, axis=1)
                rows.append({"scene": scene, "integrator": name, "dt_s": dt, "time_s": t, "wall_s": wall,
                             "cpu_s": cpu, "err_rms_cm": float(np.sqrt(np.mean(err ** 2))), "err_max_cm": float(err.max()),
                             "error": ""})
            print(f"  {name:8s} dt={dt:.2e} wall={wall:6.2f}s cpu={cpu:6.2f}s err@{times[-1]}s rms={rows[-1]['err_rms_cm']:.3g} "
                  f"max={rows[-1]['err_max_cm']:.3g} cm", flush=True)
    return rows


def spatial(quick):
    rows = []
    sigmas = (4.0, 2.0, 1.0, 0.5, 0.25) if not quick else (4.0, 2.0, 1.0)
    mat = load_material("thick_cotton").replace(damping=5.0)
    for sigma in sigmas:
        warm = hanging_cloth(mat, 20.0, sigma)  # compiles the kernels of this size's preconditioner, untimed
        ImplicitEuler(max_dt=2e-3).advance(warm, warm.state(), None, 2e-3, 2e-3)
        m = hanging_cloth(mat, 20.0, sigma)
        s = m.state()
        t0, c0 = time.perf_counter(), time.process_time()
        ImplicitEuler(max_dt=2e-3).advance(m, s, None, 2.0 if not quick else 0.5, 2e-3)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        nx = m.grid_index.shape[0]
        mid = m.index(nx // 2, -1)  # middle of the held edge, between the two pinned corners
        sag = float(s.particle_q[m.pinned, 2].mean() - s.particle_q[mid, 2])
        rows.append({"sigma_cm": sigma, "particles": m.particle_count, "sag_cm": sag, "wall_s": wall, "cpu_s": cpu})
        print(f"  sigma={sigma}: sag {sag:.3f} cm, {wall:.1f} s", flush=True)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="outputs")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    provenance = stamp(command_line("python scripts/work_precision.py", sys.argv[1:] if argv is None else argv))
    out = Path(args.out) / "work_precision"
    out.mkdir(parents=True, exist_ok=True)
    rows = temporal(args.quick)
    srows = spatial(args.quick)
    with open(out / "work_precision.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    with open(out / "spatial.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(srows[0]))
        w.writeheader()
        w.writerows(srows)

    fig, axes = plt.subplots(1, len(SCENES) + 1, figsize=(6 * (len(SCENES) + 1), 5))
    last_t = max(r["time_s"] for r in rows)
    md = [stamp_line(provenance), "",
          "| scene | integrator | Δt (s) | wall (s) | CPU (s) | RMS error (cm) | max error (cm) |", "|---|---|---|---|---|---|---|"]
    for ax, scene in zip(axes, SCENES):
        for k, (name, marker) in enumerate(MARKERS.items()):
            sel = [r for r in rows if r["scene"] == scene and r["integrator"] == name and r["time_s"] == last_t
                   and not r["error"]]
            if not sel:
                continue
            # one colour per integrator: RMS solid, max dotted and faint
            ax.loglog([r["cpu_s"] for r in sel], [r["err_rms_cm"] for r in sel], marker + "-", color=f"C{k}",
                      label=name)
            ax.loglog([r["cpu_s"] for r in sel], [r["err_max_cm"] for r in sel], marker + ":", color=f"C{k}",
                      alpha=0.35)
            for r in sel:
                ax.annotate(f"{r['dt_s']:.0e}", (r["cpu_s"], r["err_rms_cm"]), fontsize=6)
                md.append(f"| {scene} | {name} | {r['dt_s']:.2e} | {r['wall_s']:.2f} | {r['cpu_s']:.2f} | {r['err_rms_cm']:.3g} | "
                          f"{r['err_max_cm']:.3g} |")
        for r in rows:
            if r["scene"] == scene and r["error"]:
                md.append(f"| {scene} | {r['integrator']} | {r['dt_s']:.2e} | — | — | diverged | "
                          f"{r['error'][:80]} |")
        ax.set(xlabel="CPU time (s)", ylabel=f"position error at t = {last_t} s (cm): RMS solid, max dotted",
               title=scene)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="lower left")
    ax = axes[-1]
    ax.semilogx([r["sigma_cm"] for r in srows], [r["sag_cm"] for r in srows], "o-")
    for r in srows:
        ax.annotate(f"{r['cpu_s']:.1f} s", (r["sigma_cm"], r["sag_cm"]), fontsize=7)
    ax.set(xlabel="sigma (cm)", ylabel="dip of the held edge (cm)", title="spatial: sag vs sigma (CPU time)")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "work_precision.png", dpi=100)
    md += ["", "| sigma (cm) | particles | dip of held edge (cm) | wall (s) | CPU (s) |", "|---|---|---|---|---|"]
    md += [f"| {r['sigma_cm']} | {r['particles']} | {r['sag_cm']:.3f} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} |"
           for r in srows]
    (out / "work_precision.md").write_text("\n".join(md) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
