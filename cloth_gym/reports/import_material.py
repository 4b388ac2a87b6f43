"""Import measured fabrics from ARCSim material files (Wang, Ramamoorthi & O'Brien 2011).

    cloth-gym import-material 11oz-black-denim.json [--warp stiffer|u|v] [--name denim] [--out DIR]

For each file: the fabric's warp and weft tension, bending and shear curves converted to KES
units by :func:`cloth_gym.arcsim.convert` (docs/materials.md, "Measured fabrics"), fitted by the
project's polynomials as :func:`cloth_gym.load_material` would fit raw samples. Writes into
``--out``:

* ``<name>.yaml``: the material (fitted coefficients, the paper's default simulation constants)
  with a ``provenance`` block: the source file and its SHA-256, the terms of use given, the
  conversion, the warp axis, the Poisson ratios the conversion drops, the converted samples and
  each fit's R² and largest error;
* ``<name>_fit.png``: the converted samples against the fitted polynomials.

It prints one line per curve with the fit's coefficients, R² and largest error.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import warnings
from pathlib import Path

import numpy as np
import yaml

from ..arcsim import ArcsimMaterial, convert, read_arcsim
from ..errors import ConfigError, MaterialError
from ..materials import _CURVE_KINDS, KESFitWarning, Material
from . import options
from .kes_fit import CurveFit, _fit, plot_fits

__all__ = ["CONVERSION", "import_arcsim", "run_args", "main"]

CONVERSION = (
    "cloth_gym.arcsim.convert (docs/materials.md, 'Measured fabrics'): tension = ARCSim's uniaxial tension "
    "per unit reference width along the axis, lateral stress free (its biaxial Poisson coupling k1 is "
    "dropped: poisson_ratio_dropped); shear = the force per unit length of a simple shear by tan(angle) "
    "sliding along the axis; bending = the moment per unit width of ARCSim's hinges on an equilateral mesh "
    "wrapped on a cylinder, averaged over the mesh's orientation; SI to KES units with 1 gf = 980.665 dyn. "
    "The simulator uses the fitted polynomials; each fit's R² and largest error are in 'fit'."
)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def import_arcsim(path: "str | Path", warp: str = "stiffer", name: str | None = None, description: str = "",
                  source: str = "", terms_of_use: str = "") -> tuple[dict, Material, list[CurveFit], ArcsimMaterial]:
    """Convert the ARCSim material file ``path`` and fit its curves.

    Returns the material's YAML mapping (coefficients and a ``provenance`` block), the
    :class:`~cloth_gym.materials.Material` it loads as, one :class:`CurveFit` per curve and
    direction, and the :class:`~cloth_gym.arcsim.ArcsimMaterial` read. Bad files raise
    :class:`~cloth_gym.MaterialError` naming the file and key."""
    path = Path(path)
    arc = read_arcsim(path)
    samples = convert(arc, warp=warp, name=name)
    warp_axis = arc.stiffer_axis() if warp == "stiffer" else warp
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", KESFitWarning)  # the fits' quality is reported below instead
        material, fits = _fit(path, samples, name or arc.name)
    material = material.replace(description=description, source=source)
    fit_report = {}
    for f in fits:
        worst = float(np.max(np.abs(f.curve(f.x) - f.y)))
        fit_report[f"{f.kind}.{f.direction}"] = {
            "r_squared": round(float(f.r_squared), 5),
            "max_error_percent_of_max": round(100.0 * worst / float(np.max(np.abs(f.y))), 2),
        }
    nu_u, nu_v = arc.poisson_ratio()
    data = material.to_dict()
    data["provenance"] = {
        "source_file": path.name,
        "source_sha256": _sha256(path),
        "terms_of_use": terms_of_use or "as the source file's",
        "conversion": CONVERSION,
        "warp_axis": f"{warp_axis} (ARCSim's {'first' if warp_axis == 'u' else 'second'} material axis; "
                     + ("the stiffer at zero strain)" if warp == "stiffer" else "as asked)"),
        "poisson_ratio_dropped": {"pull_along_u": round(float(nu_u), 4), "pull_along_v": round(float(nu_v), 4)},
        "fit": fit_report,
        "samples": {kind: samples[kind] for kind in _CURVE_KINDS},
    }
    return data, material, fits, arc


class _FlowLists(yaml.SafeDumper):
    """YAML dumper that writes lists of numbers on one line."""


def _flow_numbers(dumper, value):
    flow = all(isinstance(v, (int, float, str)) for v in value)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", value, flow_style=flow)


_FlowLists.add_representer(list, _flow_numbers)


def write_material(data: dict, path: Path, header: str) -> None:
    """Write a converted material's YAML (lists of numbers inline) under a comment ``header``."""
    body = yaml.dump(data, Dumper=_FlowLists, sort_keys=False, allow_unicode=True, width=110)
    path.write_text("".join(f"# {line}\n" if line else "#\n" for line in header.splitlines()) + body)


add_arguments = options.import_material


def run_args(args: argparse.Namespace, command: str) -> list[dict]:
    """Import every file of ``args.files``; write each material's YAML and plot into ``args.out``."""
    if args.name and len(args.files) > 1:
        raise ConfigError("name", f"names one material; {len(args.files)} files were given (use --prefix)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for file in args.files:
        stem = args.name or (args.prefix + Path(file).stem.replace("-", "_"))
        if not stem or any(c in stem for c in "/\\") or stem in (".", ".."):
            raise ConfigError("name", f"must be a plain file name (no path separators), got {stem!r}")
        data, material, fits, _arc = import_arcsim(file, warp=args.warp, name=stem, terms_of_use=args.terms)
        yaml_path = out / f"{stem}.yaml"
        write_material(data, yaml_path, f"{stem}: converted from the ARCSim material file {Path(file).name} by\n"
                       f"`{command}`")
        plot_fits(fits, f"{stem}: converted ARCSim curves", out / f"{stem}_fit.png")
        print(f"{stem}: warp = {data['provenance']['warp_axis']}, {material.areal_density:.4g} g/cm²")
        for f in fits:
            report = data["provenance"]["fit"][f"{f.kind}.{f.direction}"]
            print(f"  {f.kind + '.' + f.direction:<14} c0 {f.curve.c0:9.4g} c1 {f.curve.c1:9.4g} c2 {f.curve.c2:9.4g}  "
                  f"R² {report['r_squared']:.4f}  largest error {report['max_error_percent_of_max']:.1f} % of the max")
        print(f"  -> {yaml_path}")
        results.append(data)
    return results


def main(argv=None, prog: str = "cloth-gym import-material") -> list[dict]:
    return options.run("import-material", run_args, argv, prog)


if __name__ == "__main__":  # pragma: no cover
    try:
        main()
    except (MaterialError, ConfigError) as err:
        raise SystemExit(f"error: {err}") from None
