"""Numba z-buffer triangle rasteriser: arrays in, arrays out (no display, no GPU).

Pipeline (driven by :class:`~cloth_gym.render.renderer.Renderer`):

1. :func:`face_shade` — Lambert intensity of each face, two-sided:
   ``ambient + (1 − ambient)·|n̂·l̂|`` (n̂ the face normal, l̂ the direction
   *towards* the light), so cloth seen from either side is lit alike;
2. :func:`clip_near` — triangles (camera frame, cm) clipped against the plane
   ``z = near`` (Sutherland–Hodgman: each triangle gives 0, 1 or 2 triangles; NumPy, as
   few triangles cross it);
3. :func:`rasterize` — per triangle, over its pixel bounding box, the three edge
   functions of each pixel centre decide coverage with the **top-left fill
   rule** (a pixel centre exactly on an edge belongs to the triangle only if
   that edge is a top or a left edge, so two triangles sharing an edge never both
   draw a pixel on it); the depth test keeps the nearer fragment (strictly
   nearer: on a tie the first drawn wins); depth and colour are interpolated
   with barycentric weights, perspective-correct under a perspective camera
   (``1/z`` is linear in screen space);
4. :func:`downsample` — block mean for supersampling, then rounding to uint8.

Pixel conventions are those of :mod:`cloth_gym.render.camera`: pixel (r, c) has
its centre at ``(c + 0.5, r + 0.5)``, y down.
"""

from __future__ import annotations

import math

import numpy as np

from ..sim._numba import njit

__all__ = ["face_shade", "clip_near", "rasterize", "coverage_count", "downsample", "to_uint8"]


@njit
def face_shade(v, faces, light_dir, ambient, out):
    """Two-sided Lambert intensity in [0, 1] of every face into ``out`` (F,).

    ``v`` (V, 3) vertices (cm), ``faces`` (F, 3), ``light_dir`` (3,) unit vector
    towards the light, ``ambient`` in [0, 1]. Degenerate faces get ``ambient``.
    """
    for t in range(faces.shape[0]):
        i = faces[t, 0]
        j = faces[t, 1]
        k = faces[t, 2]
        a0 = v[j, 0] - v[i, 0]
        a1 = v[j, 1] - v[i, 1]
        a2 = v[j, 2] - v[i, 2]
        b0 = v[k, 0] - v[i, 0]
        b1 = v[k, 1] - v[i, 1]
        b2 = v[k, 2] - v[i, 2]
        n0 = a1 * b2 - a2 * b1
        n1 = a2 * b0 - a0 * b2
        n2 = a0 * b1 - a1 * b0
        s = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        lam = 0.0
        if s > 0.0:
            lam = abs(n0 * light_dir[0] + n1 * light_dir[1] + n2 * light_dir[2]) / s
        out[t] = ambient + (1.0 - ambient) * lam


def _clip_face(p, c, inside, near):
    """The triangles (k, 3, 3) left of one triangle (corners ``p`` (3, 3), colours ``c``) that
    crosses the plane ``z = near``: its polygon on the near side (corners in order, with the
    crossing point of each edge that crosses, ``a + s·(b − a)``, s = (near − z_a)/(z_b − z_a),
    colours likewise), fanned from its first corner."""
    poly_p, poly_c = [], []
    for k in range(3):
        k2 = (k + 1) % 3
        if inside[k]:
            poly_p.append(p[k])
            poly_c.append(c[k])
        if inside[k] != inside[k2]:
            s = (near - p[k, 2]) / (p[k2, 2] - p[k, 2])
            poly_p.append(p[k] + s * (p[k2] - p[k]))
            poly_c.append(c[k] + s * (c[k2] - c[k]))
    fan = [(0, t, t + 1) for t in range(1, len(poly_p) - 1)]  # 3 corners: 1 triangle, 4: 2
    return (np.array([[poly_p[i] for i in tri] for tri in fan]),
            np.array([[poly_c[i] for i in tri] for tri in fan]))


def clip_near(pc, col, near):
    """Clip triangles against the plane ``z = near`` (keep ``z ≥ near``).

    Parameters
    ----------
    pc
        (F, 3, 3) corner positions in the camera frame (cm), ``pc[f, corner, xyz]``.
    col
        (F, 3, 3) corner colours (any linear quantity, interpolated along clipped edges).
    near
        clipping depth, cm.

    Returns
    -------
    (pc_out (G, 3, 3), col_out (G, 3, 3)), G ≤ 2F, in the order of the input faces: a triangle
    wholly in front unchanged, one wholly behind dropped, one that crosses the plane cut
    (:func:`_clip_face`); ``pc`` and ``col`` themselves when every triangle is in front. NumPy,
    with a Python loop over the crossing triangles only (a frame has few): nothing to compile.
    """
    inside = pc[:, :, 2] >= near
    n_in = inside.sum(axis=1)
    keep = n_in == 3
    if keep.all():  # nothing to clip (a task-framed camera): the arrays as given
        return pc, col
    out_p, out_c, start = [], [], 0
    for f in np.flatnonzero((n_in > 0) & (n_in < 3)):
        out_p.append(pc[start:f][keep[start:f]])
        out_c.append(col[start:f][keep[start:f]])
        p, c = _clip_face(pc[f], col[f], inside[f], near)
        out_p.append(p)
        out_c.append(c)
        start = f + 1
    out_p.append(pc[start:][keep[start:]])
    out_c.append(col[start:][keep[start:]])
    return np.concatenate(out_p).reshape(-1, 3, 3), np.concatenate(out_c).reshape(-1, 3, 3)


@njit
def _edge(ax, ay, bx, by, px, py):
    """Edge function of a→b at p: > 0 on the interior side of a positively wound triangle."""
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@njit
def _top_left(ax, ay, bx, by):
    """Whether edge a→b of a positively wound triangle (clockwise on the y-down screen) is a top or left edge."""
    dy = by - ay
    return dy < 0.0 or (dy == 0.0 and bx - ax > 0.0)


@njit
def _covered(w, top_left):
    return w > 0.0 or (w == 0.0 and top_left)


@njit
def _pixel_range(lo, hi, n):
    """Indices c with pixel centre c + 0.5 in [lo, hi], clamped to [0, n − 1] (empty: c0 > c1)."""
    a = int(math.ceil(max(lo - 0.5, -1.0)))
    b = int(math.floor(min(hi - 0.5, float(n))))
    return max(a, 0), min(b, n - 1)


@njit
def rasterize(sx, sy, sz, col, perspective, cbuf, zbuf):
    """Draw triangles into a colour buffer with a depth test (module docstring).

    Parameters
    ----------
    sx, sy
        (G, 3) screen coordinates of the corners, px (x right, y down).
    sz
        (G, 3) depth of the corners along the view direction, cm (> 0 under perspective).
    col
        (G, 3, 3) corner colours, float RGB (0–255 scale, already shaded).
    perspective
        interpolate perspective-correctly (``1/z`` linear) if True, affinely if False.
    cbuf
        (H, W, 3) float64 colour buffer, updated in place.
    zbuf
        (H, W) float64 depth buffer (``inf`` where empty), updated in place.

    Returns the number of fragments written (pixels that passed the depth test).
    """
    H = cbuf.shape[0]
    W = cbuf.shape[1]
    written = 0
    for t in range(sx.shape[0]):
        x0 = sx[t, 0]
        y0 = sy[t, 0]
        x1 = sx[t, 1]
        y1 = sy[t, 1]
        x2 = sx[t, 2]
        y2 = sy[t, 2]
        i1 = 1
        i2 = 2
        area = _edge(x0, y0, x1, y1, x2, y2)
        if not math.isfinite(area) or area == 0.0:
            continue
        if area < 0.0:  # two-sided: wind every triangle the same way
            x1, y1, x2, y2 = x2, y2, x1, y1
            i1, i2 = 2, 1
            area = -area
        tl0 = _top_left(x1, y1, x2, y2)
        tl1 = _top_left(x2, y2, x0, y0)
        tl2 = _top_left(x0, y0, x1, y1)
        za = sz[t, 0]
        zb = sz[t, i1]
        zc = sz[t, i2]
        c0, c1 = _pixel_range(min(x0, x1, x2), max(x0, x1, x2), W)
        r0, r1 = _pixel_range(min(y0, y1, y2), max(y0, y1, y2), H)
        for r in range(r0, r1 + 1):
            py = r + 0.5
            for c in range(c0, c1 + 1):
                px = c + 0.5
                w0 = _edge(x1, y1, x2, y2, px, py)
                if not _covered(w0, tl0):
                    continue
                w1 = _edge(x2, y2, x0, y0, px, py)
                if not _covered(w1, tl1):
                    continue
                w2 = _edge(x0, y0, x1, y1, px, py)
                if not _covered(w2, tl2):
                    continue
                b0 = w0 / area
                b1 = w1 / area
                b2 = w2 / area
                if perspective:
                    q0 = b0 / za
                    q1 = b1 / zb
                    q2 = b2 / zc
                    qs = q0 + q1 + q2
                    z = 1.0 / qs
                    b0 = q0 * z
                    b1 = q1 * z
                    b2 = q2 * z
                else:
                    z = b0 * za + b1 * zb + b2 * zc
                if z < zbuf[r, c]:
                    zbuf[r, c] = z
                    for k in range(3):
                        cbuf[r, c, k] = b0 * col[t, 0, k] + b1 * col[t, i1, k] + b2 * col[t, i2, k]
                    written += 1
    return written


@njit
def coverage_count(sx, sy, height, width):
    """(H, W) int32: how many of the triangles (screen corners ``sx, sy`` (G, 3), px) cover each
    pixel centre under the same fill rule as :func:`rasterize` (no depth test)."""
    out = np.zeros((height, width), dtype=np.int32)
    for t in range(sx.shape[0]):
        x0 = sx[t, 0]
        y0 = sy[t, 0]
        x1 = sx[t, 1]
        y1 = sy[t, 1]
        x2 = sx[t, 2]
        y2 = sy[t, 2]
        area = _edge(x0, y0, x1, y1, x2, y2)
        if not math.isfinite(area) or area == 0.0:
            continue
        if area < 0.0:
            x1, y1, x2, y2 = x2, y2, x1, y1
        tl0 = _top_left(x1, y1, x2, y2)
        tl1 = _top_left(x2, y2, x0, y0)
        tl2 = _top_left(x0, y0, x1, y1)
        c0, c1 = _pixel_range(min(x0, x1, x2), max(x0, x1, x2), width)
        r0, r1 = _pixel_range(min(y0, y1, y2), max(y0, y1, y2), height)
        for r in range(r0, r1 + 1):
            py = r + 0.5
            for c in range(c0, c1 + 1):
                px = c + 0.5
                if (_covered(_edge(x1, y1, x2, y2, px, py), tl0) and _covered(_edge(x2, y2, x0, y0, px, py), tl1)
                        and _covered(_edge(x0, y0, x1, y1, px, py), tl2)):
                    out[r, c] += 1
    return out


@njit
def downsample(cbuf, factor, out):
    """Block mean of ``cbuf`` (factor·H, factor·W, 3) into ``out`` (H, W, 3) (supersampling)."""
    H = out.shape[0]
    W = out.shape[1]
    inv = 1.0 / (factor * factor)
    for r in range(H):
        for c in range(W):
            for k in range(3):
                s = 0.0
                for i in range(factor):
                    for j in range(factor):
                        s += cbuf[r * factor + i, c * factor + j, k]
                out[r, c, k] = s * inv


def to_uint8(img: np.ndarray) -> np.ndarray:
    """Float RGB (0–255 scale) → uint8, rounded half up and clipped."""
    return np.clip(np.floor(img + 0.5), 0, 255).astype(np.uint8)
