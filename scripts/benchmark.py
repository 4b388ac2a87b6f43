#!/usr/bin/env python
"""Benchmark: particle-steps/s and CPU and wall seconds per simulated second.

Scene: 40 cm square of cotton draping over a 20 cm table from 10 cm above, at
21×21, 41×41 and 81×81 particles (σ = 2, 1, 0.5 cm), for each integrator.
Compile (or cache-load) time is measured apart, on a first 1-step call.
Writes ``<out>/benchmark/benchmark.json`` and ``benchmark.md``.

    python scripts/benchmark.py [--out outputs] [--sizes 21 41 81] [--duration 1.0] [--explicit-duration 0.1]
                                [--implicit 1e-3 1e-2:1e-3 2e-2:1e-3:1.0 ...] [--threads N]

``--implicit`` lists the implicit variants as ``dt[:tol[:strain_limit_percent[:strain_iters]]]``
(CG relative tolerance, default 1e-4; strain limiter, default off; its sweeps per step, default 100). Each row reports the largest strain
over the run (the impact of the drop included) and the strain at its end (the settled
drape; the accurate solution's is 0.2 % on the 41×41 cloth), wall and CPU time, and the heights
(z, cm; the table top is at 0) of the cloth's four corners and four edge midpoints at the end.
With ``--reference-dt`` each row also reports its position error against the reference run and
the largest difference of those eight heights from the reference's (with ``--duration 3``: the
settled drape).

Side by side with other code: ``--compare-tree DIR`` (e.g. a ``git worktree`` of an earlier
commit) runs every implicit row twice, in fresh processes taking turns, once importing
``cloth_gym`` from DIR and once from this checkout, and reports both and their ratio; the
reference (``--reference-dt``) is computed by this checkout. ``--threads`` sets numba's thread
count (``NUMBA_NUM_THREADS``) of those processes.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from cloth_gym import ClothGymError
from cloth_gym.reports.options import command_line
from cloth_gym.reports.provenance import stamp
from cloth_gym.scenes import tablecloth
from cloth_gym.sim import SymplecticEuler
from cloth_gym.sim.diagnostics import edge_strain
from cloth_gym.sim.implicit import ImplicitEuler

SIGMA = {21: 2.0, 41: 1.0, 81: 0.5}
REFERENCE_TOL = 1e-5  # CG tolerance of the --reference-dt run


def _command(argv) -> str:
    """The command line that regenerates this run's files."""
    args = argv if argv is not None else sys.argv[1:]
    return command_line("python scripts/benchmark.py", args)


def drape_points(model) -> list[int]:
    """The particles whose heights describe the settled drape: the four corners, then the
    midpoints of the four edges."""
    mi, mj = (n // 2 for n in model.grid_index.shape)
    return [model.index(0, 0), model.index(-1, 0), model.index(0, -1), model.index(-1, -1),
            model.index(mi, 0), model.index(0, mj), model.index(-1, mj), model.index(mi, -1)]


def run(n, integrator, duration, dt, tol=1e-4, limit=None, strain_iters=100, reference=None):
    m = tablecloth(sigma=SIGMA[n])
    integ = (SymplecticEuler(on_unstable="substep") if integrator == "explicit"
             else ImplicitEuler(max_dt=dt, tol=tol, strain_limit_percent=limit, strain_iters=strain_iters))
    s = m.state()
    t0 = time.perf_counter()
    integ.step(m, s, None, integ.stability(m).dt_limit_s * 0.5 if integrator == "explicit" else dt)
    first = time.perf_counter() - t0
    steps0 = s.step
    max_strain = 0.0
    t0 = time.perf_counter()
    c0 = time.process_time()
    frame = 0.02 if integrator == "explicit" else max(0.02, dt)  # one frame: at least one step
    n_frames = max(1, int(round(duration / frame)))
    for _ in range(n_frames):
        integ.step(m, s, None, frame)
        max_strain = max(max_strain, float(edge_strain(m, s).max()))
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    steps = s.step - steps0
    sim = n_frames * frame
    row = {
        "particles": m.particle_count, "grid": f"{n}x{n}", "sigma_cm": SIGMA[n], "integrator": integrator,
        "dt_s": sim / steps, "simulated_s": sim, "steps": steps, "wall_s": wall,
        "wall_per_simulated_s": wall / sim, "cpu_per_simulated_s": cpu / sim,
        "particle_steps_per_s": m.particle_count * steps / wall,
        "max_strain_percent": max_strain, "final_strain_percent": float(edge_strain(m, s).max()),
        "first_call_s": first,
    }
    points = drape_points(m)
    row["drape_heights_cm"] = s.particle_q[points, 2].tolist()
    if reference is not None and n in reference and abs(sim - duration) < 1e-9:
        d = np.linalg.norm(s.particle_q - reference[n], axis=1)
        row.update(error_rms_cm=float(np.sqrt(np.mean(d * d))), error_max_cm=float(d.max()),
                   drape_error_cm=float(np.abs(s.particle_q[points, 2] - reference[n][points, 2]).max()))
    row["final_positions"] = s.particle_q.copy()
    if integrator == "implicit":
        row.update(cg_iterations_mean=float(integ.last_stats[:, 0].mean()), tol=tol, strain_limit_percent=limit,
                   strain_iters=strain_iters if limit is not None else None,
                   preconditioner=integ.preconditioner_for(m))
    return row


_COLD = """
import time, sys
t0 = time.perf_counter()
from cloth_gym import ClothGymError
from cloth_gym.scenes import tablecloth
from cloth_gym.sim import SymplecticEuler
from cloth_gym.sim.implicit import ImplicitEuler
t1 = time.perf_counter()
m = tablecloth(sigma=4.0)
SymplecticEuler(on_unstable="substep").step(m, m.state(), None, 1e-3)
t2 = time.perf_counter()
ImplicitEuler(max_dt=1e-3).step(m, m.state(), None, 1e-3)
t3 = time.perf_counter()
print(t1 - t0, t2 - t1, t3 - t2)
"""


def compile_times():
    """Import and first-call times (s) with an empty numba cache (a fresh NUMBA_CACHE_DIR)."""
    import os
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        out = subprocess.run([sys.executable, "-c", _COLD], env=env, capture_output=True, text=True, check=True)
    imp, explicit, implicit = (float(v) for v in out.stdout.split())
    return {"import_s": imp, "explicit_compile_s": explicit, "implicit_compile_s": implicit}


def _child(spec: dict) -> dict:
    """One implicit row in this process (``--child``): the error against the saved reference."""
    ref = None
    if spec.get("reference"):
        ref = {spec["n"]: np.load(spec["reference"])}
    row = run(spec["n"], "implicit", spec["duration"], spec["dt"], spec["tol"], spec["limit"], spec["iters"], ref)
    row.pop("final_positions")
    return row


def compare_trees(args, variants, reference_path):
    """Each implicit row in fresh processes, alternating the other tree and this one (module docstring)."""
    import hashlib
    import subprocess
    import tempfile

    here = str(Path(__file__).resolve().parents[1])
    rows = []
    for n in args.sizes:
        for _, dt, tol, limit, iters in variants:
            spec = {"n": n, "duration": args.duration, "dt": dt, "tol": tol, "limit": limit, "iters": iters,
                    "reference": reference_path.get(n)}
            pair = {}
            for label, tree in (("other", args.compare_tree), ("this", here)):
                # each tree its own numba cache: numba keys cached kernels on their file's path and
                # time stamp, so two checkouts sharing one cache would recompile each other's kernels
                cache = Path(tempfile.gettempdir()) / "cloth_gym_benchmark_cache" / hashlib.sha1(
                    str(Path(tree).resolve()).encode()).hexdigest()[:12]
                env = {**os.environ, "PYTHONPATH": tree, "NUMBA_CACHE_DIR": str(cache)}
                if args.threads:
                    env["NUMBA_NUM_THREADS"] = str(args.threads)
                # a first call in the same tree compiles (or loads the cache) outside the timed run
                out = subprocess.run([sys.executable, __file__, "--child", json.dumps(spec)], env=env,
                                     capture_output=True, text=True)
                if out.returncode != 0:
                    pair[label] = {"error": out.stderr.strip().splitlines()[-1] if out.stderr else "failed"}
                else:
                    pair[label] = json.loads(out.stdout.strip().splitlines()[-1])
            row = {"grid": f"{n}x{n}", "dt_s": dt, "tol": tol, "strain_limit_percent": limit,
                   "other": pair["other"], "this": pair["this"]}
            if "error" not in pair["other"] and "error" not in pair["this"]:
                row["cpu_ratio_other_over_this"] = pair["other"]["cpu_per_simulated_s"] / pair["this"]["cpu_per_simulated_s"]
                row["wall_ratio_other_over_this"] = (pair["other"]["wall_per_simulated_s"]
                                                     / pair["this"]["wall_per_simulated_s"])
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def _compare_table(rows, meta) -> str:
    def cell(r, key, fmt):
        return "–" if "error" in r or r.get(key) is None else format(r[key], fmt)

    lines = [f"Other tree: `{meta['compare_tree']}`; this checkout: `{meta['commit']}`; numba threads: "
             f"{meta['threads'] or 'default'}.", "",
             "| grid | Δt (s) | CG tol | CPU / sim s, other | CPU / sim s, this | ratio | wall / sim s, other | "
             "wall / sim s, this | ratio | mean CG its, other / this | error RMS (cm), other / this |",
             "|" + "---|" * 11]
    for r in rows:
        o, t = r["other"], r["this"]
        lines.append(f"| {r['grid']} | {r['dt_s']:.2e} | {r['tol']:.0e} | {cell(o, 'cpu_per_simulated_s', '.2f')} | "
                     f"{cell(t, 'cpu_per_simulated_s', '.2f')} | {r.get('cpu_ratio_other_over_this', float('nan')):.2f} | "
                     f"{cell(o, 'wall_per_simulated_s', '.2f')} | {cell(t, 'wall_per_simulated_s', '.2f')} | "
                     f"{r.get('wall_ratio_other_over_this', float('nan')):.2f} | "
                     f"{cell(o, 'cg_iterations_mean', '.1f')} / {cell(t, 'cg_iterations_mean', '.1f')} | "
                     f"{cell(o, 'error_rms_cm', '.3f')} / {cell(t, 'error_rms_cm', '.3f')} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="outputs")
    ap.add_argument("--sizes", type=int, nargs="+", default=[21, 41, 81], choices=sorted(SIGMA))
    ap.add_argument("--duration", type=float, default=1.0, help="simulated seconds (implicit)")
    ap.add_argument("--explicit-duration", type=float, default=0.1,
                    help="simulated seconds for the explicit integrator (it is slow; wall/s is extrapolated)")
    ap.add_argument("--implicit", nargs="+", default=["1e-3", "1e-2:1e-3", "2e-2:1e-3", "2e-2:1e-3:1.0"],
                    help="implicit variants dt[:tol[:strain_limit_percent[:strain_iters]]]")
    ap.add_argument("--no-explicit", action="store_true", help="implicit rows only")
    ap.add_argument("--reference-dt", type=float, default=None,
                    help="also run the implicit integrator at this Δt (s; CG tolerance 1e-5, no limiter) and report "
                         "each row's position error against it at the end of the run (cm)")
    ap.add_argument("--skip-compile-time", action="store_true",
                    help="do not measure compilation with an empty cache (it takes about a minute)")
    ap.add_argument("--compare-tree", default=None,
                    help="another checkout (e.g. a git worktree of an earlier commit): run each implicit row under "
                         "it and under this checkout, in turns, and report both (module docstring)")
    ap.add_argument("--threads", type=int, default=None, help="numba threads of the --compare-tree processes")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(_child(json.loads(args.child))))
        return
    provenance = stamp(_command(argv))  # the code about to run
    cold = None if args.skip_compile_time or args.compare_tree else compile_times()
    print("compile (empty cache):", json.dumps(cold))
    variants = []
    for v in args.implicit:
        parts = v.split(":")
        variants.append(("implicit", float(parts[0]), float(parts[1]) if len(parts) > 1 else 1e-4,
                         float(parts[2]) if len(parts) > 2 else None, int(parts[3]) if len(parts) > 3 else 100))
    if not args.no_explicit:
        variants.append(("explicit", None, None, None, None))
    rows = []
    reference = {}
    out = Path(args.out) / "benchmark"
    out.mkdir(parents=True, exist_ok=True)
    reference_path = {}
    for n in args.sizes if args.reference_dt else []:
        ref = run(n, "implicit", args.duration, args.reference_dt, REFERENCE_TOL)
        reference[n] = ref.pop("final_positions")
        reference_path[n] = str((out / f"reference_{n}.npy").resolve())
        np.save(reference_path[n], reference[n])
        ref["reference"] = True
        rows.append(ref)
        print(json.dumps(ref), flush=True)
    if args.compare_tree:
        import subprocess

        try:
            other = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                   cwd=args.compare_tree, timeout=10).stdout.strip() or "unknown"
        except (OSError, subprocess.SubprocessError):
            other = "unknown"
        meta = {**provenance, "compare_tree": f"checkout at {other}", "threads": args.threads,
                "cpus": os.cpu_count(), "scene": "40 cm cotton square over 20 cm table from 10 cm"}
        cmp_rows = compare_trees(args, [v for v in variants if v[0] == "implicit"], reference_path)
        meta["load_average_at_end"] = list(os.getloadavg())
        (out / "compare.json").write_text(json.dumps({"meta": meta, "reference": rows, "rows": cmp_rows}, indent=2))
        table = _compare_table(cmp_rows, meta)
        (out / "compare.md").write_text(table)
        print(table)
        return
    for n in args.sizes:
        for integrator, dt, tol, limit, iters in variants:
            dur = args.duration if integrator == "implicit" else args.explicit_duration
            try:
                row = run(n, integrator, dur, dt, tol, limit, iters, reference)
                row.pop("final_positions")
            except ClothGymError as err:  # recorded as a row
                row = {"particles": None, "grid": f"{n}x{n}", "sigma_cm": SIGMA[n], "integrator": integrator,
                       "dt_s": dt, "tol": tol, "strain_limit_percent": limit, "error": f"{type(err).__name__}: {err}"}
            rows.append(row)
            print(json.dumps(row), flush=True)
    meta = {**provenance, "python": platform.python_version(), "cpus": os.cpu_count(),
            "scene": "40 cm cotton square over 20 cm table from 10 cm", "load_average_at_end": list(os.getloadavg())}
    (out / "benchmark.json").write_text(json.dumps({"meta": meta, "compile": cold, "rows": rows}, indent=2))
    lines = ["| grid | integrator | Δt (s) | CG tol | strain limit (%) / sweeps | simulated (s) | wall / simulated s | "
             "CPU / simulated s | particle-steps/s | max strain (%) | final strain (%) | mean CG its | "
             "first call (s) | error at the end, RMS / max (cm) | drape heights, largest error (cm) |",
             "|" + "---|" * 15]

    def opt(v, fmt):
        return "–" if v is None else format(v, fmt)

    for r in rows:
        head = (f"| {r['grid']} | {r['integrator']} | {r['dt_s']:.2e} | {opt(r.get('tol'), '.0e')} | "
                f"{opt(r.get('strain_limit_percent'), 'g')}"
                f"{'' if r.get('strain_iters') is None else ' / ' + str(r['strain_iters'])} |"
                if r["integrator"] == "implicit" else
                f"| {r['grid']} | {r['integrator']} | {r['dt_s']:.2e} | – | – |")
        if "error" in r:
            lines.append(head + f" diverged | | | | | | | {r['error'][:90]} | | |")
            continue
        lines.append(head + f" {r['simulated_s']:.2f} | {r['wall_per_simulated_s']:.2f} | "
                     f"{r['cpu_per_simulated_s']:.2f} | {r['particle_steps_per_s']:.3g} | "
                     f"{r['max_strain_percent']:.2f} | {r['final_strain_percent']:.2f} | "
                     f"{r.get('cg_iterations_mean', float('nan')):.1f} | {r['first_call_s']:.2f} | "
                     + ("reference | reference" if r.get("reference") else
                        f"{r['error_rms_cm']:.2f} / {r['error_max_cm']:.2f} | {r['drape_error_cm']:.2f}"
                        if "error_rms_cm" in r else "– | –") + " |")
    if cold:
        lines += ["", f"Compilation with an empty numba cache: import {cold['import_s']:.1f} s, explicit integrator "
                  f"{cold['explicit_compile_s']:.1f} s, implicit integrator {cold['implicit_compile_s']:.1f} s (then "
                  "cached on disk: the 'first call' column is a warm-cache first call)."]
    (out / "benchmark.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
