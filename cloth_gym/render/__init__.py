"""Headless software rendering of cloth scenes (numba z-buffer, no display, no GPU) and image/video output."""

from .camera import Camera
from .io import save_gif, save_mp4, save_png
from .renderer import Renderer, colormap

__all__ = ["Camera", "Renderer", "colormap", "save_png", "save_gif", "save_mp4"]
