"""Fabric materials from KES measurements (docs/physics.md, materials).

A :class:`Material` is immutable data in KES units (as measured) plus the
simulation constants of the paper. Curves are polynomials:

* stretch  ``F̂(ε) = c1·ε + c2·ε²``          ε in percent, F̂ in gf/cm
* bending  ``M̂(K) = c0·K^½ + c1·K + c2·K²``  K in 1/cm, M̂ in gf·cm/cm
* shear    ``F(φ) = c0·φ^½ + c1·φ + c2·φ²``  φ in degrees, F in gf/cm

one per direction (warp, weft). Materials are data: YAML files under
``configs/materials/`` (see ``thick_cotton.yaml``), loaded by
:func:`load_material`. A direction may give either the polynomial
coefficients or raw KES samples, which are fitted by least squares
(:func:`fit_kes_curve`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .errors import MaterialError, MaterialTypeError
from .validation import is_file, read_yaml, real, real_array

__all__ = [
    "KESCurve",
    "Material",
    "fit_kes_curve",
    "fit_r_squared",
    "KESFitWarning",
    "load_material",
    "available_materials",
    "materials_dir",
]

_CURVE_KINDS = {
    # kind: (coefficient names, sample-key for x, sample-key for y)
    "stretch": (("c1", "c2"), "strain_percent", "stress_gf_per_cm"),
    "bending": (("c0", "c1", "c2"), "curvature_per_cm", "moment_gf_cm_per_cm"),
    "shear": (("c0", "c1", "c2"), "angle_deg", "force_gf_per_cm"),
}


def _check_number(fieldname: str, value: Any, lo: float = -math.inf, hi: float = math.inf,
                  lo_open: bool = False) -> float:
    return real(fieldname, value, lo, hi, lo_open=lo_open, error=MaterialError)


#: raw KES samples that fall, somewhere along x, by more than this share of their range draw a
#: KESFitWarning (smaller dips are measurement noise)
NON_MONOTONIC_FALL = 0.02


class KESFitWarning(UserWarning):
    """Raw KES samples that a monotone polynomial fits poorly (the message gives R²)."""


def fit_r_squared(x: Sequence[float], y: Sequence[float], curve: "KESCurve") -> float:
    """Coefficient of determination R² of ``curve`` on samples ``(x, y)`` (1: exact; 1 for
    constant samples that the curve reproduces, else 0 or below)."""
    xs = np.asarray(x, dtype=float).ravel()
    ys = np.asarray(y, dtype=float).ravel()
    ss_res = float(np.sum((ys - curve(xs)) ** 2))
    ss_tot = float(np.sum((ys - ys.mean()) ** 2))
    if ss_tot == 0.0:
        return 1.0 if ss_res == 0.0 else 0.0
    return 1.0 - ss_res / ss_tot


@dataclass(frozen=True)
class KESCurve:
    """Polynomial ``c0·x^½ + c1·x + c2·x²`` fitted to a KES curve (x ≥ 0).

    Units are those of the curve kind (see module docstring). Coefficients
    must be finite and non-negative: a KES curve rises monotonically.
    """

    c0: float = 0.0
    c1: float = 0.0
    c2: float = 0.0

    def __call__(self, x, x0: float = 0.0):
        """Evaluate at ``x`` (≥ 0). ``x0 > 0`` regularises the root term as
        ``x / sqrt(x + x0)`` (docs/physics.md, forces, "Fractional powers")."""
        x = np.asarray(x, dtype=float)
        root = x / np.sqrt(x + x0) if x0 > 0 else np.sqrt(x)
        return self.c0 * root + self.c1 * x + self.c2 * x * x

    def derivative(self, x, x0: float = 0.0):
        """d/dx of :meth:`__call__` (same regularisation)."""
        x = np.asarray(x, dtype=float)
        if x0 > 0:
            droot = (x + 2.0 * x0) / (2.0 * (x + x0) ** 1.5)
        else:
            droot = 0.5 / np.sqrt(x)
        return self.c0 * droot + self.c1 + 2.0 * self.c2 * x

    def scaled(self, factor: float) -> "KESCurve":
        return KESCurve(self.c0 * factor, self.c1 * factor, self.c2 * factor)

    @staticmethod
    def mean(a: "KESCurve", b: "KESCurve") -> "KESCurve":
        return KESCurve(0.5 * (a.c0 + b.c0), 0.5 * (a.c1 + b.c1), 0.5 * (a.c2 + b.c2))

    def as_array(self) -> np.ndarray:
        return np.array([self.c0, self.c1, self.c2])


def fit_kes_curve(x: Sequence[float], y: Sequence[float], terms: Sequence[str] = ("c0", "c1", "c2"),
                  fieldname: str = "curve") -> KESCurve:
    """Least-squares fit of a KES polynomial to raw samples.

    The fit is non-negative least squares (``scipy.optimize.nnls``, on
    columns scaled to unit norm), so every coefficient is ≥ 0 and the curve
    rises monotonically. Samples that fall somewhere along x by more than
    ``NON_MONOTONIC_FALL`` (2 %) of their range are fitted all the same, with a
    :class:`KESFitWarning` that gives the fit's R² (:func:`fit_r_squared`).

    Parameters
    ----------
    x, y
        Samples of the measured curve (x ≥ 0 in the curve's unit, see module
        docstring); at least as many as terms.
    terms
        Which of ``c0`` (x^½), ``c1`` (x), ``c2`` (x²) to fit; the others are 0.
        Stretch curves use ``("c1", "c2")``.
    fieldname
        The name errors and warnings give the curve (e.g. ``stretch.warp``).

    Raises
    ------
    MaterialError
        Samples that are not finite, negative in x, too few, or that cannot be fitted.
    """
    xs = _samples(f"{fieldname} x", x)
    ys = _samples(f"{fieldname} y", y)
    if xs.shape != ys.shape:
        raise MaterialError(fieldname, f"x and y must have the same length, got {xs.size} and {ys.size}")
    if not (np.all(np.isfinite(xs)) and np.all(np.isfinite(ys))):
        raise MaterialError(fieldname, "samples must be finite")
    if np.any(xs < 0):
        raise MaterialError(fieldname, "samples must have x >= 0 (use the magnitude of the deformation)")
    if isinstance(terms, str) or not isinstance(terms, (list, tuple)):
        raise MaterialTypeError(fieldname, f"terms must be a list of c0, c1, c2, got {terms!r}")
    unknown = set(map(str, terms)) - {"c0", "c1", "c2"}
    if unknown or not terms:
        raise MaterialError(fieldname, f"terms must be a non-empty subset of c0, c1, c2, got {list(terms)}")
    if xs.size < len(terms):
        raise MaterialError(fieldname, f"need at least {len(terms)} samples, got {xs.size}")
    basis = {"c0": np.sqrt(xs), "c1": xs, "c2": xs * xs}
    if not all(np.all(np.isfinite(basis[t])) for t in terms) or np.max(np.abs(ys)) > 1e150:
        raise MaterialError(fieldname, "samples too large to fit (x² or y overflows)")
    from scipy.optimize import nnls  # imported here: loading a shipped material needs no scipy

    A = np.stack([basis[t] for t in terms], axis=1)
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0  # a column of zeros (all x = 0) fits a coefficient of 0
    try:
        coef, _residual = nnls(A / scale, ys)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as err:
        raise MaterialError(fieldname, f"the samples cannot be fitted: {err}") from None
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        coef = coef / scale
    coef = np.maximum(coef, 0.0)
    if not np.all(np.isfinite(coef)):
        raise MaterialError(fieldname, "the samples cannot be fitted: the coefficients come out infinite "
                            "(x spans too small a range)")
    values = {t: 0.0 for t in ("c0", "c1", "c2")}
    values.update({t: float(c) for t, c in zip(terms, coef)})
    curve = KESCurve(**values)
    # a measured KES curve rises: samples that fall by more than measurement noise are suspect
    rising = ys[np.argsort(xs, kind="stable")]
    fall = float(np.max(np.maximum.accumulate(rising) - rising))
    if fall > NON_MONOTONIC_FALL * float(np.ptp(ys)):
        warnings.warn(f"{fieldname}: the samples are not monotonically increasing in x (they fall by {fall:.3g}, "
                      f"{100 * fall / np.ptp(ys):.0f} % of their range); the monotone fit has "
                      f"R² = {fit_r_squared(xs, ys, curve):.3f}", KESFitWarning, stacklevel=2)
    return curve


def _samples(fieldname: str, values: Any) -> np.ndarray:
    """Raw KES samples as a flat float array (MaterialError naming ``fieldname`` otherwise)."""
    return real_array(fieldname, values, error=MaterialError).ravel()


@dataclass(frozen=True)
class DirectionalCurves:
    """A KES curve for the warp and one for the weft direction."""

    warp: KESCurve
    weft: KESCurve

    def mean(self) -> KESCurve:
        return KESCurve.mean(self.warp, self.weft)

    def scaled(self, warp: float = 1.0, weft: float = 1.0) -> "DirectionalCurves":
        return DirectionalCurves(self.warp.scaled(warp), self.weft.scaled(weft))


@dataclass(frozen=True)
class Material:
    """A fabric: KES curves (as measured) plus simulation constants.

    Attributes
    ----------
    name
        identifier (file stem for shipped materials).
    areal_density
        W, g/cm². A particle's mass is W times the area of fabric it stands for.
    stretch
        tension curves, ε in percent → gf/cm (c0 must be 0).
    bending
        moment curves, K in 1/cm → gf·cm/cm.
    shear
        shear-force curves, φ in degrees → gf/cm.
    compression_factor
        α (docs/physics.md, forces), compression stiffness relative to
        tension (dimensionless, 0 < α ≤ 1).
    restitution
        e, coefficient of restitution in collisions (0 ≤ e ≤ 1).
    air_drag
        C_air of eq. (4), g/cm³.
    strain_damping
        β, s: the material's internal (viscous) damping, acting on the rates of
        deformation (``ForceOptions.damping_model = "strain-rate"``, the default):
        each stretch edge, bending triple and shear corner of stiffness k is
        damped by ``β·k`` times the rate of its strain, so rigid translation and
        rotation are not slowed (docs/physics.md, damping). A mode of angular
        frequency ω is damped at the ratio ``β·ω/2``: the default 2e-5 s damps
        the lattice's fastest stretch vibrations, a few 10⁴ rad/s, at 0.3–0.6 of
        critical and leaves a swinging cloth (a few rad/s) to the air.
    damping
        λ, 1/s, of the paper's absolute-velocity damping ``−λ·m·v`` per particle
        (``ForceOptions.damping_model = "absolute"``: the v0 envs). 0.5/s damps a
        40 cm cloth's swing over a few seconds, and slows free fall and every
        carried cloth as well.
    friction
        Coulomb coefficient μ against obstacles (dimensionless).
    description, source
        free text.
    """

    name: str
    areal_density: float
    stretch: DirectionalCurves
    bending: DirectionalCurves
    shear: DirectionalCurves
    compression_factor: float = 0.1
    restitution: float = 0.2
    air_drag: float = 0.3e-4
    damping: float = 0.5
    friction: float = 0.3
    strain_damping: float = 2.0e-5
    description: str = ""
    source: str = ""

    def __post_init__(self):
        for text in ("name", "description", "source"):
            if not isinstance(getattr(self, text), str):
                raise MaterialTypeError(text, f"must be a string, got {getattr(self, text)!r}")
        _check_number("areal_density", self.areal_density, 0.0, 10.0, lo_open=True)
        _check_number("compression_factor", self.compression_factor, 0.0, 1.0, lo_open=True)
        _check_number("restitution", self.restitution, 0.0, 1.0)
        _check_number("air_drag", self.air_drag, 0.0, 1.0)
        _check_number("damping", self.damping, 0.0, 1.0e4)
        _check_number("strain_damping", self.strain_damping, 0.0, 1.0)
        _check_number("friction", self.friction, 0.0, 10.0)
        for kind in ("stretch", "bending", "shear"):
            curves = getattr(self, kind)
            if not isinstance(curves, DirectionalCurves):
                raise MaterialTypeError(kind, f"expected warp and weft curves (DirectionalCurves), got {curves!r}")
            for d in ("warp", "weft"):
                c = getattr(curves, d)
                if not isinstance(c, KESCurve):
                    raise MaterialTypeError(f"{kind}.{d}", f"expected a KESCurve, got {c!r}")
                for cname in ("c0", "c1", "c2"):
                    _check_number(f"{kind}.{d}.{cname}", getattr(c, cname), 0.0, 1.0e6)
            if kind == "stretch":
                for d in ("warp", "weft"):
                    c = getattr(curves, d)
                    if c.c0 != 0.0:
                        raise MaterialError(f"stretch.{d}.c0", "stretch curves have no root term (must be 0)")
                    if c.c1 <= 0.0:
                        raise MaterialError(f"stretch.{d}.c1", f"{c.c1} is outside the allowed range (0, 1e6]: "
                                            "a cloth needs a positive linear tensile stiffness")

    # ------------------------------------------------------------------ I/O
    @classmethod
    def from_dict(cls, data: Mapping[str, Any], name: str | None = None) -> "Material":
        """Build from the YAML schema (see ``configs/materials/thick_cotton.yaml``).

        An optional ``provenance`` mapping records where the curves come from (source file,
        terms of use, conversion, the converted samples and their fits: see the measured fabrics
        of ``cloth-gym import-material``); it is read by people and left out of the Material."""
        if not isinstance(data, Mapping):
            raise MaterialTypeError("<material>", f"expected a mapping, got {type(data).__name__}")
        allowed = {
            "name", "description", "source", "areal_density_g_per_cm2", "stretch", "bending", "shear",
            "compression_factor", "restitution", "air_drag", "damping_per_s", "friction", "strain_damping_s",
            "provenance",
        }
        unknown = sorted((k for k in data if k not in allowed), key=str)
        if unknown:
            raise MaterialError(unknown[0], f"unknown key; allowed keys: {sorted(allowed)}")
        for required in ("areal_density_g_per_cm2", "stretch", "bending", "shear"):
            if required not in data:
                raise MaterialError(required, "missing (required)")
        if "provenance" in data and not isinstance(data["provenance"], Mapping):
            raise MaterialTypeError("provenance", f"must be a mapping (where the curves come from: source, "
                                    f"terms of use, conversion, samples), got {type(data['provenance']).__name__}")
        curves = {kind: _parse_directional(kind, data[kind]) for kind in _CURVE_KINDS}
        kwargs: dict[str, Any] = {}
        for key, attr in (("compression_factor", "compression_factor"), ("restitution", "restitution"),
                          ("air_drag", "air_drag"), ("damping_per_s", "damping"), ("friction", "friction"),
                          ("strain_damping_s", "strain_damping")):
            if key in data:
                kwargs[attr] = _check_number(key, data[key])
        try:
            return cls(**cls._dict_kwargs(data, name, curves, kwargs))
        except MaterialError as err:  # report the YAML key, not the attribute name
            yaml_key = {"areal_density": "areal_density_g_per_cm2", "damping": "damping_per_s",
                        "strain_damping": "strain_damping_s"}
            if err.field in yaml_key:
                raise type(err)(yaml_key[err.field], err.message) from None
            raise

    @staticmethod
    def _dict_kwargs(data, name, curves, kwargs) -> dict:
        return dict(
            name=data.get("name", name or "material"),
            areal_density=data["areal_density_g_per_cm2"],
            description=data.get("description", ""),
            source=data.get("source", ""),
            **curves,
            **kwargs,
        )

    def to_dict(self) -> dict:
        """Inverse of :meth:`from_dict` (coefficients form)."""
        def dc(kind):
            names = _CURVE_KINDS[kind][0]
            c = getattr(self, kind)
            return {d: {n: float(getattr(getattr(c, d), n)) for n in names} for d in ("warp", "weft")}
        return {
            "name": self.name, "description": self.description, "source": self.source,
            "areal_density_g_per_cm2": self.areal_density,
            "stretch": dc("stretch"), "bending": dc("bending"), "shear": dc("shear"),
            "compression_factor": self.compression_factor, "restitution": self.restitution,
            "air_drag": self.air_drag, "damping_per_s": self.damping, "friction": self.friction,
            "strain_damping_s": self.strain_damping,
        }

    def replace(self, **changes) -> "Material":
        """A copy with fields changed (validated again)."""
        fields = [f.name for f in dataclasses.fields(self)]
        unknown = sorted((k for k in changes if k not in fields), key=str)
        if unknown:
            raise MaterialTypeError(unknown[0], f"unknown field of Material; fields: {fields}")
        return dataclasses.replace(self, **changes)


def _parse_directional(kind: str, data: Any) -> DirectionalCurves:
    names, xkey, ykey = _CURVE_KINDS[kind]
    if not isinstance(data, Mapping):
        raise MaterialTypeError(kind, f"expected a mapping with 'warp' and 'weft', got {data!r}")
    unknown = sorted((k for k in data if k not in ("warp", "weft")), key=str)
    if unknown:
        raise MaterialError(f"{kind}.{unknown[0]}", "unknown key; allowed keys: ['warp', 'weft']")
    out = {}
    for d in ("warp", "weft"):
        if d not in data:
            raise MaterialError(f"{kind}.{d}", "missing (both warp and weft curves are required)")
        spec = data[d]
        path = f"{kind}.{d}"
        if not isinstance(spec, Mapping):
            raise MaterialTypeError(path, f"expected a mapping of coefficients or samples, got {spec!r}")
        if xkey in spec or ykey in spec:
            allowed = {xkey, ykey, "terms"}
            unknown = sorted((k for k in spec if k not in allowed), key=str)
            if unknown:
                raise MaterialError(f"{path}.{unknown[0]}", f"unknown key; allowed keys: {sorted(allowed)}")
            if xkey not in spec or ykey not in spec:
                raise MaterialError(path, f"raw samples need both '{xkey}' and '{ykey}'")
            terms = spec.get("terms", names)
            out[d] = fit_kes_curve(spec[xkey], spec[ykey], terms=terms, fieldname=path)
        else:
            unknown = sorted((k for k in spec if k not in names), key=str)
            if unknown:
                raise MaterialError(f"{path}.{unknown[0]}", f"unknown key; allowed keys: {list(names)} "
                                    f"or raw samples {xkey}/{ykey}")
            if not spec:
                raise MaterialError(path, f"no coefficients given (expected {list(names)})")
            missing = [n for n in names if n not in spec]
            if missing:  # a coefficient left out is an error, not a silent 0
                raise MaterialError(f"{path}.{missing[0]}", f"missing coefficient: give all of {list(names)} "
                                    f"(0 where the term is absent)")
            coeffs = {n: _check_number(f"{path}.{n}", spec[n], 0.0, 1.0e6) for n in names}
            out[d] = KESCurve(**coeffs)
    return DirectionalCurves(**out)


def materials_dir() -> Path:
    """Directory of the shipped material YAML files.

    ``$CLOTH_GYM_MATERIALS`` overrides it; otherwise the package data ``cloth_gym.configs``
    (``configs/materials`` of the repository, installed with the package).
    """
    env = os.environ.get("CLOTH_GYM_MATERIALS")
    if env:
        return Path(env)
    return configs_dir() / "materials"


def configs_dir() -> Path:
    """Directory of the shipped configs: ``materials/`` (fabric YAML files), ``train/`` (the
    rl-baselines3-zoo hyperparameter files of the baselines) and ``sweep/`` (search spaces of
    the hyperparameter sweeps)."""
    from importlib.resources import files

    return Path(str(files("cloth_gym.configs")))


def available_materials() -> list[str]:
    """Names of the shipped materials."""
    d = materials_dir()
    return sorted(p.stem for p in d.glob("*.yaml")) if d.is_dir() else []


def load_material(spec: "str | os.PathLike | Mapping | Material") -> Material:
    """Load a material by name (``"thick_cotton"``), YAML path, mapping, or pass one through.

    A name without a suffix is looked up among the shipped materials. Errors are
    :class:`~cloth_gym.errors.MaterialError`; one from a file names the file, and a YAML syntax
    error its line."""
    if isinstance(spec, Material):
        return spec
    if isinstance(spec, Mapping):
        return Material.from_dict(spec)
    if not isinstance(spec, (str, os.PathLike)):
        raise MaterialTypeError("material", f"expected a material name, a YAML path, a mapping or a Material, "
                                f"got {spec!r} ({type(spec).__name__})")
    path = Path(spec)
    if not path.suffix:
        path = materials_dir() / f"{spec}.yaml"
    if not is_file(path):
        raise MaterialError("material", f"unknown material {str(spec)[:200]!r}; shipped materials: "
                            f"{available_materials()}, or give a path to a YAML file")
    data = read_yaml(path, "material", error=MaterialError)
    with naming_file(path):
        return Material.from_dict(data, name=path.stem)


@contextlib.contextmanager
def naming_file(path: "str | os.PathLike"):
    """Within the block, a :class:`~cloth_gym.errors.MaterialError` is re-raised naming ``path``
    (in its message and as ``err.file``): the error of a material read from that file."""
    try:
        yield
    except MaterialError as err:
        named = type(err)(err.field, f"{err.message} (in {path})")
        named.file = str(path)
        raise named from None
