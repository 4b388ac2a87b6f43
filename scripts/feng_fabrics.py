#!/usr/bin/env python
"""What the conversion of Feng et al. 2022's bending records does to them (numbers for
docs/materials.md), from your copy of ``dataset/dataset.csv`` (not shipped: no licence).

    python scripts/feng_fabrics.py --src ClothDrapeTester/dataset/dataset.csv \
        --out docs/data/materials/feng2022.json

Writes: the file's SHA-256, rows and distinct records, the density range, how many warp/weft
curves the clamp changed and by how much, the fit's largest error per curve (percent of the
curve's top, percentiles), and how many records take their stretch and shear from each shipped
material. Summary statistics only, never the records.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from cloth_gym.arcsim import CURVATURE_PER_CM
from cloth_gym.feng import clamped_moment, read_feng2022, record_material
from cloth_gym.materials import available_materials, load_material
from cloth_gym.reports.options import command_line
from cloth_gym.reports.provenance import stamp


def summary(src: str) -> dict:
    data = Path(src).read_bytes()
    rows = sum(1 for line in data.decode().splitlines()[1:] if line.strip())
    records = read_feng2022(src)
    library = [load_material(n) for n in available_materials()]
    k = CURVATURE_PER_CM
    clamp, err, bases = [], [], Counter()
    for r in records:
        m = record_material(r, library)
        bases[m.description.split(" of ")[-1].split(" (")[0]] += 1
        for d in ("warp", "weft"):
            raw, c = r.moment_gf_cm_per_cm(d, k), clamped_moment(r, d, k)
            clamp.append(float(np.max(c - raw) / c.max()))
            err.append(float(np.max(np.abs(getattr(m.bending, d)(k) - c)) / c.max()))
    clamp, err = np.array(clamp), np.array(err)
    dens = np.array([r.density_kg_per_m2 * 1000 for r in records])
    q = np.array([r.quadratic_n_m2[:2] for r in records])
    pct = (0, 5, 50, 95, 100)
    return {
        "source_sha256": hashlib.sha256(data).hexdigest(), "rows": rows, "distinct_records": len(records),
        "density_g_per_m2_percentiles": dict(zip(map(str, pct), np.percentile(dens, pct).round(1).tolist())),
        "negative_quadratic_fraction_warp_weft": (q < 0).mean(axis=0).round(4).tolist(),
        "curves": int(clamp.size), "curves_clamped": int((clamp > 0).sum()),
        "largest_clamp_percent_of_top": round(float(clamp.max()) * 100, 2),
        "fit_max_error_percent_of_top_percentiles": dict(zip(map(str, pct), (np.percentile(err, pct) * 100)
                                                             .round(2).tolist())),
        "stretch_and_shear_from": dict(bases.most_common()),
    }


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", required=True, help="Feng et al. 2022 dataset/dataset.csv")
    ap.add_argument("--out", default="outputs/feng2022.json")
    args = ap.parse_args(argv)
    doc = {"stamp": stamp(command_line("python scripts/feng_fabrics.py", argv)), **summary(args.src)}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=2) + "\n")
    print(json.dumps({k: v for k, v in doc.items() if k != "stamp"}, indent=2))
    return doc


if __name__ == "__main__":
    main()
