"""Trilinear filtering of decoded textures in numpy, with the hardware conventions
`bcfpipe.model.sampling` implements in torch for training (OpenGL 4.5 §8.14, D3D11 3.5.8): texel
centres at (i + 0.5) / w, bilinear within a level, linear between the two nearest levels, lod
clamped to the levels (below 0: level 0 magnified), addressing per axis (`addressing.address`) after
the decoder's range reduction (`addressing.reduce_coord`).

The exported files' classic textures are read through this, so that measuring a classic layout
needs no torch; the operations are torch's, in the same order and in float32, so both give the
same bits (tests/test_filtering.py)."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from bcfpipe.formats.addressing import address, reduce_coord
from bcfpipe.formats.vocabulary import wrap_axes


def bilinear(tex: np.ndarray, uv: np.ndarray, wrap) -> np.ndarray:
    """One level ``tex`` (H, W, C) sampled at ``uv`` (N, 2) float32 -> (N, C)."""
    h, w = tex.shape[:2]
    ws, wt = wrap_axes(wrap)
    x = reduce_coord(uv[:, 0], ws) * w - 0.5
    y = reduce_coord(uv[:, 1], wt) * h - 0.5
    x0f, y0f = np.floor(x), np.floor(y)
    fx, fy = (x - x0f)[:, None], (y - y0f)[:, None]
    x0, y0 = x0f.astype(np.int64), y0f.astype(np.int64)
    xa, xb = address(x0, w, ws), address(x0 + 1, w, ws)
    ya, yb = address(y0, h, wt), address(y0 + 1, h, wt)
    flat = tex.reshape(h * w, -1)
    if not fx.any() and not fy.any():  # the level's own texel centres: each sample is its texel, the same bits
        return flat[ya * w + xa]
    t00, t01, t10, t11 = flat[ya * w + xa], flat[ya * w + xb], flat[yb * w + xa], flat[yb * w + xb]
    top = t00 + (t01 - t00) * fx
    bot = t10 + (t11 - t10) * fx
    return top + (bot - top) * fy


def whole_level(levels: Sequence[np.ndarray], lod: float, height: int, width: int) -> np.ndarray | None:
    """What `trilinear` gives at every texel centre of an (``height``, ``width``) image, row-major,
    when that is a level's texels as they are: the one level ``lod`` reads (clamped to the levels, no
    blend) has that shape and power-of-two sides, so each centre's uv and coordinate are exact in
    float32 and `bilinear` reads its own texel. Then (H*W, C), a view where the level allows; else
    None. A whole mip decoded so makes no uv (`bcfpipe.export.writer.decode_mips`)."""
    n = len(levels)
    l = min(max(float(lod), 0.0), n - 1)
    lo = int(l)
    if l != lo:
        return None
    level = levels[lo]
    h, w = level.shape[:2]
    if (h, w) != (height, width) or h & (h - 1) or w & (w - 1) or max(h, w) > 1 << 23:
        return None
    return level.reshape(h * w, -1)


def trilinear(levels: Sequence[np.ndarray], uv: np.ndarray, lod: float, wrap) -> np.ndarray:
    """A mip chain ``levels`` [(H_k, W_k, C)] sampled at ``uv`` (N, 2) float32 and one ``lod`` for
    every point -> (N, C)."""
    n = len(levels)
    l = min(max(float(lod), 0.0), n - 1)
    lo = min(int(l), n - 1)
    hi, t = min(lo + 1, n - 1), l - lo
    a = bilinear(levels[lo], uv, wrap)
    if hi != lo and t > 0:
        a = a + (bilinear(levels[hi], uv, wrap) - a) * t
    return a
