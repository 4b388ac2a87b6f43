"""The one place where numba flags are set.

``cache=True`` writes compiled kernels next to the sources (``__pycache__``)
so a second process pays no compile time; ``error_model="numpy"`` turns a
division by zero into inf/NaN (caught by the divergence check) instead of an
exception inside a kernel; ``fastmath`` stays off so results are reproducible
and finite-difference tests are meaningful.
"""

from __future__ import annotations

import numba

NJIT_FLAGS = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


def njit(fn=None, **overrides):
    """``numba.njit`` with the project's flags (usable bare or with overrides)."""
    flags = {**NJIT_FLAGS, **overrides}
    if fn is None:
        return lambda f: numba.njit(**flags)(f)
    return numba.njit(**flags)(fn)
