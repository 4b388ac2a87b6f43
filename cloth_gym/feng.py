"""Fabrics from the bending records of Feng et al. 2022, for episodes drawn over real fabrics.

Feng, Huang, Wang, Chen & Jiang 2022, "Learning-based bending stiffness parameter estimation
by a drape tester" (ACM TOG 41(6), SIGGRAPH Asia), publish ``dataset/dataset.csv`` in the
repository ``DrapeTester/ClothDrapeTester``: for each of 618 rows (251 distinct), a real fabric's
areal density and its bending stiffness along the warp, the weft and the diagonal, measured on
their drape tester. The repository states no licence for the dataset (its code is CC-BY-NC-ND),
so cloth_gym does not ship it: download it and read your copy::

    from cloth_gym.feng import feng2022_materials
    fabrics = feng2022_materials("ClothDrapeTester/dataset/dataset.csv")   # 251 Materials
    env = gym.make("cloth_gym/RibbonDrop-v4", material={"choose": fabrics})

**The records.** Their simulator's bending moment per unit width along a direction is
``M(κ) = k1·κ + k2·κ²`` (``principal_curvature_based_bending_force`` in their ARCSim: force
``−(k1·κ + k2·κ²)·l·∂θ``), ``k1`` in N·m (the CSV's "linear" column × 1e-9) and ``k2`` in N·m²
(the "nonlinear" column × 1e-12), κ in 1/m; density in kg/m².

**The conversion** (:func:`record_material`):

* bending, warp and weft: ``M`` sampled at the curvatures of the ARCSim conversion
  (0–0.4 1/cm, :data:`cloth_gym.arcsim.CURVATURE_PER_CM`), in KES units (gf·cm/cm, 1 gf =
  980.665 dyn). Nearly every ``k2`` is negative (the moment softens), and where ``M`` would
  fall the samples are clamped to their running maximum (a KES curve never falls); then fitted
  with ``c0·√κ + c1·κ + c2·κ²`` (non-negative coefficients, :func:`~cloth_gym.materials.fit_kes_curve`).
  The diagonal (bias) record is not used: the simulator's bending is warp and weft only.
* areal density: the record's.
* stretch, shear and the simulation constants (damping, friction, drag): those of the shipped
  material nearest in areal density (on a log scale), which the material's ``description`` names:
  the records measure bending only.
"""

from __future__ import annotations

import csv
import math
import os
import warnings
from dataclasses import dataclass

import numpy as np

from .arcsim import CURVATURE_PER_CM, GF
from .errors import MaterialError
from .materials import (DirectionalCurves, KESFitWarning, Material, available_materials, fit_kes_curve,
                        load_material)

__all__ = ["COLUMNS", "BendingRecord", "read_feng2022", "record_material", "feng2022_materials"]

#: the CSV's header, in order
COLUMNS = ("density[kg.m-2]", "linear warp[SI*1e9]", "linear weft[SI*1e9]", "linear diag[SI*1e9]",
           "nonlinear warp[SI*1e12]", "nonlinear weft[SI*1e12]", "nonlinear diag[SI*1e12]")

#: the directions of a record's bending, in the CSV's order
DIRECTIONS = ("warp", "weft", "diag")


@dataclass(frozen=True)
class BendingRecord:
    """One distinct row of the dataset, in SI units."""

    row: int                          #: the CSV's data row it was first seen on (1: the first after the header)
    density_kg_per_m2: float
    linear_n_m: tuple[float, float, float]      #: k1 along warp, weft, diagonal (N·m)
    quadratic_n_m2: tuple[float, float, float]  #: k2 along warp, weft, diagonal (N·m²)

    def moment_gf_cm_per_cm(self, direction: str, curvature_per_cm) -> np.ndarray:
        """The record's bending moment per unit width (gf·cm/cm) at curvatures in 1/cm, as
        recorded (not clamped)."""
        i = DIRECTIONS.index(direction)
        k = np.asarray(curvature_per_cm, dtype=float) * 100.0  # 1/m
        m_newton = self.linear_n_m[i] * k + self.quadratic_n_m2[i] * k * k  # N·m per m of width
        return m_newton * 1.0e5 / GF  # N -> dyn -> gf


def read_feng2022(path: "str | os.PathLike") -> list[BendingRecord]:
    """The dataset's distinct rows (exact repeats dropped, first occurrence kept, in file order).

    Raises :class:`~cloth_gym.errors.MaterialError` naming the file, and the row and column of a
    value that is not a number, not finite, or (density, linear stiffness) not positive."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except OSError as err:
        raise MaterialError("dataset", f"cannot read {os.fspath(path)!r}: {err.strerror or err}") from None
    header = tuple(c.strip() for c in rows[0]) if rows else ()
    if header != COLUMNS:
        raise MaterialError("dataset", f"{os.fspath(path)!r} has columns {list(header)}, expected {list(COLUMNS)} "
                            f"(Feng et al. 2022, dataset/dataset.csv)")
    seen: dict[tuple, BendingRecord] = {}
    for n, raw in enumerate(rows[1:], start=1):
        if not any(c.strip() for c in raw):
            continue
        if len(raw) != len(COLUMNS):
            raise MaterialError(f"dataset.row[{n}]", f"has {len(raw)} values, expected {len(COLUMNS)}")
        values = []
        for col, text in zip(COLUMNS, raw):
            try:
                v = float(text)
            except ValueError:
                raise MaterialError(f"dataset.row[{n}].{col}", f"is {text.strip()!r}, not a number") from None
            if not math.isfinite(v):
                raise MaterialError(f"dataset.row[{n}].{col}", f"must be finite, got {v}")
            if not col.startswith("nonlinear") and v <= 0:
                raise MaterialError(f"dataset.row[{n}].{col}", f"must be > 0, got {v}")
            values.append(v)
        key = tuple(values)
        if key not in seen:
            seen[key] = BendingRecord(n, values[0], tuple(v * 1e-9 for v in values[1:4]),
                                      tuple(v * 1e-12 for v in values[4:7]))
    if not seen:
        raise MaterialError("dataset", f"{os.fspath(path)!r} has no records")
    return list(seen.values())


def clamped_moment(record: BendingRecord, direction: str, curvature_per_cm=CURVATURE_PER_CM) -> np.ndarray:
    """The record's moment (gf·cm/cm) at ``curvature_per_cm`` (increasing), clamped to its running
    maximum and to ≥ 0: the curve the material is fitted to."""
    m = record.moment_gf_cm_per_cm(direction, curvature_per_cm)
    return np.maximum.accumulate(np.maximum(m, 0.0))


def nearest_by_density(density_g_per_cm2: float, library: list[Material]) -> Material:
    """The material of ``library`` nearest in areal density on a log scale (the first on a tie)."""
    return min(library, key=lambda m: abs(math.log(m.areal_density / density_g_per_cm2)))


def record_material(record: BendingRecord, library: list[Material] | None = None) -> Material:
    """The :class:`~cloth_gym.materials.Material` of a record (see the module docstring): its
    density and bending, the rest from the ``library`` material nearest in density (default: every
    shipped material). Named ``feng2022_row<row>``."""
    library = library if library is not None else [load_material(n) for n in available_materials()]
    density = record.density_kg_per_m2 * 0.1  # g/cm²
    base = nearest_by_density(density, library)
    curves = {}
    for d in ("warp", "weft"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", KESFitWarning)  # clamped samples never fall; a flat tail may warn
            curves[d] = fit_kes_curve(CURVATURE_PER_CM, clamped_moment(record, d), fieldname=f"bending.{d}")
    return base.replace(
        name=f"feng2022_row{record.row}",
        description=(f"Feng et al. 2022 drape-tester record (row {record.row}): density and warp/weft bending "
                     f"measured; stretch, shear and constants of {base.name} (nearest in density)"),
        source="Feng, Huang, Wang, Chen & Jiang 2022, ACM TOG 41(6); DrapeTester/ClothDrapeTester dataset/dataset.csv",
        areal_density=density,
        bending=DirectionalCurves(warp=curves["warp"], weft=curves["weft"]),
    )


def feng2022_materials(path: "str | os.PathLike", library: list[Material] | None = None) -> list[Material]:
    """Every distinct record of the dataset at ``path`` as a Material (:func:`record_material`)."""
    library = library if library is not None else [load_material(n) for n in available_materials()]
    return [record_material(r, library) for r in read_feng2022(path)]
