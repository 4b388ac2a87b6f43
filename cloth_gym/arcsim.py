"""Measured fabrics from ARCSim material files (Wang, Ramamoorthi & O'Brien 2011), as KES curves.

An ARCSim material file (JSON, SI units) holds a fabric measured by Wang et al. 2011:

* ``density``: areal density, kg/m²;
* ``stretching``: 6 × 4 membrane stiffnesses (C11, C12, C22, C33), N/m. Row 0 is the stiffness
  at zero strain; rows 1–5 the stiffness at a principal stretch of 1 + 1/6 whose direction makes
  0°, 22.5°, 45°, 67.5° and 90° with the first material axis u. ARCSim blends them linearly in
  the principal stretch and the angle, clips each at 0 and doubles the result; the stress is the
  second Piola–Kirchhoff stress of the energy density
  ``W = ½·k0·G00² + k1·G00·G11 + ½·k2·G11² + k3·G01²`` of the Green strain G, with the stiffness
  k held fixed (the force ARCSim applies);
* ``bending``: 3 × 5 hinge stiffnesses, N·m. Rows are the direction of the fold edge in
  material space (along u, at 45°, along v), columns the hinge curvature
  ``α = θ·l / (2·(A1 + A2))`` = 0, 5, 10, 15, 20 1/m (held at the last column beyond). A hinge
  of dihedral angle θ, length l and triangle areas A1, A2 stores ``ke·l²·θ² / (8·(A1 + A2))``.

:func:`read_arcsim` reads and checks a file; :class:`ArcsimMaterial` evaluates ARCSim's model;
:func:`convert` turns it into the project's material (tension against strain in the warp and
weft directions, bending moment against curvature, shear force against angle, as samples in KES
units that loading the material fits: :mod:`cloth_gym.materials`). The conversion, its
assumptions and its accuracy are in docs/materials.md ("Measured fabrics"). In short:

* **tension** is ARCSim's uniaxial tension along the direction with the lateral stress free
  (``P_dd = λ·S_dd`` with ``S_⊥⊥ = 0``), per unit reference width. The project's stretch springs
  have no Poisson coupling: the term ``k1`` that couples warp and weft in a biaxial stretch is
  dropped (:meth:`ArcsimMaterial.poisson_ratio` gives its size);
* **shear** is the force per unit length of a simple shear by ``γ = tan φ``,
  ``dW/dγ = k3·γ/2 + k·γ³/2`` (k the stiffness of the sheared-along direction);
* **bending** is the moment per unit width of a cylinder of curvature κ on ARCSim's kind of
  mesh, equilateral triangles (of side l, its vertices on the cylinder), averaged over the mesh's
  orientation: an edge whose normal makes an angle ψ with the curvature direction bends by
  ``θ = κ·l·(4·cos²ψ − 1)/(2√3)`` (to first order in κ·l), so its hinge curvature is
  ``α = κ·|4·cos²ψ − 1|/6``, and the moment is ``M(κ) = (κ/12)·⟨ke(edge, α)·(4·cos²ψ − 1)²⟩``
  averaged over the edge directions (``M = ke·κ/4`` for a constant ke);
* **warp** is the material axis (u or v) with the larger tensile stiffness at zero strain
  unless told otherwise: ARCSim names no warp or weft, and a woven fabric's warp is usually the
  stiffer direction.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .errors import MaterialError, MaterialTypeError
from .validation import is_file, one_of, real

__all__ = ["ArcsimMaterial", "read_arcsim", "parse_arcsim", "convert", "STRAIN_PERCENT", "SHEAR_DEG",
           "CURVATURE_PER_CM", "GF"]

GF = 980.665
"""One gram-force in dyne."""

N_PER_M = 1.0e3
"""N/m in dyn/cm."""

NM = 1.0e7
"""N·m in dyn·cm (erg)."""

STRAIN_PERCENT = np.linspace(0.0, 15.0, 31)
"""Engineering strains of the converted tension curves, %: up to ARCSim's measured range (its
stiffness reaches the stretched samples at a principal stretch of 1 + 1/6 and is held beyond)."""

SHEAR_DEG = np.linspace(0.0, 8.0, 17)
"""Shear angles of the converted shear curves, degrees (the KES shear test's ±8°)."""

CURVATURE_PER_CM = np.linspace(0.0, 0.4, 21)
"""Curvatures of the converted bending curves, 1/cm: up to 0.4 1/cm, where the hinges across the
curvature reach ARCSim's last curvature sample (α = κ/2 = 0.2 1/cm); beyond it every stiffness is
held, so the moment grows linearly."""

_ALPHA_STEP_PER_CM = 0.05  # ARCSim's bending samples are 5 1/m = 0.05 1/cm apart
_GRID_N = 30  # ARCSim tabulates the stiffness on a 30³ grid of Green strains at load time


def _load_json(text: str, where: str) -> Any:
    # ARCSim's parser (jsoncpp) accepts // comments, which some of its files carry
    stripped = re.sub(r"(?m)^\s*//.*$", "", text)
    try:
        return json.loads(stripped)
    except json.JSONDecodeError as err:
        raise MaterialError("<arcsim>", f"not valid JSON ({err.msg} at line {err.lineno}) in {where}") from None


def _table(data: Mapping, key: str, shape: tuple[int, int], unit: str) -> np.ndarray:
    if key not in data:
        raise MaterialError(key, f"missing (an ARCSim material has density, stretching {shape[0]}×4 "
                            "and bending 3×5)")
    rows = data[key]
    if not isinstance(rows, list) or len(rows) != shape[0]:
        raise MaterialTypeError(key, f"must be a list of {shape[0]} rows of {shape[1]} numbers ({unit}), "
                                f"got {str(rows)[:80]}")
    out = np.empty(shape)
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != shape[1]:
            raise MaterialTypeError(f"{key}[{i}]", f"must be a row of {shape[1]} numbers ({unit}), got {str(row)[:80]}")
        for j, v in enumerate(row):
            out[i, j] = real(f"{key}[{i}][{j}]", v, -1.0e9, 1.0e9, unit=unit, error=MaterialError)
    return out


def parse_arcsim(data: Any, name: str = "arcsim") -> "ArcsimMaterial":
    """An :class:`ArcsimMaterial` from the parsed JSON of an ARCSim material file.

    Raises :class:`~cloth_gym.errors.MaterialError` naming the key (``density``,
    ``stretching[2][1]``, ...) of anything missing, malformed or out of range."""
    if not isinstance(data, Mapping):
        raise MaterialTypeError("<arcsim>", f"expected a JSON object with density, stretching and bending, "
                                f"got {type(data).__name__}")
    if "density" not in data:
        raise MaterialError("density", "missing (areal density, kg/m²)")
    density = real("density", data["density"], 0.0, 10.0, lo_open=True, unit="kg/m²", error=MaterialError)
    stretching = _table(data, "stretching", (6, 4), "N/m")
    bending = _table(data, "bending", (3, 5), "N·m")
    if not np.any(stretching[:, [0, 2]] > 0):
        raise MaterialError("stretching", "no positive tensile stiffness (columns C11 and C22)")
    return ArcsimMaterial(name=name, density=density, stretching=stretching, bending=bending)


def read_arcsim(path: "str | os.PathLike") -> "ArcsimMaterial":
    """Read an ARCSim material file (JSON; ``//`` comment lines allowed, as ARCSim allows them)."""
    path = Path(path)
    if not is_file(path):
        raise MaterialError("material", f"no ARCSim material file at {str(path)[:200]!r}")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise MaterialError("material", f"cannot read {path}: {err}") from None
    try:
        return parse_arcsim(_load_json(text, str(path)), name=path.stem)
    except MaterialError as err:
        named = type(err)(err.field, f"{err.message} (in {path})")
        named.file = str(path)
        raise named from None


@dataclass(frozen=True)
class ArcsimMaterial:
    """ARCSim's model of a measured fabric, in SI as stored (see the module docstring).

    Attributes
    ----------
    name
        the file's stem.
    density
        areal density, kg/m².
    stretching
        (6, 4) stiffness samples (C11, C12, C22, C33), N/m, as stored (before ARCSim's doubling).
    bending
        (3, 5) hinge stiffness samples, N·m: rows fold edge along u, at 45°, along v; columns
        α = 0, 5, 10, 15, 20 1/m.
    """

    name: str
    density: float
    stretching: np.ndarray
    bending: np.ndarray

    # ---------------------------------------------------------------- stretching
    def stiffness(self, G: np.ndarray) -> np.ndarray:
        """ARCSim's stiffness (k0, k1, k2, k3), N/m, at Green strains ``G`` (..., 2, 2), evaluated
        from the samples: linear in the principal stretch from row 0 to the stretched rows, linear
        in the principal direction's angle between them, clipped at 0 and doubled (the blend that
        ARCSim tabulates at load time)."""
        G = np.asarray(G, dtype=float)
        a = 2.0 * G[..., 0, 0] + 1.0
        d = 2.0 * G[..., 1, 1] + 1.0
        b = 2.0 * G[..., 0, 1]
        lam = 0.5 * (a + d + np.sqrt((a - d) ** 2 + 4.0 * b * b))  # larger eigenvalue of C = 2G + I
        vx = lam - d
        vy = b.copy()
        flat = (b == 0.0)
        vx = np.where(flat, np.where(a >= d, 1.0, 0.0), vx)
        vy = np.where(flat, np.where(a >= d, 0.0, 1.0), vy)
        t_ang = np.clip(8.0 * np.abs(np.arctan2(vy, vx)) / math.pi, 0.0, 4.0 - 1e-6)
        ia = np.floor(t_ang).astype(int)
        fa = (t_ang - ia)[..., None]
        fs = np.clip(6.0 * (np.sqrt(lam) - 1.0), 0.0, 1.0 - 1e-6)[..., None]
        zero, stretched = self.stretching[0], self.stretching[1:]
        k = ((1.0 - fs) * zero + fs * ((1.0 - fa) * stretched[ia] + fa * stretched[ia + 1]))
        return 2.0 * np.maximum(k, 0.0)

    def _grid(self) -> np.ndarray:
        cached = self.__dict__.get("_grid_cache")
        if cached is None:
            g = np.arange(_GRID_N) / _GRID_N
            i, j, k = np.meshgrid(g - 0.25, g - 0.25, g, indexing="ij")
            G = np.stack([np.stack([i, k], -1), np.stack([k, j], -1)], -2)
            cached = self.stiffness(G)
            object.__setattr__(self, "_grid_cache", cached)
        return cached

    def table_stiffness(self, G: np.ndarray) -> np.ndarray:
        """The stiffness ARCSim's runtime uses, N/m: the load-time table over Green strains
        (G00, G11 from −0.25 in steps of 1/30; |G01| from 0), read by trilinear interpolation and
        held constant outside the table."""
        G = np.asarray(G, dtype=float)
        grid = self._grid()
        coords = [_GRID_N * (G[..., 0, 0] + 0.25), _GRID_N * (G[..., 1, 1] + 0.25), _GRID_N * np.abs(G[..., 0, 1])]
        base, frac = [], []
        for c in coords:
            c = np.clip(c, 0.0, _GRID_N - 1 - 1e-5)
            i = np.minimum(np.floor(c).astype(int), _GRID_N - 2)
            base.append(i)
            frac.append((c - i)[..., None])
        out = 0.0
        for di in (0, 1):
            for dj in (0, 1):
                for dk in (0, 1):
                    w = ((frac[0] if di else 1 - frac[0]) * (frac[1] if dj else 1 - frac[1])
                         * (frac[2] if dk else 1 - frac[2]))
                    out = out + w * grid[base[0] + di, base[1] + dj, base[2] + dk]
        return out

    def stress(self, G: np.ndarray, table: bool = False) -> np.ndarray:
        """Second Piola–Kirchhoff stress (..., 2, 2), N/m, that ARCSim's force applies at ``G``:
        with the stiffness blended from the samples, or with ``table`` as ARCSim's runtime
        reads it from its load-time table (which rounds the blend to its 1/30 grid: near zero
        strain it mixes in a twentieth of the stretched samples)."""
        G = np.asarray(G, dtype=float)
        k = self.table_stiffness(G) if table else self.stiffness(G)
        k0, k1, k2, k3 = (k[..., i] for i in range(4))
        s00 = k0 * G[..., 0, 0] + k1 * G[..., 1, 1]
        s11 = k1 * G[..., 0, 0] + k2 * G[..., 1, 1]
        s01 = k3 * G[..., 0, 1]
        return np.stack([np.stack([s00, s01], -1), np.stack([s01, s11], -1)], -2)

    def uniaxial_tension(self, strain: np.ndarray, angle_deg: float, table: bool = False) -> np.ndarray:
        """Tension per unit reference width, N/m, of a strip stretched by engineering ``strain``
        (dimensionless) along the material direction at ``angle_deg`` from u, its lateral stress
        free and its clamps holding it from shearing (``table``: see :meth:`stress`)."""
        from scipy.optimize import brentq

        c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
        d, n = np.array([c, s]), np.array([-s, c])
        out = []
        for e in np.atleast_1d(np.asarray(strain, dtype=float)):
            lam = 1.0 + e

            def lateral(lt, lam=lam):
                G = 0.5 * (lam * lam - 1.0) * np.outer(d, d) + 0.5 * (lt * lt - 1.0) * np.outer(n, n)
                return n @ self.stress(G, table) @ n, d @ self.stress(G, table) @ d

            lo, hi = 0.3, 1.0 + 1e-12
            flo, fhi = lateral(lo)[0], lateral(hi)[0]
            if fhi <= 0.0:  # no Poisson contraction (k1 = 0 or a compressive lateral pull): strip keeps its width
                lt = 1.0
            elif flo >= 0.0:
                lt = lo
            else:
                lt = brentq(lambda x: lateral(x)[0], lo, hi, xtol=1e-14)
            out.append(lam * lateral(lt)[1])
        return np.array(out)

    def shear_force(self, angle_deg: np.ndarray, along: int, table: bool = False) -> np.ndarray:
        """Force per unit length, N/m, of a simple shear by ``γ = tan φ`` sliding along material
        axis ``along`` (0: u, 1: v): the work-conjugate ``S : dG/dγ`` of ARCSim's stress."""
        g = np.tan(np.radians(np.asarray(angle_deg, dtype=float)))
        G = np.zeros(g.shape + (2, 2))
        G[..., 0, 1] = G[..., 1, 0] = 0.5 * g
        G[..., 1 - along, 1 - along] = 0.5 * g * g  # the sheared fibres lengthen
        S = self.stress(G, table)
        return 2.0 * S[..., 0, 1] * 0.5 + S[..., 1 - along, 1 - along] * g

    def poisson_ratio(self) -> tuple[float, float]:
        """ARCSim's Poisson ratios at zero strain (``k1/k2`` for a pull along u, ``k1/k0`` along
        v): how much a biaxial stretch couples the axes, the term the conversion drops."""
        k0, k1, k2, _ = 2.0 * np.maximum(self.stretching[0], 0.0)
        return (k1 / k2 if k2 > 0 else 0.0, k1 / k0 if k0 > 0 else 0.0)

    # ---------------------------------------------------------------- bending
    def hinge_stiffness(self, edge_angle_deg: np.ndarray, alpha_per_cm: np.ndarray) -> np.ndarray:
        """ARCSim's hinge stiffness ke, N·m, of a fold edge at ``edge_angle_deg`` from u and hinge
        curvature ``alpha_per_cm`` (1/cm): bilinear in the edge direction (rows 0°, 45°, 90°,
        mirrored) and the curvature (columns 0.05 1/cm apart, held beyond the last), clipped at 0."""
        beta = np.abs(4.0 * np.radians(np.asarray(edge_angle_deg, dtype=float)) / math.pi)
        beta = np.mod(beta, 8.0)
        beta = np.where(beta > 4.0, 8.0 - beta, beta)
        beta = np.where(beta > 2.0, 4.0 - beta, beta)
        ib = np.clip(np.floor(beta).astype(int), 0, 1)
        fb = beta - ib
        tc = np.minimum(np.abs(np.asarray(alpha_per_cm, dtype=float)) / _ALPHA_STEP_PER_CM, 4.0)
        ic = np.clip(np.floor(tc).astype(int), 0, 3)
        fc = tc - ic
        B = self.bending
        ke = ((1 - fb) * (1 - fc) * B[ib, ic] + fb * (1 - fc) * B[ib + 1, ic]
              + (1 - fb) * fc * B[ib, ic + 1] + fb * fc * B[ib + 1, ic + 1])
        return np.maximum(ke, 0.0)

    def bending_moment(self, curvature_per_cm: np.ndarray, axis: int, n_dirs: int = 3600) -> np.ndarray:
        """Moment per unit width, N·m/m, of a cylinder of curvature κ (1/cm) along material axis
        ``axis`` (0: u, 1: v) on an equilateral mesh averaged over its orientation:
        ``(κ/12)·⟨ke(edge, κ·|4cos²ψ − 1|/6)·(4cos²ψ − 1)²⟩`` over the edge directions, ψ between
        the edge's normal and the curvature direction (module docstring), with ke held fixed as
        in ARCSim's force. ``n_dirs`` edge directions sample the average (midpoint rule)."""
        kappa = np.atleast_1d(np.asarray(curvature_per_cm, dtype=float))
        edge = (np.arange(n_dirs) + 0.5) * 180.0 / n_dirs  # edge direction from u, degrees
        normal = np.radians(edge + 90.0)
        f = 4.0 * np.cos(normal - math.radians(90.0 * axis)) ** 2 - 1.0
        alpha = kappa[:, None] * np.abs(f)[None, :] / 6.0
        ke = self.hinge_stiffness(edge[None, :], alpha)
        kappa_per_m = kappa * 100.0
        return kappa_per_m / 12.0 * np.mean(ke * (f * f)[None, :], axis=1)

    def mesh_bending_moment(self, curvature_per_cm: float, axis: int, rotations: int = 90,
                            edge_cm: float = 0.01) -> float:
        """Reference for :meth:`bending_moment`, N·m/m: the moment per unit width that ARCSim's
        hinge forces exert on equilateral meshes (side ``edge_cm``) wrapped on a cylinder of
        curvature κ (1/cm) along material axis ``axis``, averaged over ``rotations`` mesh
        orientations. Each hinge family's dihedral angle is computed from the wrapped vertices
        (every hinge of a family alike: the cylinder is the same everywhere), its stiffness
        looked up from the edge direction and ``α = |θ|·l/(2(A1 + A2))`` and held fixed when θ is
        differentiated in κ (ARCSim's force): ``M = Σ ke·l²·θ·dθ/dκ / (4(A1 + A2)²)``."""
        kappa = float(curvature_per_cm)
        l = float(edge_cm)
        area_e = math.sqrt(3.0) / 2.0 * l * l  # A1 + A2
        c, c_perp = np.eye(2)[axis], np.eye(2)[1 - axis]

        def wrap(p, k):
            s, t = p @ c, p @ c_perp
            return np.array([math.sin(k * s) / k, t, (1.0 - math.cos(k * s)) / k])

        def theta(p, q, r1, k):
            r2 = p + q - r1  # the other wing, mirrored across the edge
            P, Q, R1, R2 = (wrap(x, k) for x in (p, q, r1, r2))
            n1, n2 = np.cross(Q - P, R1 - P), np.cross(R2 - P, Q - P)
            n1, n2 = n1 / np.linalg.norm(n1), n2 / np.linalg.norm(n2)
            sign = 1.0 if np.cross(n1, n2) @ (Q - P) >= 0 else -1.0
            return sign * math.atan2(np.linalg.norm(np.cross(n1, n2)), n1 @ n2)

        total = 0.0
        origin = np.array([0.37, -0.21])  # anywhere: the cylinder is the same everywhere
        for rho in (np.arange(rotations) + 0.5) * (math.pi / 3.0) / rotations:
            a1 = l * np.array([math.cos(rho), math.sin(rho)])
            a2 = l * np.array([math.cos(rho + math.pi / 3), math.sin(rho + math.pi / 3)])
            for p, q, r1 in ((origin, origin + a1, origin + a2), (origin, origin + a2, origin + a2 - a1),
                             (origin + a1, origin + a2, origin)):
                th = theta(p, q, r1, kappa)
                h = 1e-6 * kappa
                dth = (theta(p, q, r1, kappa + h) - theta(p, q, r1, kappa - h)) / (2.0 * h)
                e = q - p
                ke = float(self.hinge_stiffness(math.degrees(math.atan2(e[1], e[0])), abs(th) * l / (2.0 * area_e)))
                total += ke * l * l * th * dth / (4.0 * area_e * area_e)  # one hinge per A1 + A2 of area
        return total / rotations * 100.0  # N·m/cm → N·m/m

    # ---------------------------------------------------------------- axes
    def stiffer_axis(self) -> str:
        """``"u"`` or ``"v"``: the axis of the larger tensile stiffness at zero strain."""
        k = self.stretching[0]
        return "u" if k[0] >= k[2] else "v"


def convert(material: ArcsimMaterial, warp: str = "stiffer", name: str | None = None,
            description: str = "", source: str = "") -> dict:
    """The project's material (the YAML schema of :mod:`cloth_gym.materials`) of an ARCSim fabric:
    warp and weft tension, bending and shear as samples in KES units (fitted when loaded), the
    areal density, and the default simulation constants of :class:`~cloth_gym.materials.Material`.

    ``warp`` is ``"u"``, ``"v"`` or ``"stiffer"`` (the axis of larger tensile stiffness at zero
    strain). Returns a mapping for :func:`cloth_gym.load_material` or ``yaml.safe_dump``."""
    warp = one_of("warp", warp, ("u", "v", "stiffer"), error=MaterialError)
    if warp == "stiffer":
        warp = material.stiffer_axis()
    axes = {"warp": 0 if warp == "u" else 1}
    axes["weft"] = 1 - axes["warp"]
    eps = STRAIN_PERCENT / 100.0

    def r(values, digits=6):
        return [float(f"{v:.{digits}g}") for v in np.asarray(values, dtype=float)]

    stretch, bending, shear = {}, {}, {}
    for d, ax in axes.items():
        stretch[d] = {"strain_percent": r(STRAIN_PERCENT),
                      "stress_gf_per_cm": r(material.uniaxial_tension(eps, 90.0 * ax) * N_PER_M / GF),
                      "terms": ["c1", "c2"]}
        bending[d] = {"curvature_per_cm": r(CURVATURE_PER_CM),
                      "moment_gf_cm_per_cm": r(material.bending_moment(CURVATURE_PER_CM, ax) * NM / 100.0 / GF)}
        shear[d] = {"angle_deg": r(SHEAR_DEG),
                    "force_gf_per_cm": r(material.shear_force(SHEAR_DEG, ax) * N_PER_M / GF)}
    return {
        "name": name or material.name,
        "description": description,
        "source": source,
        "areal_density_g_per_cm2": float(f"{material.density * 0.1:.6g}"),
        "stretch": stretch,
        "bending": bending,
        "shear": shear,
    }
