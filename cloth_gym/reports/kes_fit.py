"""Fit a fabric's raw KES curves: the fitted material, a plot of samples against the fits, R².

    cloth-gym fit-kes my_fabric.yaml [--out outputs/kes_fit] [--name my_fabric]

The input is a material YAML (the schema of ``configs/materials/thick_cotton.yaml``)
in which any curve may be given as raw KES samples instead of coefficients:

* stretch: ``strain_percent`` (ε, %) and ``stress_gf_per_cm`` (gf/cm), fitted by ``c1·ε + c2·ε²``;
* bending: ``curvature_per_cm`` (K, 1/cm) and ``moment_gf_cm_per_cm`` (gf·cm/cm),
  fitted by ``c0·K^½ + c1·K + c2·K²``;
* shear: ``angle_deg`` (φ, degrees) and ``force_gf_per_cm`` (gf/cm), the same polynomial in φ;

each optionally with ``terms`` (which of c0, c1, c2 to fit). Every curve is fitted
by non-negative least squares (:func:`cloth_gym.fit_kes_curve`). Writes into ``--out``:

* ``<name>.yaml`` (``--name``, else the input file's stem): the fitted material (coefficients only), loadable by
  :func:`cloth_gym.load_material` and by every scene and env (``material="<path>"``);
* ``<name>_fit.png``: per curve and direction, the samples against the fitted polynomial;
* ``<name>_fit.json``: coefficients, R² and sample count per curve.

It prints one line per curve with its coefficients and R² (the fraction of the
samples' variance the fit explains; 1 is a perfect fit).
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np
import yaml

from ..errors import ConfigError, MaterialError
from ..materials import _CURVE_KINDS, KESCurve, KESFitWarning, Material, fit_r_squared, naming_file
from ..validation import read_yaml
from . import figure, options

__all__ = ["CurveFit", "fit_material_file", "plot_fits", "add_arguments", "run_args", "main"]

UNITS = {  # kind: (x label, y label) of the KES curves, as measured
    "stretch": ("strain ε, %", "tension, gf/cm"),
    "bending": ("curvature K, 1/cm", "moment, gf·cm/cm"),
    "shear": ("shear angle φ, degrees", "shear force, gf/cm"),
}


class CurveFit:
    """One fitted curve: ``kind`` (stretch, bending, shear), ``direction`` (warp, weft), the
    fitted :class:`~cloth_gym.KESCurve`, and the samples ``x``, ``y`` with the fit's ``r_squared``
    (``None``, with empty samples, where the file gave coefficients)."""

    def __init__(self, kind: str, direction: str, curve: KESCurve, x=(), y=(), r_squared: float | None = None,
                 warning: str | None = None):
        self.kind, self.direction, self.curve = kind, direction, curve
        self.x, self.y = np.asarray(x, float), np.asarray(y, float)
        self.r_squared, self.warning = r_squared, warning

    def as_dict(self) -> dict:
        return {"kind": self.kind, "direction": self.direction, "c0": self.curve.c0, "c1": self.curve.c1,
                "c2": self.curve.c2, "samples": int(self.x.size), "r_squared": self.r_squared,
                "warning": self.warning}


def fit_material_file(path: str | Path, name: str | None = None) -> tuple[Material, list[CurveFit]]:
    """Fit every raw-sample curve of the material YAML ``path``.

    Returns the material as :func:`~cloth_gym.load_material` reads the file (validated,
    coefficients form; named ``name`` if given, else by the file's ``name:``, else its stem) and one :class:`CurveFit` per curve and
    direction. Bad files raise :class:`~cloth_gym.MaterialError` naming the file and field.
    """
    path = Path(path)
    data = read_yaml(path, "material", error=MaterialError)  # a read or syntax error names the file itself
    with naming_file(path):
        return _fit(path, data, name)


def _fit(path: Path, data, name: str | None) -> tuple[Material, list[CurveFit]]:
    # the material exactly as load_material reads the file (validated, raw curves fitted), then
    # each curve's samples against its fit
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", KESFitWarning)
        material = Material.from_dict(data, name=path.stem)
    notes = {str(w.message).split(":")[0]: str(w.message) for w in caught if w.category is KESFitWarning}
    fits = []
    for kind, (_names, xkey, ykey) in _CURVE_KINDS.items():
        for direction in ("warp", "weft"):
            spec = data[kind][direction]
            curve = getattr(getattr(material, kind), direction)
            if xkey in spec:
                x = np.asarray(spec[xkey], float).ravel()
                y = np.asarray(spec[ykey], float).ravel()
                fits.append(CurveFit(kind, direction, curve, x, y, fit_r_squared(x, y, curve),
                                     notes.get(f"{kind}.{direction}")))
            else:
                fits.append(CurveFit(kind, direction, curve))
    if name:
        material = material.replace(name=name)
    return material, fits


def plot_fits(fits: list[CurveFit], title: str, path: Path):
    """Samples (dots) against the fitted polynomials (lines), one panel per curve kind, warp and weft."""
    fig = figure((12.0, 3.8))
    axes = fig.subplots(1, 3)
    colours = {"warp": "tab:blue", "weft": "tab:orange"}
    for ax, kind in zip(axes, _CURVE_KINDS):
        top = max([f.x.max() for f in fits if f.kind == kind and f.x.size] or [{"stretch": 3.0, "bending": 2.5,
                                                                               "shear": 8.0}[kind]])
        xs = np.linspace(0.0, top, 200)
        for f in (f for f in fits if f.kind == kind):
            label = f"{f.direction}" + (f", R² = {f.r_squared:.4f}" if f.r_squared is not None else ", given")
            ax.plot(xs, f.curve(xs), "-", color=colours[f.direction], label=label)
            if f.x.size:
                ax.plot(f.x, f.y, "o", ms=3, color=colours[f.direction], alpha=0.7)
        ax.set_xlabel(UNITS[kind][0])
        ax.set_ylabel(UNITS[kind][1])
        ax.set_title(kind, fontsize=10)
        ax.legend(fontsize=8)
    fig.suptitle(title + " (dots: samples; lines: fits)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return fig


add_arguments = options.fit_kes


def run_args(args: argparse.Namespace, command: str) -> dict:
    """Fit ``args.yaml``, write the material, plot and JSON (files named after ``args.name``, else
    the YAML file's stem); return the JSON data."""
    stem = args.name or Path(args.yaml).stem
    if not stem or stem in (".", "..") or any(c in stem for c in "/\\"):
        raise ConfigError("name", f"must be a plain file name (no path separators), got {stem!r}")
    material, fits = fit_material_file(args.yaml, args.name)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    header = (f"# {material.name}: fitted by `{command}` (non-negative least squares).\n"
              + "".join(f"# {f.kind}.{f.direction}: R² = {f.r_squared:.4f} over {f.x.size} samples\n"
                        for f in fits if f.r_squared is not None))
    yaml_path = out / f"{stem}.yaml"
    yaml_path.write_text(header + yaml.safe_dump(material.to_dict(), sort_keys=False))
    plot_fits(fits, f"{material.name}: KES fits", out / f"{stem}_fit.png")
    data = {"material": material.name, "source_file": str(args.yaml), "fitted_yaml": str(yaml_path),
            "curves": [f.as_dict() for f in fits]}
    (out / f"{stem}_fit.json").write_text(json.dumps(data, indent=2) + "\n")
    print(f"{'curve':<16} {'c0':>10} {'c1':>10} {'c2':>10} {'R²':>8} samples")
    for f in fits:
        r2 = f"{f.r_squared:8.4f}" if f.r_squared is not None else "   given"
        print(f"{f.kind + '.' + f.direction:<16} {f.curve.c0:10.4g} {f.curve.c1:10.4g} {f.curve.c2:10.4g} {r2} "
              f"{f.x.size}")
        if f.warning:
            print(f"  warning: {f.warning}")
    print(f"-> {yaml_path}, {out / (stem + '_fit.png')}")
    return data


def main(argv=None, prog: str = "cloth-gym fit-kes") -> dict:
    return options.run("fit-kes", run_args, argv, prog)
