"""A pinhole (or orthographic) camera: world points (cm) → pixel coordinates + depth.

Frames and conventions:

* **camera frame**: x to the right of the image, y up the image, z along the
  viewing direction (``depth``, cm, > 0 in front of the eye);
* **pixel coordinates**: ``(px, py)`` with px to the right and py *down* the
  image, in pixels; pixel ``(row r, column c)`` covers ``[c, c+1) × [r, r+1)``,
  so its centre is ``(c + 0.5, r + 0.5)``; the image centre is
  ``(width/2, height/2)``;
* **perspective**: ``px = W/2 + f·x/z``, ``py = H/2 − f·y/z`` with the focal
  length ``f = (H/2)/tan(fov/2)`` px (``fov_deg`` is the *vertical* field of view);
* **orthographic**: ``px = W/2 + s·x``, ``py = H/2 − s·y`` with
  ``s = (H/2)/ortho_half_height`` px/cm (``ortho_half_height``: half the height,
  cm, of the world seen by the image).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import ConfigError

__all__ = ["Camera"]


def _vec3(name: str, v) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ConfigError(name, f"must be 3 finite numbers (cm), got {v!r}")
    return a


def check_size(width, height) -> tuple[int, int]:
    """``(width, height)`` as ints, or :class:`ConfigError` unless both are positive integers (px)."""
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise ConfigError(name, f"must be a positive integer number of pixels, got {v!r}")
    return int(width), int(height)


@dataclass(frozen=True, eq=False)
class Camera:
    """A camera at ``eye`` (cm) with an orthonormal frame. Build it with :meth:`look_at`.

    Attributes
    ----------
    eye
        (3,) position of the eye, world frame, cm.
    right, up, forward
        (3,) unit vectors of the camera frame in the world frame
        (image right, image up, viewing direction); right-handed as ``right × up = −forward``.
    fov_deg
        vertical field of view of the perspective camera, degrees (0, 180).
    ortho_half_height
        ``None`` for a perspective camera; otherwise the camera is
        orthographic and sees ``2·ortho_half_height`` cm from the bottom to the top of the image.
    near
        near clipping distance along ``forward``, cm; geometry closer than this is clipped away.
    """

    eye: np.ndarray
    right: np.ndarray
    up: np.ndarray
    forward: np.ndarray
    fov_deg: float = 40.0
    ortho_half_height: float | None = None
    near: float = 0.01

    @classmethod
    def look_at(cls, eye: Sequence[float], target: Sequence[float], up: Sequence[float] = (0.0, 0.0, 1.0),
                fov_deg: float = 40.0, ortho_half_height: float | None = None, near: float = 0.01) -> "Camera":
        """A camera at ``eye`` looking at ``target`` (both cm), with ``up`` pointing up the image.

        Perspective with a vertical field of view ``fov_deg`` (degrees) by default;
        orthographic when ``ortho_half_height`` (cm) is given.
        """
        e = _vec3("eye", eye)
        t = _vec3("target", target)
        u = _vec3("up", up)
        fwd = t - e
        d = np.linalg.norm(fwd)
        if d == 0:
            raise ConfigError("target", "must differ from eye")
        fwd = fwd / d
        right = np.cross(fwd, u)
        n = np.linalg.norm(right)
        if n < 1e-9 * max(np.linalg.norm(u), 1e-300):
            raise ConfigError("up", f"must not be parallel to the viewing direction, got {up!r}")
        right = right / n
        true_up = np.cross(right, fwd)
        if not (isinstance(fov_deg, (int, float)) and math.isfinite(fov_deg) and 0 < fov_deg < 180):
            raise ConfigError("fov_deg", f"must be in (0, 180) degrees, got {fov_deg!r}")
        if ortho_half_height is not None and not (isinstance(ortho_half_height, (int, float))
                                                  and math.isfinite(ortho_half_height) and ortho_half_height > 0):
            raise ConfigError("ortho_half_height", f"must be a finite length > 0 cm or None, got {ortho_half_height!r}")
        if not (isinstance(near, (int, float)) and math.isfinite(near) and near > 0):
            raise ConfigError("near", f"must be a finite distance > 0 cm, got {near!r}")
        ro = []
        for a in (e, right, true_up, fwd):
            a = a.copy()
            a.flags.writeable = False
            ro.append(a)
        return cls(*ro, fov_deg=float(fov_deg),
                   ortho_half_height=None if ortho_half_height is None else float(ortho_half_height),
                   near=float(near))

    @property
    def orthographic(self) -> bool:
        return self.ortho_half_height is not None

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) world points (cm) → (N, 3) camera-frame coordinates (x right, y up, z depth), cm."""
        p = np.asarray(points, dtype=float) - self.eye
        return np.stack([p @ self.right, p @ self.up, p @ self.forward], axis=-1)

    def scale(self, height: int) -> float:
        """Focal length f (px) of a perspective camera, or px per cm of an orthographic one, at this image height."""
        if self.orthographic:
            return 0.5 * height / self.ortho_half_height
        return 0.5 * height / math.tan(math.radians(self.fov_deg) / 2.0)

    def project_camera(self, pc: np.ndarray, width: int, height: int) -> np.ndarray:
        """Camera-frame points (..., 3), cm → pixel coordinates (..., 2) (module docstring).

        Points with depth ≤ 0 under a perspective camera give non-finite or mirrored
        coordinates; clip them first (the renderer does)."""
        s = self.scale(height)
        x, y, z = pc[..., 0], pc[..., 1], pc[..., 2]
        if not self.orthographic:
            with np.errstate(divide="ignore", invalid="ignore"):
                x = x / z
                y = y / z
        return np.stack([0.5 * width + s * x, 0.5 * height - s * y], axis=-1)

    def project(self, points: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """Project world points for an image of ``width`` × ``height`` pixels.

        Parameters
        ----------
        points
            (N, 3) world positions, cm.
        width, height
            image size, px.

        Returns
        -------
        pixels: (N, 2) float64 ``(px, py)``, px to the right, py down (module docstring).
        depth: (N,) float64 distance along the viewing direction, cm (> 0 in front of the eye).
        """
        width, height = check_size(width, height)
        p = np.asarray(points, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ConfigError("points", f"must have shape (N, 3), got {p.shape}")
        pc = self.to_camera(p)
        return self.project_camera(pc, width, height), pc[:, 2].copy()
