"""Headless software renderer: triangle meshes and cloth scenes → uint8 RGB images.

No display and no GPU: triangles are shaded on the CPU (two-sided Lambert with
one directional light plus ambient, flat per face), clipped at the camera's
near plane and drawn by the numba z-buffer rasteriser of
:mod:`cloth_gym.render.raster`. Output images are ``(height, width, 3)`` uint8,
row 0 at the top.

Colours: an integer array (or a tuple of ints) is RGB on the 0–255 scale; a
float array is RGB on the 0–1 scale (matplotlib's convention).
"""

from __future__ import annotations

import math
import warnings
from typing import Iterable, Sequence

import numpy as np

from ..errors import ConfigError
from ..sim.obstacles import Plane
from .camera import Camera, check_size
from .raster import clip_near, downsample, face_shade, rasterize, to_uint8
from .shapes import obstacle_mesh, sphere_mesh

__all__ = ["Renderer", "colormap", "DEFAULT_CLOTH_RGB", "OBSTACLE_RGB", "PLANE_RGB"]

DEFAULT_CLOTH_RGB = (70, 110, 190)
"""Default cloth colour (0–255)."""
OBSTACLE_RGB = (150, 150, 150)
"""Colour of boxes, spheres, cylinders and mesh obstacles (0–255)."""
PLANE_RGB = (215, 210, 200)
"""Colour of floor planes (0–255)."""


def _rgb(name: str, c, n_rows: Sequence[int] = ()) -> np.ndarray:
    """Colours as float64 on the 0–255 scale: (3,) or (R, 3) with R in ``n_rows``."""
    a = np.asarray(c)
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise ConfigError(name, f"must be numeric RGB, got dtype {a.dtype}")
    if not (a.shape == (3,) or (a.ndim == 2 and a.shape[1] == 3 and a.shape[0] in n_rows)):
        rows = " or ".join(f"({n}, 3)" for n in n_rows)
        raise ConfigError(name, f"must have shape (3,){' or ' + rows if rows else ''}, got {a.shape}")
    a = a.astype(float)
    if not np.all(np.isfinite(a)):
        raise ConfigError(name, "must be finite")
    top = 255.0 if np.issubdtype(np.asarray(c).dtype, np.integer) else 1.0
    if np.any(a < 0) or np.any(a > top):
        raise ConfigError(name, f"{'integer' if top == 255 else 'float'} RGB must be in [0, {top:g}]")
    return a * (255.0 / top)


def _mesh(i: int, mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated (vertices (V, 3), faces (F, 3) int64, corner colours (F, 3, 3) on 0–255)."""
    try:
        verts, faces, colors = mesh
    except (TypeError, ValueError):
        raise ConfigError(f"meshes[{i}]", "must be a (vertices, faces, colors) triple") from None
    v = np.asarray(verts, dtype=float) if np.asarray(verts).dtype != object else None
    if v is None or v.ndim != 2 or v.shape[1] != 3:
        raise ConfigError(f"meshes[{i}].vertices", f"must have shape (V, 3) (cm), got {np.shape(verts)}")
    if not np.all(np.isfinite(v)):
        raise ConfigError(f"meshes[{i}].vertices", "must be finite")
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and not np.issubdtype(f.dtype, np.integer)):
        raise ConfigError(f"meshes[{i}].faces", f"must be an integer array of shape (F, 3), got {f.dtype} {f.shape}")
    f = f.astype(np.int64)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ConfigError(f"meshes[{i}].faces", f"indices must be in [0, {len(v) - 1}]")
    c = _rgb(f"meshes[{i}].colors", colors, (len(v), len(f)))
    if c.ndim == 1:
        corner = np.broadcast_to(c, (len(f), 3, 3))
    elif c.shape[0] == len(v):  # per vertex (also when V == F)
        corner = c[f]
    else:  # per face
        corner = np.broadcast_to(c[:, None, :], (len(f), 3, 3))
    return v, f, corner


def colormap(values, name: str = "viridis", vmin: float | None = None, vmax: float | None = None) -> np.ndarray:
    """Map scalars to (N, 3) uint8 RGB with a matplotlib colormap.

    Parameters
    ----------
    values
        (N,) scalars (any unit). Non-finite values get the colormap's "bad" colour.
    name
        a name registered in ``matplotlib.colormaps`` (``"viridis"``, ``"coolwarm"``, ...).
    vmin, vmax
        value range mapped to the ends of the colormap (default: the finite min / max);
        values outside are clipped. A zero range maps everything to the low end.
    """
    import matplotlib

    v = np.asarray(values, dtype=float)
    if v.ndim != 1:
        raise ConfigError("values", f"must have shape (N,), got {v.shape}")
    try:
        cmap = matplotlib.colormaps[name]
    except KeyError:
        raise ConfigError("name", f"unknown matplotlib colormap {name!r}") from None
    fin = v[np.isfinite(v)]
    lo = float(fin.min()) if vmin is None and fin.size else (0.0 if vmin is None else float(vmin))
    hi = float(fin.max()) if vmax is None and fin.size else (1.0 if vmax is None else float(vmax))
    if not (math.isfinite(lo) and math.isfinite(hi) and hi >= lo):
        raise ConfigError("vmin", f"need finite vmin <= vmax, got {lo}, {hi}")
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.clip((v - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.where(np.isfinite(v), 0.0, np.nan)
    rgba = cmap(np.ma.masked_invalid(t))
    return to_uint8(np.asarray(rgba)[:, :3] * 255.0)


def framing_camera(points: np.ndarray, width: int, height: int, fov_deg: float = 40.0,
                   direction: Sequence[float] = (0.55, -1.0, 0.85)) -> Camera:
    """A perspective camera looking at the centre of the bounding box of ``points`` (N, 3), cm,
    from ``direction`` (towards the eye), far enough that the box's bounding sphere fits the view."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1.0)
    half = math.radians(fov_deg) / 2.0
    half = min(half, math.atan(math.tan(half) * width / height))
    d = np.asarray(direction, dtype=float)
    eye = centre + d / np.linalg.norm(d) * (1.05 * radius / math.sin(half))
    return Camera.look_at(eye, centre, up=(0.0, 0.0, 1.0), fov_deg=fov_deg)


class Renderer:
    """Render triangle meshes or a cloth scene to ``(height, width, 3)`` uint8 RGB.

    Parameters
    ----------
    width, height
        image size, px.
    camera
        a :class:`Camera`; ``None`` frames the content's bounding box at each call
        (the meshes' for :meth:`render_meshes`, the cloth's for :meth:`render_scene`).
    background
        RGB of empty pixels (0–255 ints, or 0–1 floats).
    light_dir
        direction *towards* the light, world frame (normalised here).
    ambient
        fraction of the light that is ambient, in [0, 1]; a face is lit with
        ``ambient + (1 − ambient)·|n̂·l̂|`` (two-sided). ``ambient=1`` draws unlit colours.
    ssaa
        supersampling factor, 1 (off) or 2 (render 2W × 2H, average 2 × 2 blocks).
    """

    def __init__(self, width: int = 320, height: int = 240, camera: Camera | None = None,
                 background=(255, 255, 255), light_dir: Sequence[float] = (0.3, -0.4, 1.0),
                 ambient: float = 0.35, ssaa: int = 1):
        self.width, self.height = check_size(width, height)
        if camera is not None and not isinstance(camera, Camera):
            raise ConfigError("camera", f"must be a Camera or None, got {type(camera).__name__}")
        self.camera = camera
        self.background = _rgb("background", background)
        ld = np.asarray(light_dir, dtype=float)
        if ld.shape != (3,) or not np.all(np.isfinite(ld)) or np.linalg.norm(ld) == 0:
            raise ConfigError("light_dir", f"must be 3 finite numbers, not all 0, got {light_dir!r}")
        self.light_dir = ld / np.linalg.norm(ld)
        if not (isinstance(ambient, (int, float)) and 0.0 <= ambient <= 1.0):
            raise ConfigError("ambient", f"must be in [0, 1], got {ambient!r}")
        self.ambient = float(ambient)
        if ssaa not in (1, 2) or isinstance(ssaa, bool):
            raise ConfigError("ssaa", f"must be 1 or 2, got {ssaa!r}")
        self.ssaa = int(ssaa)

    # ------------------------------------------------------------------ public
    def render_meshes(self, meshes: Iterable) -> np.ndarray:
        """Draw ``meshes``, each ``(vertices (V, 3) cm, faces (F, 3) int, colors)``.

        ``colors``: one RGB (3,), per vertex (V, 3) (interpolated across faces; chosen
        when V == F) or per face (F, 3). Returns (H, W, 3) uint8.
        """
        if isinstance(meshes, (str, bytes)) or not hasattr(meshes, "__iter__"):
            raise ConfigError("meshes", "must be a sequence of (vertices, faces, colors)")
        return self._draw([_mesh(i, m) for i, m in enumerate(meshes)], self.camera)

    def render_scene(self, model, state, *, particle_colors=None, markers: Iterable = (),
                     show_obstacles: bool = True, meshes: Iterable = ()) -> np.ndarray:
        """Draw a cloth ``model`` at ``state.particle_q``, its obstacles and markers.

        Parameters
        ----------
        model
            :class:`~cloth_gym.sim.model.Model`; its triangles ``tri_indices`` are drawn.
        state
            :class:`~cloth_gym.sim.model.State` (positions, cm).
        particle_colors
            RGB (3,) or (N, 3) per particle (e.g. from :func:`colormap`);
            default :data:`DEFAULT_CLOTH_RGB`.
        markers
            ``(center (3,) cm, radius cm, rgb)`` triples drawn as spheres (grippers, targets).
        show_obstacles
            draw ``model.obstacles`` (Plane as a 200 cm square around its point,
            Box, Sphere, Cylinder, and any obstacle with ``vertices``/``faces``).
        meshes
            more triangle meshes to draw, as in :meth:`render_meshes` (target regions, labels).

        Returns (H, W, 3) uint8. With ``camera=None`` the view frames the cloth's bounding box.
        """
        return self._draw(*self._scene(model, state, particle_colors, markers, show_obstacles, meshes))

    def render_scene_depth(self, model, state, *, markers: Iterable = (), show_obstacles: bool = True,
                           meshes: Iterable = ()) -> np.ndarray:
        """The depth image of :meth:`render_scene`'s view: (H, W) float32, the distance (cm) along
        the view direction of what each pixel shows, ``inf`` where it shows only background. With
        ``ssaa=2`` each pixel is the nearest of its 2 × 2 samples."""
        return self._draw(*self._scene(model, state, None, markers, show_obstacles, meshes), depth=True)

    # ------------------------------------------------------------------ internals
    def _scene(self, model, state, particle_colors, markers, show_obstacles, extra=()) -> tuple:
        """(meshes, camera) of a cloth scene (:meth:`render_scene`'s arguments, validated)."""
        q = np.asarray(state.particle_q, dtype=float)
        n = model.particle_count
        if q.shape != (n, 3):
            raise ConfigError("state.particle_q", f"must have shape ({n}, 3), got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise ConfigError("state.particle_q", "must be finite")
        colors = DEFAULT_CLOTH_RGB if particle_colors is None else particle_colors
        if particle_colors is not None:  # validate here so the error names the field
            _rgb("particle_colors", particle_colors, (n,))
        meshes = [_mesh(0, (q, model.tri_indices, colors))] if n else []
        if show_obstacles:
            for k, ob in enumerate(model.obstacles):
                vf = obstacle_mesh(ob)
                if vf is None:
                    warnings.warn(f"render_scene: cannot draw obstacle {type(ob).__name__}; skipped", stacklevel=2)
                    continue
                rgb = PLANE_RGB if isinstance(ob, Plane) else OBSTACLE_RGB
                try:
                    meshes.append(_mesh(k, (vf[0], vf[1], rgb)))
                except ConfigError as e:
                    raise ConfigError(f"model.obstacles[{k}]", str(e)) from None
        for k, m in enumerate(markers):
            try:
                center, radius, rgb = m
            except (TypeError, ValueError):
                raise ConfigError(f"markers[{k}]", "must be a (center, radius, rgb) triple") from None
            c = np.asarray(center, dtype=float)
            if c.shape != (3,) or not np.all(np.isfinite(c)):
                raise ConfigError(f"markers[{k}].center", f"must be 3 finite numbers (cm), got {center!r}")
            if not (isinstance(radius, (int, float, np.floating)) and math.isfinite(radius) and radius > 0):
                raise ConfigError(f"markers[{k}].radius", f"must be a finite length > 0 cm, got {radius!r}")
            v, f = sphere_mesh(c, float(radius))
            meshes.append(_mesh(k, (v, f, np.rint(_rgb(f"markers[{k}].rgb", rgb)).astype(np.uint8))))
        if isinstance(extra, (str, bytes)) or not hasattr(extra, "__iter__"):
            raise ConfigError("meshes", "must be a sequence of (vertices, faces, colors)")
        meshes += [_mesh(i, m) for i, m in enumerate(extra)]
        camera = self.camera
        if camera is None and n:
            camera = framing_camera(q, self.width, self.height)
        return meshes, camera

    def _draw(self, meshes, camera: Camera | None, depth: bool = False) -> np.ndarray:
        """The colour image (H, W, 3) uint8 of ``meshes`` seen by ``camera``, or with ``depth`` its
        depth image (H, W) float32, cm (``inf``: background)."""
        s = self.ssaa
        H, W = self.height * s, self.width * s
        cbuf = np.empty((H, W, 3))
        cbuf[:] = self.background
        zbuf = np.full((H, W), np.inf)
        meshes = [m for m in meshes if len(m[1])]
        if meshes:
            if camera is None:
                camera = framing_camera(np.concatenate([m[0] for m in meshes]), self.width, self.height)
            corners, colors = [], []
            for v, f, corner in meshes:
                shade = np.empty(len(f))
                face_shade(v, f, self.light_dir, self.ambient, shade)
                corners.append(camera.to_camera(v)[f])
                colors.append(corner * shade[:, None, None])
            pc, col = clip_near(np.ascontiguousarray(np.concatenate(corners)),
                                np.ascontiguousarray(np.concatenate(colors)), camera.near)
            scr = camera.project_camera(pc, W, H)
            rasterize(np.ascontiguousarray(scr[..., 0]), np.ascontiguousarray(scr[..., 1]),
                      np.ascontiguousarray(pc[..., 2]), col, not camera.orthographic, cbuf, zbuf)
        if depth:
            z = zbuf.reshape(self.height, s, self.width, s).min(axis=(1, 3)) if s > 1 else zbuf
            return z.astype(np.float32)
        if s > 1:
            out = np.empty((self.height, self.width, 3))
            downsample(cbuf, s, out)
            cbuf = out
        return to_uint8(cbuf)
