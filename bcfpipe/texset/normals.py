"""Tangent-space normals as a renderer reads them (issue 57): z rebuilt from x and y, the stored
form of a classic normal texture that keeps z (BC7 x, y, z), what a UsdPreviewSurface sees
(the texel's 2t - 1, normalised) and the angular error between two normal maps.

A set holds a normal's x and y as v in [-1, 1] (bcfpipe.texset.texture_set); engines rebuild z as
sqrt(max(0, 1 - x² - y²)). A UsdUVTexture cannot rebuild z: it gives scale * t + bias per slot, and
UsdPreviewSurface normalises what it reads. So a classic normal that USD reads stores z too.
"""
from __future__ import annotations

import numpy as np

__all__ = ["rebuild_z", "stored_xyz", "usd_normal", "unit", "angular_error_deg", "angular_stats"]


def rebuild_z(xy: np.ndarray) -> np.ndarray:
    """(…, 2) x, y in [-1, 1] -> (…, 3) x, y, z with z = sqrt(max(0, 1 - x² - y²)), as engines
    rebuild a BC5 normal (and bcfpipe's decoder does)."""
    xy = np.asarray(xy, np.float32)
    z = np.sqrt(np.maximum(0.0, 1.0 - xy[..., 0] ** 2 - xy[..., 1] ** 2))
    return np.concatenate([xy, z[..., None]], -1)


def stored_xyz(xy: np.ndarray) -> np.ndarray:
    """(…, 2) set values -> (…, 3) stored texels in [0, 1]: (n + 1) / 2 of the rebuilt unit-ish normal,
    what a BC7 normal texture holds in r, g, b."""
    return (rebuild_z(xy) + 1.0) * 0.5


def unit(v: np.ndarray) -> np.ndarray:
    """(…, 3) vectors normalised; a zero vector becomes (0, 0, 1)."""
    v = np.asarray(v, np.float32)
    n = np.sqrt(np.sum(v.astype(np.float64) ** 2, -1, keepdims=True))
    out = np.where(n > 1e-12, v / np.maximum(n, 1e-12), 0.0).astype(np.float32)
    out[..., 2] = np.where(n[..., 0] > 1e-12, out[..., 2], 1.0)
    return out


def usd_normal(texels: np.ndarray, scale=(2.0, 2.0, 2.0), bias=(-1.0, -1.0, -1.0)) -> np.ndarray:
    """(…, ≥3) decoded texels -> the unit normal a UsdPreviewSurface shades with: the UsdUVTexture's
    ``scale * t + bias`` on r, g, b, normalised (Storm normalises the tangent-space normal)."""
    t = np.asarray(texels, np.float32)[..., :3]
    return unit(t * np.asarray(scale, np.float32) + np.asarray(bias, np.float32))


def angular_error_deg(ref: np.ndarray, dec: np.ndarray) -> np.ndarray:
    """Per-texel angle in degrees between two (…, 3) normal maps (each normalised first)."""
    d = np.sum(unit(ref).astype(np.float64) * unit(dec), -1)
    return np.degrees(np.arccos(np.clip(d, -1.0, 1.0)))


def angular_stats(ref: np.ndarray, dec: np.ndarray, mask: np.ndarray | None = None) -> tuple[float, float]:
    """(mean, p99) angular error in degrees between ``ref`` and ``dec`` (over ``mask``'s texels if given)."""
    a = angular_error_deg(ref, dec)
    if mask is not None:
        a = a[np.asarray(mask, bool)]
    if a.size == 0:
        return 0.0, 0.0
    return float(np.mean(a)), float(np.percentile(a, 99))
