"""Write rendered images and animations: PNG, GIF, MP4 (imageio; MP4 through ``imageio-ffmpeg``).

Every writer creates the parent directories of ``path`` and returns ``path`` as
a :class:`pathlib.Path`. Images are ``(H, W, 3)`` uint8 RGB (``(H, W)`` grey is
also accepted); the frames of an animation all have the same shape.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import ConfigError

__all__ = ["save_png", "save_gif", "save_mp4"]


def _image(name: str, img) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype != np.uint8:
        raise ConfigError(name, f"must be uint8, got {a.dtype}")
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)) or a.shape[0] == 0 or a.shape[1] == 0:
        raise ConfigError(name, f"must have shape (H, W, 3) or (H, W), got {a.shape}")
    return np.ascontiguousarray(a)


def _frames(frames) -> list[np.ndarray]:
    if isinstance(frames, np.ndarray) and frames.ndim in (3, 4):
        frames = list(frames)
    out = [_image(f"frames[{i}]", f) for i, f in enumerate(frames)]
    if not out:
        raise ConfigError("frames", "must hold at least one frame")
    for i, f in enumerate(out):
        if f.shape != out[0].shape:
            raise ConfigError(f"frames[{i}]", f"shape {f.shape} differs from frames[0] {out[0].shape}")
    return out


def _fps(fps) -> float:
    if isinstance(fps, bool) or not (isinstance(fps, (int, float)) and math.isfinite(fps) and 0 < fps <= 1000):
        raise ConfigError("fps", f"must be in (0, 1000] frames per second, got {fps!r}")
    return float(fps)


def _path(path) -> Path:
    p = Path(os.fspath(path))
    p.parent.mkdir(parents=True, exist_ok=True)
    return p


def save_png(path, img) -> Path:
    """Write one (H, W, 3) uint8 image as PNG."""
    import imageio.v3 as iio

    a = _image("img", img)
    p = _path(path)
    iio.imwrite(p, a, extension=".png")
    return p


def save_gif(path, frames: Sequence[np.ndarray], fps: float = 20.0) -> Path:
    """Write frames as a looping GIF at ``fps`` frames per second.

    GIF stores frame durations in 1/100 s, so the rate is rounded to that; GIF
    has a 256-colour palette per frame. Pillow merges *identical consecutive*
    frames into one longer frame, so such a GIF reads back with fewer frames.
    """
    import imageio.v3 as iio

    fr = _frames(frames)
    rate = _fps(fps)
    p = _path(path)
    iio.imwrite(p, np.stack(fr), extension=".gif", plugin="pillow", duration=1000.0 / rate, loop=0)
    return p


def save_mp4(path, frames: Sequence[np.ndarray], fps: float = 30.0) -> Path:
    """Write frames as an H.264 MP4 (yuv420p, playable everywhere) at ``fps`` frames per second.

    yuv420p needs even sizes: a frame of odd width or height is padded by one
    pixel (its last column / row repeated). Lossy; needs the ``imageio-ffmpeg`` package.
    """
    import imageio.v2 as iio2

    fr = _frames(frames)
    rate = _fps(fps)
    p = _path(path)
    h, w = fr[0].shape[:2]
    pad = ((0, h % 2), (0, w % 2)) + (((0, 0),) if fr[0].ndim == 3 else ())
    with iio2.get_writer(p, format="FFMPEG", mode="I", fps=rate, codec="libx264", pixelformat="yuv420p",
                         macro_block_size=1, quality=8) as writer:
        for f in fr:
            writer.append_data(np.pad(f, pad, mode="edge") if (h % 2 or w % 2) else f)
    return p
