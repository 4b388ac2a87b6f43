#!/usr/bin/env python
"""Drape test over several lattice spacings and seeds: the table of docs/drape_results.md.

Runs :func:`cloth_gym.reports.drape.run` (what ``cloth-gym drape`` and ``scripts/drape_test.py``
run: the same scene, settling rule and metrics) for each (material, σ, seed) case, prints one
table row per case as it finishes, and writes the rows with a stamp
(:func:`cloth_gym.reports.provenance.stamp`: git commit, uncommitted files, machine, command
line) to ``--out`` after every case, so an interrupted run keeps what it finished.

    python scripts/drape_results.py                       # the documented cases (about 15 min on one core)
    python scripts/drape_results.py --sigma 1.0 --seeds 0 1 2 --materials thin_wool
    python scripts/drape_results.py --table docs/data/drape_results.json   # its stamp line and table, run nothing
    python scripts/drape_results.py --materials library --sigma 0.5 --geometry cusick \
        --out docs/data/drape_fabrics.json          # every shipped fabric on the Cusick tester

``--materials library`` is every shipped material (``cloth_gym.materials.available_materials()``);
``--geometry`` the tester (``paper``: 25.4 cm disc on a 12.7 cm pedestal; ``cusick``: 30 cm on
18 cm, the standard tester the published drape coefficients of fabric families come from).

Cases: every ``--materials`` × ``--sigma`` × ``--seeds``. Without ``--sigma`` and ``--seeds`` the
documented set: σ = 2.0 and 1.5 cm with seed 0, σ = 1.0 and 0.5 cm with seeds 0, 1 and 2. Without
one of the two, ``--sigma`` is 1.0 and ``--seeds`` is 0. Cases run from the coarsest σ down: a σ =
0.5 cm case (2,025 particles) takes one to a few minutes on one core, one at σ ≥ 1 cm seconds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from cloth_gym.materials import available_materials
from cloth_gym.reports.drape import run
from cloth_gym.reports.options import command_line
from cloth_gym.reports.provenance import stamp, stamp_line

DEFAULT_CASES = [(2.0, 0), (1.5, 0), (1.0, 0), (1.0, 1), (1.0, 2), (0.5, 0), (0.5, 1), (0.5, 2)]
COLUMNS = ("material", "sigma_cm", "seed", "drape_coefficient", "node_count", "settle_time_s",
           "max_strain_warp_percent", "max_strain_weft_percent", "wall_s", "cpu_s")


def cases(materials, sigmas, seeds) -> list[tuple[str, float, int]]:
    if sigmas is None and seeds is None:
        pairs = DEFAULT_CASES
    else:
        pairs = [(s, n) for s in (sigmas or [1.0]) for n in (seeds if seeds is not None else [0])]
    pairs = sorted(set(pairs), key=lambda p: (-p[0], p[1]))  # coarsest (fastest) first
    return [(m, s, n) for s, n in pairs for m in materials]


def _cell(key: str, v) -> str:
    if v is None:
        return "—"
    if key == "material":
        return str(v).replace("_", " ")
    if key == "drape_coefficient":
        return f"{v:.3f}"
    if key.startswith("max_strain"):
        return f"{v:.2f} %"
    if key == "settle_time_s":
        return f"{v:.2f} s"
    if key in ("wall_s", "cpu_s"):
        return f"{v / 60:.1f} min" if v >= 600 else f"{v:.0f} s" if v >= 10 else f"{v:.1f} s"
    return f"{v:g}"


HEADER = ("| material | σ (cm) | seed | DC | nodes | settle time | max strain warp / weft | wall time | CPU time |\n"
          "|---|---|---|---|---|---|---|---|---|")


def table_row(r: dict) -> str:
    c = {k: _cell(k, r.get(k)) for k in COLUMNS}
    if not r.get("settled", True):
        c["settle_time_s"] = f"not settled in {r['simulated_s']:g} s"
    return (f"| {c['material']} | {c['sigma_cm']} | {c['seed']} | {c['drape_coefficient']} | {c['node_count']} | "
            f"{c['settle_time_s']} | {c['max_strain_warp_percent']} / {c['max_strain_weft_percent']} | "
            f"{c['wall_s']} | {c['cpu_s']} |")


def markdown_table(rows: list[dict]) -> str:
    """The rows by material, then from the coarsest σ down, then by seed."""
    rows = sorted(rows, key=lambda r: (r["material"], -r["sigma_cm"], r["seed"]))
    return "\n".join([HEADER, *(table_row(r) for r in rows)])


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--materials", nargs="+", default=["thick_cotton", "thin_wool"],
                    help="material names or YAML paths; 'library': every shipped material")
    ap.add_argument("--geometry", choices=("paper", "cusick"), default="paper",
                    help="drape tester: paper 25.4 cm disc on 12.7 cm, cusick 30 cm on 18 cm")
    ap.add_argument("--sigma", nargs="+", type=float, help="lattice spacings, cm")
    ap.add_argument("--seeds", nargs="+", type=int, help="seeds of the start-height perturbation")
    ap.add_argument("--max-time", type=float, default=8.0, help="give up after this simulated time, s")
    ap.add_argument("--out", default="docs/data/drape_results.json")
    ap.add_argument("--table", metavar="JSON", help="print a results file's stamp line and Markdown table, and exit")
    ap.add_argument("--quiet", action="store_true", help="no kinetic-energy progress on stderr")
    args = ap.parse_args(argv)

    if args.table:
        doc = json.loads(Path(args.table).read_text())
        print(f"{stamp_line(doc['stamp'])}\n\n{markdown_table(doc['rows'])}")
        return doc

    materials = list(dict.fromkeys(n for m in args.materials for n in (available_materials() if m == "library"
                                                                        else [m])))  # each once, in order
    todo = cases(materials, args.sigma, args.seeds)
    command = command_line("python scripts/drape_results.py", argv)
    doc = {"stamp": stamp(command), "geometry": args.geometry, "max_time_s": args.max_time, "complete": False,
           "rows": []}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    run(todo[0][0], "kes", 2.5, "paper", 0.05, 0, True)  # compiles the kernels, so no row's time includes that
    print(f"warm-up {time.perf_counter() - t0:.0f} s; {len(todo)} cases -> {out}\n{HEADER}", flush=True)
    for material, sigma, seed in todo:
        cpu0, wall0 = time.process_time(), time.perf_counter()
        _, _, _, m = run(material, "kes", sigma, args.geometry, args.max_time, seed, args.quiet)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0  # scene build + settling
        row = {"material": Path(material).stem, "geometry": args.geometry, "sigma_cm": sigma, "seed": seed,
               **{k: m[k] for k in ("drape_coefficient", "node_count", "settled", "settle_time_s", "simulated_s",
                                    "max_strain_warp_percent", "max_strain_weft_percent", "particles", "integrator")},
               "wall_s": wall, "cpu_s": cpu}
        doc["rows"].append(row)
        doc["complete"] = len(doc["rows"]) == len(todo)
        out.write_text(json.dumps(doc, indent=2) + "\n")
        print(table_row(row), flush=True)
    return doc


if __name__ == "__main__":
    main()
