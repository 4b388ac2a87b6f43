"""Drape and settling measurements on cloth states (CGS: cm, cm², dyne, s, erg).

* :func:`shadow_area` / :func:`cloth_shadow_area`: area of the union of the
  cloth's triangles projected on the floor (xy) plane, by rasterising onto a grid;
* :func:`drape_coefficient` / :func:`drape_coefficient_from_area`: the drape
  coefficient ``DC = (A_shadow − A_disc)/(A_cloth − A_disc)`` of the drape test;
* :func:`outline_radius` and :func:`node_count`: the projected outline r(θ) and
  its number of folds (nodes);
* :func:`force_fields` / :func:`force_vectors`: internal force per particle,
  one field per force type;
* :func:`settle_time`: when a kinetic-energy series comes to rest.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import ConfigError
from .sim._numba import njit
from .sim.bundles import Force

__all__ = [
    "shadow_area", "cloth_shadow_area", "cloth_rest_area", "drape_coefficient", "drape_coefficient_from_area",
    "outline_radius", "outline_angles", "node_count", "force_vectors", "force_fields", "settle_time",
]

MAX_GRID_CELLS = 100_000_000
"""Largest shadow grid (cells) :func:`shadow_area` accepts before asking for a coarser resolution."""

# bits of cloth_gym.sim.bundles.ForceData.flags
_FORCE_BITS = {"stretch": int(Force.STRETCH), "bending": int(Force.BENDING), "shear": int(Force.SHEAR)}
_BREEN_BIT = int(Force.BREEN)


# ============================================================================ validation helpers
def _xy(name: str, points) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise ConfigError(name, f"must have shape (N, 2) or (N, 3) (cm), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ConfigError(name, "must be finite")
    return np.ascontiguousarray(p[:, :2])


def _length(name: str, v, allow_zero: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v) \
            or v < 0 or (v == 0 and not allow_zero):
        raise ConfigError(name, f"must be a finite length {'>=' if allow_zero else '>'} 0 cm, got {v!r}")
    return float(v)


def _indices(name: str, idx, n: int, k: int) -> np.ndarray:
    a = np.asarray(idx)
    if a.ndim != 2 or a.shape[1] != k or (a.size and not np.issubdtype(a.dtype, np.integer)):
        raise ConfigError(name, f"must be an integer array of shape (M, {k}), got {a.dtype} {a.shape}")
    a = a.astype(np.int64)
    if a.size and (a.min() < 0 or a.max() >= n):
        raise ConfigError(name, f"indices must be in [0, {n - 1}]")
    return np.ascontiguousarray(a)


def _center(center_xy, xy: np.ndarray) -> np.ndarray:
    if center_xy is None:
        return xy.mean(axis=0)
    c = np.asarray(center_xy, dtype=float)
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise ConfigError("center_xy", f"must be 2 finite numbers (cm), got {center_xy!r}")
    return c


# ============================================================================ shadow area
@njit
def mark_triangles(xy, tris, x0, y0, h, grid):
    """Set ``grid[i, j]`` for every cell whose centre ``(x0 + (i + ½)h, y0 + (j + ½)h)`` lies in
    (or on the boundary of) one of the triangles ``tris`` (T, 3) of the points ``xy`` (N, 2), cm."""
    nx = grid.shape[0]
    ny = grid.shape[1]
    for t in range(tris.shape[0]):
        ax = xy[tris[t, 0], 0]
        ay = xy[tris[t, 0], 1]
        bx = xy[tris[t, 1], 0]
        by = xy[tris[t, 1], 1]
        cx = xy[tris[t, 2], 0]
        cy = xy[tris[t, 2], 1]
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if area == 0.0:
            continue
        sgn = 1.0 if area > 0.0 else -1.0
        eps = -1e-12 * abs(area)
        i0 = max(int(math.ceil((min(ax, bx, cx) - x0) / h - 0.5)), 0)
        i1 = min(int(math.floor((max(ax, bx, cx) - x0) / h - 0.5)), nx - 1)
        j0 = max(int(math.ceil((min(ay, by, cy) - y0) / h - 0.5)), 0)
        j1 = min(int(math.floor((max(ay, by, cy) - y0) / h - 0.5)), ny - 1)
        for i in range(i0, i1 + 1):
            px = x0 + (i + 0.5) * h
            for j in range(j0, j1 + 1):
                if grid[i, j]:
                    continue
                py = y0 + (j + 0.5) * h
                w0 = sgn * ((cx - bx) * (py - by) - (cy - by) * (px - bx))
                w1 = sgn * ((ax - cx) * (py - cy) - (ay - cy) * (px - cx))
                w2 = sgn * ((bx - ax) * (py - ay) - (by - ay) * (px - ax))
                if w0 >= eps and w1 >= eps and w2 >= eps:
                    grid[i, j] = True


@njit
def mark_disc(cx, cy, r, x0, y0, h, grid):
    """Set ``grid[i, j]`` for every cell whose centre lies in the disc of radius ``r`` at (cx, cy), cm."""
    for i in range(grid.shape[0]):
        px = x0 + (i + 0.5) * h - cx
        for j in range(grid.shape[1]):
            py = y0 + (j + 0.5) * h - cy
            if px * px + py * py <= r * r:
                grid[i, j] = True


def shadow_area(points_xy, tris, resolution_cm: float = 0.05, *, disc=None) -> float:
    """Area (cm²) of the union of the triangles ``tris`` projected onto the xy plane.

    The plane is cut into square cells of side ``resolution_cm`` and a cell counts
    (its full area ``h²``) when its centre lies in a projected triangle, so folds
    and overlaps count once (a union, not a sum, and not a convex hull). The error
    is of the order of ``perimeter × h / 2`` at worst and much smaller on average.

    Parameters
    ----------
    points_xy
        (N, 2) or (N, 3) positions, cm (z, if any, is ignored).
    tris
        (T, 3) integer vertex indices of the triangles.
    resolution_cm
        cell side h, cm.
    disc
        optional ``(cx, cy, radius)`` (cm) added to the union (a pedestal's own shadow).
    """
    xy = _xy("points_xy", points_xy)
    t = _indices("tris", tris, len(xy), 3)
    h = _length("resolution_cm", resolution_cm)
    used = xy[np.unique(t)] if t.size else np.zeros((0, 2))
    pts = [used]
    if disc is not None:
        d = np.asarray(disc, dtype=float)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or d[2] < 0:
            raise ConfigError("disc", f"must be (cx, cy, radius >= 0) in cm, got {disc!r}")
        pts.append(np.array([[d[0] - d[2], d[1] - d[2]], [d[0] + d[2], d[1] + d[2]]]))
    allp = np.concatenate(pts)
    if not len(allp):
        return 0.0
    lo = allp.min(axis=0) - h
    n = np.ceil((allp.max(axis=0) + h - lo) / h).astype(np.int64) + 1
    if n[0] * n[1] > MAX_GRID_CELLS:
        raise ConfigError("resolution_cm", f"{h} cm needs a grid of {n[0]} x {n[1]} cells; use a coarser one")
    grid = np.zeros((int(n[0]), int(n[1])), dtype=np.bool_)
    mark_triangles(xy, t, float(lo[0]), float(lo[1]), h, grid)
    if disc is not None and d[2] > 0:
        mark_disc(float(d[0]), float(d[1]), float(d[2]), float(lo[0]), float(lo[1]), h, grid)
    return float(np.count_nonzero(grid)) * h * h


def cloth_shadow_area(model, state, resolution_cm: float = 0.05) -> float:
    """:func:`shadow_area` of the cloth's triangles (``model.tri_indices``) at ``state.particle_q``, cm²."""
    return shadow_area(state.particle_q, model.tri_indices, resolution_cm)


def cloth_rest_area(model) -> float:
    """Area of the flat cloth, cm²: the sum of its triangles' areas in the rest configuration.

    For a full lattice this is (number of lattice squares) × σ²; along a disc's
    outline it counts the half squares the triangulation keeps."""
    q = model.particle_q0
    t = model.tri_indices
    if not len(t):
        return 0.0
    return float(0.5 * np.linalg.norm(np.cross(q[t[:, 1]] - q[t[:, 0]], q[t[:, 2]] - q[t[:, 0]]), axis=1).sum())


# ============================================================================ drape coefficient
def drape_coefficient_from_area(shadow_area_cm2: float, cloth_area_cm2: float, pedestal_radius_cm: float) -> float:
    """``DC = (A_shadow − A_disc)/(A_cloth − A_disc)``, ``A_disc = π·r_pedestal²`` (all cm²).

    1 for a cloth that stays flat, smaller the more it drapes (folds hang down
    and their shadow shrinks towards the pedestal's)."""
    a_s = _length("shadow_area_cm2", shadow_area_cm2, allow_zero=True)
    a_c = _length("cloth_area_cm2", cloth_area_cm2)
    r = _length("pedestal_radius_cm", pedestal_radius_cm, allow_zero=True)
    a_d = math.pi * r * r
    if a_c <= a_d:
        raise ConfigError("pedestal_radius_cm", f"the pedestal's area {a_d:.6g} cm² is not smaller than the "
                                                f"cloth's {a_c:.6g} cm²")
    return (a_s - a_d) / (a_c - a_d)


def drape_coefficient(model, state, pedestal_radius_cm: float, center_xy=None,
                      resolution_cm: float = 0.05) -> float:
    """Drape coefficient of the cloth ``state`` on a circular pedestal (dimensionless).

    ``A_shadow`` is :func:`shadow_area` of the cloth's triangles united with the
    pedestal's disc of radius ``pedestal_radius_cm`` centred at ``center_xy`` (cm;
    default the mean xy of the particles) — a drape meter sees the pedestal's
    shadow too; ``A_cloth`` is :func:`cloth_rest_area`. See
    :func:`drape_coefficient_from_area` for the formula.
    """
    r = _length("pedestal_radius_cm", pedestal_radius_cm, allow_zero=True)
    xy = _xy("state.particle_q", state.particle_q)
    c = _center(center_xy, xy)
    a_s = shadow_area(xy, model.tri_indices, resolution_cm, disc=(c[0], c[1], r))
    return drape_coefficient_from_area(a_s, cloth_rest_area(model), r)


# ============================================================================ outline and nodes
def outline_angles(n_bins: int = 360) -> np.ndarray:
    """(n_bins,) bin-centre angles θ_k = 2π(k + ½)/n_bins (rad) of :func:`outline_radius`."""
    return 2.0 * np.pi * (np.arange(n_bins) + 0.5) / n_bins


@njit
def _bin_max(px, py, cx, cy, n_bins, out):
    """``out[k] = max(out[k], radius)`` for the point's angular bin."""
    dx = px - cx
    dy = py - cy
    th = math.atan2(dy, dx)
    if th < 0.0:
        th += 2.0 * math.pi
    k = int(th / (2.0 * math.pi) * n_bins)
    if k >= n_bins:
        k = n_bins - 1
    r = math.sqrt(dx * dx + dy * dy)
    if r > out[k]:
        out[k] = r


@njit
def outline_max(xy, edges, cx, cy, n_bins, out):
    """Max radius (cm) about (cx, cy) per angular bin of the points ``xy`` (N, 2) and of points along
    the segments ``edges`` (E, 2), sampled finely enough (half a bin at the nearer end) to reach every
    bin they cross. ``out`` (n_bins,) starts at −1 (empty bins stay −1)."""
    for p in range(xy.shape[0]):
        _bin_max(xy[p, 0], xy[p, 1], cx, cy, n_bins, out)
    dth = 2.0 * math.pi / n_bins
    for e in range(edges.shape[0]):
        ax = xy[edges[e, 0], 0]
        ay = xy[edges[e, 0], 1]
        bx = xy[edges[e, 1], 0]
        by = xy[edges[e, 1], 1]
        L = math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
        rmin = min(math.sqrt((ax - cx) ** 2 + (ay - cy) ** 2), math.sqrt((bx - cx) ** 2 + (by - cy) ** 2))
        m = 1 + int(min(L / max(0.5 * dth * rmin, 1e-9), 10000.0))
        for s in range(1, m):
            f = s / m
            _bin_max(ax + f * (bx - ax), ay + f * (by - ay), cx, cy, n_bins, out)


def outline_radius(points_xy, center_xy=None, n_bins: int = 360, edges=None) -> np.ndarray:
    """Projected outline radius r(θ), cm: the largest distance from ``center_xy`` of the
    projected points (and of the segments ``edges`` between them) in each angular bin.

    Parameters
    ----------
    points_xy
        (N, 2) or (N, 3) positions, cm (z ignored).
    center_xy
        (2,) centre, cm (default: the mean of the points).
    n_bins
        number of angular bins; bin k covers θ ∈ [2πk/n, 2π(k+1)/n) (θ from +x towards +y),
        its centre is :func:`outline_angles`\\ ``[k]``.
    edges
        optional (E, 2) index pairs (e.g. ``model.edge_indices``): sampling along them closes
        the gaps between the particles of a coarse cloth.

    Returns
    -------
    (n_bins,) radius, cm. Bins with no point are filled by linear interpolation in θ
    between the nearest filled bins (periodically).
    """
    xy = _xy("points_xy", points_xy)
    if len(xy) == 0:
        raise ConfigError("points_xy", "must hold at least one point")
    if isinstance(n_bins, bool) or not isinstance(n_bins, (int, np.integer)) or n_bins < 4:
        raise ConfigError("n_bins", f"must be an integer >= 4, got {n_bins!r}")
    c = _center(center_xy, xy)
    e = np.zeros((0, 2), dtype=np.int64) if edges is None else _indices("edges", edges, len(xy), 2)
    r = np.full(int(n_bins), -1.0)
    outline_max(xy, e, float(c[0]), float(c[1]), int(n_bins), r)
    filled = r >= 0.0
    if not filled.all():
        th = outline_angles(int(n_bins))
        r = np.interp(th, th[filled], r[filled], period=2.0 * np.pi)
    return r


@njit
def peak_prominences(s, peaks):
    """Prominence of each peak of the periodic signal ``s`` (M,): its height above the higher of the two
    lowest points met walking left and right from it until a strictly higher sample (or all the way round)."""
    M = s.shape[0]
    out = np.empty(peaks.shape[0])
    for k in range(peaks.shape[0]):
        i = peaks[k]
        h = s[i]
        lows = np.empty(2)
        for d in range(2):
            step = 1 if d == 0 else -1
            lo = h
            j = i
            for _ in range(M - 1):
                j = (j + step) % M
                if s[j] > h:
                    break
                if s[j] < lo:
                    lo = s[j]
            lows[d] = lo
        out[k] = h - max(lows[0], lows[1])
    return out


def node_count(r_theta, max_harmonic: int = 20, rel_prominence: float = 0.15, samples: int = 1024) -> int:
    """Number of nodes (folds) of a drape outline r(θ) sampled at equal angles over a full turn.

    Method:

    1. **low-pass**: the real FFT of ``r − mean(r)`` keeps harmonics 1 … ``max_harmonic``
       (a fold count above ``max_harmonic`` cannot be seen), and the inverse FFT resamples
       the smooth periodic signal s(θ) at ``samples`` equal angles;
    2. **maxima**: the local maxima of s, periodically (``s[i−1] < s[i] ≥ s[i+1]``);
    3. **prominence**: for each maximum, its height above the higher of the lowest points
       met walking left and right until a higher value (all the way round for the highest);
    4. the maxima with prominence ≥ ``rel_prominence × (max s − min s)`` are counted.

    Noise that survives the low-pass makes small wiggles whose prominence is a small
    fraction of the peak-to-peak amplitude, so they are not counted. A (near-)circular
    outline (amplitude below 1e-9 of the mean radius) has 0 nodes.

    Parameters
    ----------
    r_theta
        (n,) radius (cm, or any unit), n ≥ 8, e.g. from :func:`outline_radius`.
    max_harmonic
        highest harmonic kept (≥ 1; limited to n/2).
    rel_prominence
        threshold relative to the peak-to-peak amplitude, in (0, 1].
    samples
        resampling size of the smoothed signal (≥ n).
    """
    r = np.asarray(r_theta, dtype=float)
    if r.ndim != 1 or r.size < 8 or not np.all(np.isfinite(r)):
        raise ConfigError("r_theta", f"must be a finite (n,) array with n >= 8, got shape {r.shape}")
    if isinstance(max_harmonic, bool) or not isinstance(max_harmonic, (int, np.integer)) or max_harmonic < 1:
        raise ConfigError("max_harmonic", f"must be an integer >= 1, got {max_harmonic!r}")
    if not (isinstance(rel_prominence, (int, float)) and 0 < rel_prominence <= 1):
        raise ConfigError("rel_prominence", f"must be in (0, 1], got {rel_prominence!r}")
    n = r.size
    m = max(int(samples), n)
    c = np.fft.rfft(r - r.mean())
    k = min(int(max_harmonic), n // 2)
    c[0] = 0.0
    c[k + 1:] = 0.0
    s = np.fft.irfft(c, n=m) * (m / n)
    amp = float(s.max() - s.min())
    if amp <= 1e-9 * max(abs(float(r.mean())), 1e-300):
        return 0
    peaks = np.nonzero((s > np.roll(s, 1)) & (s >= np.roll(s, -1)))[0]
    prom = peak_prominences(s, peaks.astype(np.int64))
    return int(np.count_nonzero(prom >= rel_prominence * amp))


# ============================================================================ force fields
def force_vectors(model, state) -> dict:
    """Internal force (dyne) on every particle per force type: ``{"stretch", "bending", "shear"}``,
    each (N, 3).

    Each is :func:`cloth_gym.sim.forces.eval_forces` with only that force's flag bit set
    (the model's law — KES or Breen — kept; gravity, air and damping off). A force
    switched off in ``model.options`` gives zeros, so the three sum to the model's
    total internal force."""
    from .sim.forces import eval_forces

    q = np.asarray(state.particle_q, dtype=float)
    n = model.particle_count
    if q.shape != (n, 3) or not np.all(np.isfinite(q)):
        raise ConfigError("state.particle_q", f"must be finite with shape ({n}, 3), got {q.shape}")
    fd = model.force_data
    base = fd.flags & _BREEN_BIT
    o = model.options
    v = np.zeros((n, 3))
    out = {}
    for name, bit in _FORCE_BITS.items():
        f = np.zeros((n, 3))
        if getattr(o, name):
            eval_forces(q, v, np.zeros(3), fd._replace(flags=base | bit), np.empty((n, 3)), f)
        out[name] = f
    return out


def force_fields(model, state) -> dict:
    """Per-particle force magnitude (dyne) of each internal force: ``{"stretch", "bending", "shear"}``,
    each (N,) float64 (the norms of :func:`force_vectors`)."""
    return {k: np.linalg.norm(f, axis=1) for k, f in force_vectors(model, state).items()}


# ============================================================================ settling
def settle_time(kinetic_energy_series, times, threshold: float) -> float | None:
    """First time (s) from which the kinetic energy stays strictly below ``threshold`` (erg).

    Returns ``times[k]`` for the smallest k with ``KE[j] < threshold`` for every j ≥ k,
    or ``None`` if the last sample is not below the threshold (not settled yet).
    """
    ke = np.asarray(kinetic_energy_series, dtype=float)
    t = np.asarray(times, dtype=float)
    if ke.ndim != 1 or ke.size == 0:
        raise ConfigError("kinetic_energy_series", f"must be a non-empty (n,) array, got shape {ke.shape}")
    if t.shape != ke.shape:
        raise ConfigError("times", f"must have the shape of kinetic_energy_series {ke.shape}, got {t.shape}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise ConfigError("times", "must be finite and non-decreasing (s)")
    if not (isinstance(threshold, (int, float)) and math.isfinite(threshold)):
        raise ConfigError("threshold", f"must be a finite energy (erg), got {threshold!r}")
    above = ~(ke < threshold)  # NaN counts as not settled
    if above[-1]:
        return None
    last = np.nonzero(above)[0]
    return float(t[last[-1] + 1]) if last.size else float(t[0])
