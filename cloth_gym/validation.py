"""Checks of user input, shared by every public entry point.

Each check returns the value in its canonical type or raises a
:class:`~cloth_gym.errors.ConfigError` that names the field, the value given and
what is allowed: the :class:`~cloth_gym.errors.ConfigTypeError` flavour (also a
``TypeError``) when the type is wrong, the plain one (a ``ValueError``) when the
value is out of range or not finite. ``error`` picks another ConfigError class
(materials raise :class:`~cloth_gym.errors.MaterialError`); its type flavour is
looked up in :data:`TYPE_FLAVOURS`.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ConfigError, ConfigTypeError, MaterialError, MaterialTypeError

__all__ = ["real", "integer", "flag", "one_of", "vector", "seed", "read_yaml", "TYPE_FLAVOURS"]

#: the TypeError flavour of each ConfigError class a check may be asked to raise
TYPE_FLAVOURS: dict[type, type] = {ConfigError: ConfigTypeError, MaterialError: MaterialTypeError}


def _type_error(error: type) -> type:
    return TYPE_FLAVOURS.get(error, error)


def _interval(lo: float, hi: float, lo_open: bool, hi_open: bool) -> str:
    return f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"


def real(field: str, value: Any, lo: float = -math.inf, hi: float = math.inf, *, lo_open: bool = False,
         hi_open: bool = False, unit: str = "", error: type = ConfigError) -> float:
    """``value`` as a finite float in the interval from ``lo`` to ``hi`` (closed unless ``*_open``).

    Accepts Python and NumPy reals (not ``bool``, not strings, not complex); ``unit`` is named in
    the message (``"s"``, ``"cm"``)."""
    allowed = _interval(lo, hi, lo_open, hi_open) + (f" {unit}" if unit else "")
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise _type_error(error)(field, f"must be a real number in {allowed}, got {value!r} ({type(value).__name__})")
    v = float(value)
    if not math.isfinite(v) or v < lo or v > hi or (lo_open and v == lo) or (hi_open and v == hi):
        raise error(field, f"must be a finite number in {allowed}, got {v!r}")
    return v


def integer(field: str, value: Any, lo: int, hi: int, *, error: type = ConfigError) -> int:
    """``value`` as an int in [lo, hi] (Python or NumPy integers, not ``bool``)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise _type_error(error)(field, f"must be an integer in [{lo}, {hi}], got {value!r} "
                                        f"({type(value).__name__})")
    if not lo <= int(value) <= hi:
        raise error(field, f"must be an integer in [{lo}, {hi}], got {int(value)}")
    return int(value)


def flag(field: str, value: Any, *, error: type = ConfigError) -> bool:
    """``value`` as a bool (only ``True``/``False``, NumPy's included)."""
    if not isinstance(value, (bool, np.bool_)):
        raise _type_error(error)(field, f"must be True or False, got {value!r} ({type(value).__name__})")
    return bool(value)


def one_of(field: str, value: Any, allowed: Collection, *, error: type = ConfigError):
    """``value`` if it is one of ``allowed`` (compared by ``==`` after a hashability check)."""
    try:
        ok = value in allowed
    except TypeError:  # an unhashable value asked of a set
        ok = False
    if not ok:
        raise error(field, f"must be one of {list(allowed)}, got {value!r}")
    return value


def vector(field: str, value: Any, n: int = 3, *, unit: str = "", error: type = ConfigError) -> np.ndarray:
    """``value`` as a float array of ``n`` finite numbers (a new array)."""
    u = f" ({unit})" if unit else ""
    if isinstance(value, (str, bytes, dict)):
        raise _type_error(error)(field, f"must be {n} finite numbers{u}, got {value!r}")
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise _type_error(error)(field, f"must be {n} finite numbers{u}, got {value!r}") from None
    if np.iscomplexobj(np.asarray(value)) or a.dtype == bool:
        raise _type_error(error)(field, f"must be {n} real numbers{u}, got {value!r}")
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise error(field, f"must be {n} finite numbers{u}, got {value!r}")
    return a


def seed(field: str, value: Any) -> "int | None":
    """A random seed: None or an integer >= 0 (any size, as NumPy's ``SeedSequence`` takes)."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ConfigTypeError(field, f"must be None or an integer >= 0, got {value!r} ({type(value).__name__})")
    if value < 0:
        raise ConfigError(field, f"must be None or an integer >= 0, got {value!r}")
    return int(value)


def read_yaml(path: "str | Path", field: str, *, error: type = ConfigError) -> Any:
    """The contents of a YAML file; a syntax error becomes ``error`` naming the file and the line."""
    import yaml

    try:
        with open(path, encoding="utf-8") as fh:
            return yaml.safe_load(fh)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise error(field, f"{path} is not valid YAML{where}: {problem}") from None
    except UnicodeDecodeError as err:
        raise error(field, f"{path} is not a UTF-8 text file: {err.reason}") from None
    except OSError as err:
        raise error(field, f"cannot read {path}: {err.strerror or err}") from None
