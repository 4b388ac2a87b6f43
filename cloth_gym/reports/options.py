"""The command-line options of each report, importable without the simulator.

``cloth-gym --help`` and the light subcommands (``envs``, ``configs``) build their parser from
these, so they load neither numba nor matplotlib; a report's own module is imported only when
it runs.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from typing import Callable, Sequence

__all__ = ["FIGURES", "PAPER_MATERIALS", "REPORTS", "command_line", "drape", "figures", "fit_kes", "import_material",
           "parser", "run"]

FIGURES = (3, 8, 10, 11, 13)
"""The paper's figures ``cloth-gym figures`` redoes."""

PAPER_MATERIALS = ("thick_cotton", "thin_wool")
"""The paper's two fabrics: the figures' materials unless ``--material`` names others."""


def drape(ap: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The drape test's options (``cloth-gym drape``, ``scripts/drape_test.py``)."""
    ap.add_argument("--material", required=True, help="shipped material name or YAML path")
    ap.add_argument("--model", default="kes", choices=["kes", "breen"])
    ap.add_argument("--sigma", type=float, default=1.0, help="lattice spacing, cm (paper: 0.5)")
    ap.add_argument("--geometry", default="paper", choices=["paper", "cusick"])
    ap.add_argument("--max-time", type=float, default=6.0, help="give up after this simulated time, s")
    ap.add_argument("--seed", type=int, nargs="+", default=[0],
                    help="seed(s) of the start-height perturbation; several: one run each, with the node counts' "
                         "distribution and the drape coefficient's mean and spread")
    ap.add_argument("--out", default="outputs/drape_test", help="writes <out>/<file stem>_<model>[_cusick]/")
    ap.add_argument("--quiet", action="store_true")
    return ap


def figures(ap: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The paper figures' options (``cloth-gym figures``, ``scripts/paper_figures.py``)."""
    ap.add_argument("--fig", type=int, nargs="+", default=list(FIGURES), choices=FIGURES)
    ap.add_argument("--material", nargs="+", default=list(PAPER_MATERIALS), metavar="NAME_OR_YAML",
                    help="fabrics to draw (shipped names or YAML paths, with distinct names; default: the "
                         "paper's cotton and wool)")
    ap.add_argument("--fast", action="store_true", help="coarse lattice, short runs (CI / smoke test)")
    ap.add_argument("--out", default="outputs/paper")
    return ap


def fit_kes(ap: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The KES fit's options (``cloth-gym fit-kes``)."""
    ap.add_argument("yaml", help="material YAML whose curves may be raw KES samples")
    ap.add_argument("--name", default=None,
                    help="name of the fitted material and its files (default: the file's stem)")
    ap.add_argument("--out", default="outputs/kes_fit", help="directory for <name>.yaml, <name>_fit.png/.json")
    return ap


def import_material(ap: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The ARCSim importer's options (``cloth-gym import-material``)."""
    ap.add_argument("files", nargs="+", help="ARCSim material files (JSON: density, stretching, bending)")
    ap.add_argument("--warp", default="stiffer", choices=["stiffer", "u", "v"],
                    help="the material axis called warp (default: the stiffer at zero strain; ARCSim names none)")
    ap.add_argument("--name", default=None, help="name of the material and its files (one file only)")
    ap.add_argument("--prefix", default="", help="prefix of each material's name (default: the file's stem)")
    ap.add_argument("--terms", default="", help="the source's terms of use, recorded in each material's provenance")
    ap.add_argument("--out", default="outputs/materials", help="directory for <name>.yaml and <name>_fit.png")
    return ap


DRAPE_TEXT = """\
The drape test (the paper's fig. 8): a 25.4 cm disc of cloth released just above a 12.7 cm
pedestal, run until its kinetic energy stays low. Writes <out>/<file stem>_<model>/metrics.json
(drape coefficient, node count, strains, settle time) and drape.png (top view with the outline
the nodes are counted on, and a perspective view). sigma = 1 cm takes about 10 s after
compilation, the paper's 0.5 cm one to three minutes."""

FIGURES_TEXT = """\
The paper's figures, each as PNGs and a JSON of its numbers in --out: 3 (restoring force and
torque curves, Breen against the KES model), 8 (drape test), 10 (tablecloth coloured by strain),
11 (force fields on the tablecloth), 13 (falling ribbon, with and without angular momentum in
the collision response). --material replaces the paper's two fabrics by yours: figs. 3, 8 and
10 draw every material given, figs. 11 and 13 the last. --fast runs each on a coarse lattice."""

FIT_KES_TEXT = """\
Fit a fabric's raw KES curves. The input is a material YAML (the schema of the shipped
materials: `cloth-gym configs` shows where they are) in which any curve may be raw samples:
stretch strain_percent / stress_gf_per_cm, bending curvature_per_cm / moment_gf_cm_per_cm,
shear angle_deg / force_gf_per_cm, each optionally with terms: [c0, c1, c2]. Curves are fitted
by non-negative least squares, as loading the YAML would. Writes <name>.yaml (the fitted
material), <name>_fit.png (samples against the fits) and <name>_fit.json, and prints each
curve's coefficients and R²."""

IMPORT_MATERIAL_TEXT = """\
Convert measured fabrics from ARCSim material files (the format of Wang, Ramamoorthi & O'Brien
2011's database: density kg/m², stretching 6×4 N/m, bending 3×5 N·m) into the project's
materials: warp and weft tension against strain, bending moment against curvature and shear
force against angle, in KES units, fitted by the project's polynomials. Writes <name>.yaml (the
material, with the source file, its hash, the terms of use, the conversion, the converted samples
and each fit's R² and largest error under provenance) and <name>_fit.png, and prints each fit.
docs/materials.md ("Measured fabrics") gives the equations and assumptions."""

REPORTS = {  # subcommand: (module of cloth_gym.reports, its options, one-line help, description)
    "drape": ("drape", drape, "the drape test (drape coefficient, node count, pictures)", DRAPE_TEXT),
    "figures": ("figures", figures, "the paper's figures, for its fabrics or yours (--material)", FIGURES_TEXT),
    "fit-kes": ("kes_fit", fit_kes, "fit raw KES curves: fitted material, plot of the fits, R² per curve",
                FIT_KES_TEXT),
    "import-material": ("import_material", import_material,
                        "convert ARCSim (Wang 2011) material files into materials", IMPORT_MATERIAL_TEXT),
}


def command_line(prog: str, argv: Sequence[str]) -> str:
    """The shell command that reruns ``prog`` with ``argv``, quoted so it can be pasted."""
    return shlex.join([*prog.split(), *map(str, argv)])


def parser(name: str, prog: str | None = None) -> argparse.ArgumentParser:
    """The argument parser of report ``name`` (a key of :data:`REPORTS`), as ``prog``."""
    _module, add_options, _help, text = REPORTS[name]
    ap = argparse.ArgumentParser(prog=prog or f"cloth-gym {name}", description=text,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    return add_options(ap)


def run(name: str, run_args: Callable, argv: Sequence[str] | None = None, prog: str | None = None):
    """Parse ``argv`` (default ``sys.argv[1:]``) with report ``name``'s options and call
    ``run_args(args, command)`` with the command that reruns it; returns what ``run_args`` does."""
    prog = prog or f"cloth-gym {name}"
    argv = sys.argv[1:] if argv is None else list(argv)
    return run_args(parser(name, prog).parse_args(argv), command_line(prog, argv))
