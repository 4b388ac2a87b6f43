"""The one place where numba flags are set.

``cache=True`` keeps compiled kernels on disk so a second process pays no
compile time. numba keys a cached kernel on its own source file only, so an
edit to a kernel it calls in another module would leave a stale kernel in the
cache; hence the cache lives in a directory named after a hash of every
kernel source of the package (``~/.cache/cloth_gym/numba/<hash>``, or under
``$XDG_CACHE_HOME``; a ``NUMBA_CACHE_DIR`` set by the user wins). ``make
clean-cache`` removes it. ``error_model="numpy"`` turns a
division by zero into inf/NaN (caught by the divergence check) instead of an
exception inside a kernel; ``fastmath`` stays off so results are reproducible
and finite-difference tests are meaningful.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parents[1]


def _kernel_sources_hash() -> str:
    h = hashlib.sha1()
    for p in sorted([*_PACKAGE.glob("sim/**/*.py"), *_PACKAGE.glob("render/*.py"), _PACKAGE / "metrics.py"]):
        if p.is_file():
            h.update(p.name.encode())
            h.update(p.read_bytes())
    return h.hexdigest()[:16]


def cache_dir() -> Path:
    """Where compiled kernels are cached (see the module docstring)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"])
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "cloth_gym" / "numba" / _kernel_sources_hash()


_CACHE_DIR = cache_dir()
if not os.environ.get("NUMBA_CACHE_DIR"):
    os.environ["NUMBA_CACHE_DIR"] = str(_CACHE_DIR)  # for numba's config, read at its import

import numba  # noqa: E402

numba.config.CACHE_DIR = str(_CACHE_DIR)  # numba may already be imported (its config read then)

NJIT_FLAGS = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


def njit(fn=None, **overrides):
    """``numba.njit`` with the project's flags (usable bare or with overrides)."""
    flags = {**NJIT_FLAGS, **overrides}
    if fn is None:
        return lambda f: numba.njit(**flags)(f)
    return numba.njit(**flags)(fn)
