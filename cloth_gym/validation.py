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

__all__ = ["real", "integer", "flag", "one_of", "is_one_of", "real_array", "vector", "seed", "is_file", "read_yaml",
           "TYPE_FLAVOURS"]

#: the TypeError flavour of each ConfigError class a check may be asked to raise
TYPE_FLAVOURS: dict[type, type] = {ConfigError: ConfigTypeError, MaterialError: MaterialTypeError}


def _type_error(error: type) -> type:
    return TYPE_FLAVOURS.get(error, error)


def _interval(lo: float, hi: float, lo_open: bool, hi_open: bool) -> str:
    if lo == -math.inf and hi == math.inf:
        return ""
    return f" in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"


def _is_real(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def real(field: str, value: Any, lo: float = -math.inf, hi: float = math.inf, *, lo_open: bool = False,
         hi_open: bool = False, unit: str = "", error: type = ConfigError) -> float:
    """``value`` as a finite float in the interval from ``lo`` to ``hi`` (closed unless ``*_open``).

    Accepts Python and NumPy reals (not ``bool``, not strings, not complex); ``unit`` is named in
    the message (``"s"``, ``"cm"``)."""
    if not _is_real(value):
        raise _type_error(error)(field, f"must be a real number{_allowed(lo, hi, lo_open, hi_open, unit)}, got "
                                        f"{value!r} ({type(value).__name__})")
    try:
        v = float(value)
    except OverflowError:  # a Python int beyond the float range
        raise error(field, f"must be a finite number{_allowed(lo, hi, lo_open, hi_open, unit)}, got an integer of "
                           f"{len(str(value))} digits") from None
    if not math.isfinite(v) or v < lo or v > hi or (lo_open and v == lo) or (hi_open and v == hi):
        raise error(field, f"must be a finite number{_allowed(lo, hi, lo_open, hi_open, unit)}, got {v!r}")
    return v


def _allowed(lo: float, hi: float, lo_open: bool, hi_open: bool, unit: str) -> str:
    """What :func:`real` allows, for its message (written only when a check fails)."""
    return _interval(lo, hi, lo_open, hi_open) + (f" {unit}" if unit else "")


def _wanted(shape: tuple | None, unit: str) -> str:
    """What :func:`real_array` wants, for its message (written only when a check fails)."""
    return ("real numbers" if shape is None else f"real numbers of shape {shape}") + (f" ({unit})" if unit else "")


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
    """``value`` if it is one of ``allowed`` (compared by ``==``; an array or an unhashable value is
    none of them)."""
    if not is_one_of(value, allowed):
        raise error(field, f"must be one of {list(allowed)}, got {value!r}")
    return value


def is_one_of(value: Any, allowed: Collection) -> bool:
    """Whether ``value`` is one of ``allowed`` (``==``, with arrays and unhashable values never)."""
    if isinstance(value, np.ndarray):
        return False
    try:
        return bool(value in allowed)
    except (TypeError, ValueError):  # unhashable in a set, or an ambiguous comparison
        return False


def real_array(field: str, value: Any, shape: tuple | None = None, *, unit: str = "", limit: float = math.inf,
               error: type = ConfigError) -> np.ndarray:
    """``value`` as a new float64 array of real numbers (any real dtype, or nested lists of real
    numbers; not strings, complex, bool or ragged), of ``shape`` when given (−1: any length), finite
    and within ±``limit``."""
    if isinstance(value, (str, bytes, dict)) or value is None:
        raise _type_error(error)(field, f"must be {_wanted(shape, unit)}, got {value!r}")
    try:
        raw = np.asarray(value)
        if raw.dtype.kind not in "iuf" and not (raw.dtype.kind == "O" and all(_is_real(v) for v in raw.flat)):
            raise TypeError
        a = np.array(raw, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise _type_error(error)(field, f"must be {_wanted(shape, unit)}, got {value!r}") from None
    if shape is not None and (a.ndim != len(shape) or any(s not in (-1, d) for s, d in zip(shape, a.shape))):
        raise error(field, f"must be {_wanted(shape, unit)}, got shape {a.shape}")
    # |a| ≤ a finite limit is false for NaN and ±inf: one check then does both
    if not (bool((np.abs(a) <= limit).all()) if limit < math.inf else bool(np.isfinite(a).all())):
        bound = f" of magnitude at most {limit:g}" if limit < math.inf else ""
        raise error(field, f"must be finite{bound}{' (' + unit + ')' if unit else ''}, got {value!r}")
    return a


def vector(field: str, value: Any, n: int = 3, *, unit: str = "", limit: float = math.inf,
           error: type = ConfigError) -> np.ndarray:
    """``value`` as a float array of ``n`` finite real numbers (a new array)."""
    return real_array(field, value, (n,), unit=unit, limit=limit, error=error)


def seed(field: str, value: Any) -> "int | None":
    """A random seed: None or an integer >= 0 (any size, as NumPy's ``SeedSequence`` takes)."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ConfigTypeError(field, f"must be None or an integer >= 0, got {value!r} ({type(value).__name__})")
    if value < 0:
        raise ConfigError(field, f"must be None or an integer >= 0, got {value!r}")
    return int(value)


def is_file(path: Any) -> bool:
    """``Path(path).is_file()``, False for a path the system cannot even look up (too long, NUL)."""
    try:
        return Path(path).is_file()
    except (OSError, ValueError):
        return False


def _no_duplicate_keys(node, path, error: type, where: str = "") -> None:
    """Raise ``error`` at the first mapping of the composed YAML ``node`` that holds a key twice."""
    import yaml

    if isinstance(node, yaml.MappingNode):
        seen: dict = {}
        for key, value in node.value:
            name = key.value if isinstance(key, yaml.ScalarNode) else repr(key.value)
            dotted = f"{where}.{name}" if where else str(name)
            if name in seen:
                raise error(dotted, f"duplicate key in {path}: at line {key.start_mark.line + 1}, first given "
                            f"at line {seen[name] + 1} (YAML would keep the last silently)")
            seen[name] = key.start_mark.line
            _no_duplicate_keys(value, path, error, dotted)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _no_duplicate_keys(item, path, error, f"{where}[{i}]")


def read_yaml(path: "str | Path", field: str, *, error: type = ConfigError) -> Any:
    """The contents of a YAML file; a syntax error becomes ``error`` naming the file and the line,
    and a key given twice in one mapping (YAML would keep the last silently) ``error`` naming the
    key's dotted path, the file and both lines."""
    import yaml

    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
        _no_duplicate_keys(yaml.compose(text, Loader=yaml.SafeLoader), path, error)
        return yaml.safe_load(text)
    except RecursionError:
        raise error(field, f"{path} is nested too deeply to read") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise error(field, f"{path} is not valid YAML{where}: {problem}") from None
    except UnicodeDecodeError as err:
        raise error(field, f"{path} is not a UTF-8 text file: {err.reason}") from None
    except OSError as err:
        raise error(field, f"cannot read {path}: {err.strerror or err}") from None
