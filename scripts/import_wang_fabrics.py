"""The measured fabrics of Wang, Ramamoorthi & O'Brien 2011, converted into the shipped materials.

The ten fabrics ship with ARCSim (``materials/*.json`` of ARCSim 0.2.1 and later, and of
repositories that carry ARCSim, e.g. ``wxhaooo/lyra``), under ARCSim's licence (educational,
research and not-for-profit use; the text is ``configs/materials/LICENSE-wang2011.txt``). Give
the directory that holds their JSON files:

    .venv/bin/python scripts/import_wang_fabrics.py --src path/to/arcsim/materials

Writes ``configs/materials/wang_<fabric>.yaml`` (``cloth_gym.reports.import_material``: the
material with its provenance) and ``docs/data/materials/wang2011.json``: per fabric the density,
the warp axis, the Poisson ratios the conversion drops, each polynomial fit's R² and largest
error, how far ARCSim's runtime table strays from its samples' blend (the tension at 1 % and
10 % strain), and the converted bending moment against ARCSim's hinges on bent meshes.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cloth_gym.reports.import_material import import_arcsim, write_material  # noqa: E402

# materials/README of ARCSim: "ivory-rib-knit: underwear 95% cotton 5% spandex", ...
FABRICS = {
    "ivory-rib-knit": ("rib knit (underwear)", "95 % cotton, 5 % spandex"),
    "pink-ribbon-brown": ("blanket", "100 % polyester"),
    "white-dots-on-blk": ("tablecloth", "100 % polyester"),
    "navy-sparkle-sweat": ("sweater knit", "96 % polyester, 4 % spandex"),
    "camel-ponte-roma": ("ponte roma knit (jacket)", "60 % polyester, 40 % rayon"),
    "gray-interlock": ("interlock knit (t-shirt)", "60 % cotton, 40 % polyester"),
    "11oz-black-denim": ("11 oz denim (jeans)", "99 % cotton, 1 % spandex"),
    "white-swim-solid": ("swimsuit knit", "87 % nylon, 13 % spandex"),
    "tango-red-jet-set": ("jacket fabric", "100 % polyester"),
    "royal-target": ("pants fabric", "65 % cotton, 35 % polyester"),
}

SOURCE = ("Wang, Ramamoorthi & O'Brien 2011, 'Data-driven elastic models for cloth: modeling and measurement', "
          "ACM TOG 30(4); the ARCSim material file {file} (ARCSim 0.2.1 materials/, also wxhaooo/lyra materials/)")

TERMS = ("ARCSim licence, (c) 2013 The Regents of the University of California: educational, research and "
         "not-for-profit use only, with the licence text (configs/materials/LICENSE-wang2011.txt) in every copy; "
         "publications cite Narain, Samii & O'Brien 2012 and Narain, Pfaff & O'Brien 2013 (and the measurements' "
         "authors, Wang, Ramamoorthi & O'Brien 2011). Commercial use: UC Berkeley Office of Technology Licensing.")


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", required=True, help="directory of ARCSim's material JSON files")
    ap.add_argument("--materials", default=str(ROOT / "configs" / "materials"))
    ap.add_argument("--json", default=str(ROOT / "docs" / "data" / "materials" / "wang2011.json"))
    args = ap.parse_args(argv)
    command = "python scripts/import_wang_fabrics.py " + shlex.join(sys.argv[1:] if argv is None else argv)
    src, out = Path(args.src), Path(args.materials)
    report = {"command": command, "commit": _commit(), "fabrics": {}}
    for stem, (kind, fibres) in FABRICS.items():
        name = "wang_" + stem.replace("-", "_")
        path = src / f"{stem}.json"
        data, material, _fits, arc = import_arcsim(
            path, name=name, description=f"{kind}, {fibres} (Wang et al. 2011, measured)",
            source=SOURCE.format(file=path.name), terms_of_use=TERMS)
        write_material(data, out / f"{name}.yaml",
                       f"{name}: {kind}, {fibres}. Measured by Wang, Ramamoorthi & O'Brien 2011, converted from\n"
                       f"ARCSim's {path.name} by `{command}`.\n"
                       "Data under the ARCSim licence (non-commercial): configs/materials/LICENSE-wang2011.txt.")
        axes = {"warp": 0 if data["provenance"]["warp_axis"].startswith("u") else 1}
        axes["weft"] = 1 - axes["warp"]
        table = {}
        for d, ax in axes.items():
            eps = np.array([0.01, 0.10])
            blend = arc.uniaxial_tension(eps, 90.0 * ax)
            runtime = arc.uniaxial_tension(eps, 90.0 * ax, table=True)
            table[d] = [round(float(100.0 * (r / b - 1.0)), 2) for r, b in zip(runtime, blend)]
        mesh = {}
        for d, ax in axes.items():
            k = np.array([0.05, 0.2, 0.4])
            closed = arc.bending_moment(k, ax)
            ref = np.array([arc.mesh_bending_moment(x, ax, rotations=60) for x in k])
            mesh[d] = round(float(100.0 * np.max(np.abs(closed / ref - 1.0))), 3)
        report["fabrics"][name] = {
            "kind": kind, "fibres": fibres,
            "areal_density_g_per_cm2": material.areal_density,
            "warp_axis": data["provenance"]["warp_axis"][0],
            "poisson_ratio_dropped": data["provenance"]["poisson_ratio_dropped"],
            "fit": data["provenance"]["fit"],
            "runtime_table_tension_vs_blend_percent_at_1_and_10_percent_strain": table,
            "bending_closed_form_vs_bent_meshes_max_percent": mesh,
            "coefficients": {k: data[k] for k in ("stretch", "bending", "shear")},
        }
        fit = data["provenance"]["fit"]
        print(f"{name:32s} {material.areal_density:.4f} g/cm²  warp {data['provenance']['warp_axis'][0]}  "
              f"worst fit: stretch {max(fit[f'stretch.{d}']['max_error_percent_of_max'] for d in axes):.1f} %, "
              f"bending {max(fit[f'bending.{d}']['max_error_percent_of_max'] for d in axes):.1f} %, "
              f"shear {max(fit[f'shear.{d}']['max_error_percent_of_max'] for d in axes):.1f} %; "
              f"table vs blend {table}; bending vs meshes {max(mesh.values()):.2f} %")
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
    print(f"-> {out}/wang_*.yaml, {args.json}")
    return report


if __name__ == "__main__":
    main()
