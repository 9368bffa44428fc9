"""The checks of arguments that the API and the loops share: an integer, a number in a range, a flag, a
path. Each refuses with one :class:`~projreg.errors.ProjregError` line naming the argument; numpy's
integer and floating types count as integers and numbers, a bool as neither."""

from __future__ import annotations

import math
import numbers
import os
from pathlib import Path

import numpy as np

from .errors import ProjregError


def is_int(value: object) -> bool:
    """Whether ``value`` is an integer (numpy's included), not a bool."""
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def check_number(name: str, value: object, low: float, high: float, *, low_open: bool = False) -> float:
    """``value`` as a float if it is a real number (not a bool) in ``[low, high]`` (``(low, high]`` with
    ``low_open``), else one line naming ``name``; NaN and infinities are outside every range."""
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
    if ok and (low < value if low_open else low <= value) and value <= high:
        return float(value)
    span = f"{'(' if low_open else '['}{low:g}, {high:g}]"
    raise ProjregError(f"{name}: expected a number in {span}, got {value!r}")


def check_flag(name: str, value: object) -> bool:
    """``value`` if it is True or False (numpy's included), else one line naming ``name``: a string such as
    ``"no"`` is truthy, None falsy, and neither is a setting."""
    if not isinstance(value, bool | np.bool_):
        raise ProjregError(f"{name}: expected True or False, got {value!r}")
    return bool(value)


def check_path(name: str, value: object) -> Path:
    """``value`` as a :class:`~pathlib.Path` if it is a non-empty ``str`` or ``os.PathLike``, else one line
    naming ``name`` (an empty one would be read as the current folder)."""
    text = os.fspath(value) if isinstance(value, str | os.PathLike) else None
    if not isinstance(text, str):
        raise ProjregError(f"{name}: expected a path (str or os.PathLike), got {type(value).__name__}")
    if not text.strip():
        raise ProjregError(f"{name}: empty; give a path")
    return Path(text)
