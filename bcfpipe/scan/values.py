"""Attribute values read defensively. A layer can declare an attribute with a type name that USD
does not know (it opens, with a warning, and the value reads as ``Sdf.UnregisteredValue``) or
with the wrong type or arity. Readers treat such a value as missing, as a renderer would, and
never fail on it."""
from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["is_unregistered", "numbers", "number"]


def is_unregistered(value: Any) -> bool:
    """Whether ``value`` is what USD returns for a type name it does not know."""
    from pxr import Sdf  # lazy: start-up

    return isinstance(value, Sdf.UnregisteredValue)


def numbers(value: Any, dtype=np.float64, width: int | None = None) -> np.ndarray:
    """``value`` (a Vt array, a sequence, or None) as a flat array, or ``(n, width)`` rows; empty
    when it is missing, unregistered, not numeric, a scalar, or does not split into rows."""
    empty = np.zeros((0, width) if width else 0, dtype)
    if value is None or is_unregistered(value):
        return empty
    try:
        a = np.asarray(value, dtype)
    except (TypeError, ValueError, OverflowError):
        return empty
    if a.ndim == 0 or (width and a.size % width):
        return empty
    return a.reshape(-1, width) if width else a.reshape(-1)


def number(value: Any, default: float) -> float:
    """``value`` as a finite float, else ``default``."""
    try:
        f = float(value)
    except (TypeError, ValueError, OverflowError):
        return default
    return f if np.isfinite(f) else default
