"""Tangent-space normals as a renderer reads them (issue 57): z rebuilt from x and y, the slopes
(x / z, y / z) a layout's classic normal stores, what a UsdPreviewSurface sees (scale * t + bias,
normalised) and the angular error between two normal maps.

A set holds a normal's x and y as v in [-1, 1] (bcfpipe.texset.texture_set); engines rebuild z as
sqrt(max(0, 1 - x² - y²)). A UsdUVTexture cannot rebuild z: it gives scale * t + bias per slot, and
UsdPreviewSurface normalises what it reads. So a classic normal that USD reads carries z in its
ratio: BC5 of the slopes s = (x / z, y / z) / m, read as (s_x, s_y, 1), whose direction is (x, y, z).
One m per texture (a UsdUVTexture has one scale and bias): the `SLOPE_QUANTILE` of |s| at level 0,
so that a few near-horizontal texels (s up to 1000 on the brick) do not flatten the rest.
"""
from __future__ import annotations

import numpy as np

__all__ = ["rebuild_z", "stored_xyz", "slope_scale", "slope_texels", "slope_normal", "usd_normal", "unit",
           "angular_error_deg", "angular_stats", "SLOPE_QUANTILE", "SLOPE_FLOOR"]

SLOPE_QUANTILE = 0.999  # m: this quantile of |x / z|, |y / z| at level 0 (1.0 breaks on the brick: m = 1000)
SLOPE_FLOOR = 1.0 / 64.0  # the least m: a flat map keeps a finite scale
_MIN_Z = 1e-3  # z below this (a horizontal normal) counts as this when divided by


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


def _slopes(xy: np.ndarray) -> np.ndarray:
    """(…, 2) set values -> (…, 2) slopes (x / z, y / z) of the normal with z rebuilt."""
    n = rebuild_z(xy)
    return n[..., :2] / np.maximum(n[..., 2:3], _MIN_Z)


def slope_scale(xy: np.ndarray) -> float:
    """m of a slope normal texture: the `SLOPE_QUANTILE` of |x / z| and |y / z| over ``xy`` (its
    level 0's set values), at least `SLOPE_FLOOR`."""
    return max(float(np.quantile(np.abs(_slopes(xy)), SLOPE_QUANTILE)), SLOPE_FLOOR)


def slope_texels(xy: np.ndarray, m: float) -> np.ndarray:
    """(…, 2) set values -> (…, 2) stored texels in [0, 1]: clip(s / m, -1, 1) / 2 + 1 / 2 of the
    slopes s = (x / z, y / z), z rebuilt (what a layout's BC5 normal holds)."""
    return np.clip(_slopes(xy) / m, -1.0, 1.0) * 0.5 + 0.5


def slope_normal(texels: np.ndarray, m: float) -> np.ndarray:
    """(…, ≥2) decoded slope texels -> the unit normal (s_x, s_y, 1) normalised, s = (2t - 1) m:
    what a UsdPreviewSurface shades with and what bcfpipe's decoder gives."""
    s = (np.asarray(texels, np.float32)[..., :2] * 2.0 - 1.0) * np.float32(m)
    return unit(np.concatenate([s, np.ones_like(s[..., :1])], -1))


def unit(v: np.ndarray) -> np.ndarray:
    """(…, 3) vectors normalised; a zero vector becomes (0, 0, 1)."""
    v = np.asarray(v, np.float32)
    n2 = np.einsum("...i,...i->...", v, v, dtype=np.float64)  # the length in float64, without a float64 copy
    ok = n2 > 1e-24
    out = v * np.where(ok, 1.0 / np.sqrt(np.maximum(n2, 1e-24)), 0.0).astype(np.float32)[..., None]
    out[..., 2] = np.where(ok, out[..., 2], 1.0)
    return out


def usd_normal(texels: np.ndarray, scale=(2.0, 2.0, 2.0), bias=(-1.0, -1.0, -1.0)) -> np.ndarray:
    """(…, ≥3) decoded texels -> the unit normal a UsdPreviewSurface shades with: the UsdUVTexture's
    ``scale * t + bias`` on r, g, b, normalised (Storm normalises the tangent-space normal). A
    two-channel texture (BC5) reads 0 in b, as Storm and OpenImageIO read one."""
    t = np.asarray(texels, np.float32)[..., :3]
    if t.shape[-1] < 3:
        t = np.concatenate([t, np.zeros(t.shape[:-1] + (3 - t.shape[-1],), np.float32)], -1)
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
