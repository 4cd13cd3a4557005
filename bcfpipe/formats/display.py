"""How sizes, byte counts and file names read in every command's text (scan, plan, build, render),
so that one texture set is described the same way everywhere."""
from __future__ import annotations

import re

_PACKAGED = re.compile(r"^(.*)\[([^\[\]]+)\]$")  # pkg.usdz[inner/a.png], as Ar resolves a packaged asset


def dims_text(width: int, height: int) -> str:
    """``1024²`` for a square set, ``2048×16`` otherwise."""
    return f"{width}²" if width == height else f"{width}×{height}"


def bytes_text(n: float) -> str:
    """A byte count that stays readable at any size: MiB from 1 MiB, KiB from 1 KiB (one decimal
    below 10 KiB), bytes below."""
    if n >= 2**20:
        return f"{n / 2**20:.2f} MiB"
    if n >= 10 * 2**10:
        return f"{n / 2**10:.0f} KiB"
    if n >= 2**10:
        return f"{n / 2**10:.1f} KiB"
    return f"{int(n)} B"


def bytes_range(low: float, high: float) -> str:
    """``lo–hi`` in the unit of ``high`` (one figure when they are equal), e.g. ``2.8–3.1 KiB``."""
    if round(low) == round(high):
        return bytes_text(high)
    unit = bytes_text(high).split()[-1]
    scale = {"MiB": 2**20, "KiB": 2**10, "B": 1}[unit]
    digits = 2 if unit == "MiB" else 1 if unit == "KiB" and high < 10 * 2**10 else 0
    return f"{low / scale:.{digits}f}–{high / scale:.{digits}f} {unit}"


def file_name(path: str) -> str:
    """The file's own name: for a packaged asset ``pkg.usdz[inner/a.png]`` that is ``a.png``."""
    m = _PACKAGED.match(path)
    inner = m.group(2) if m else path
    return inner.replace("\\", "/").rstrip("/").rsplit("/", 1)[-1]
