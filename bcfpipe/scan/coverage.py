"""Which texels the scene reads (issue #18, item 4): the bound meshes' uv triangles rasterised
into a coverage mask per texture set, with a mip chain dilated by the filter footprint.

- Level 0 (the texture set's reference size W x H): a texel is covered when its centre lies in a
  uv triangle, or a triangle's vertex falls in it (slivers thinner than a texel still count); the
  result is dilated by one texel, the reach of a bilinear tap.
- Level k + 1: a texel is covered when any of its 2 x 2 children is, dilated by one texel again.
- Texel (i, j) of a w-texel level has its centre at ((i + 0.5) / w, (j + 0.5) / h) in bcfpipe's
  uv, whose v = 0 is the first stored row: USD's st maps to (s, 1 - t). Per axis, repeat addressing
  wraps triangles that leave [0, 1], mirror reflects them, clamp clips them to the edge texels.

Training draws its texel-centre samples from covered texels only (the same as weighting the loss
by the mask), and quality is also reported over covered texels.
"""
from __future__ import annotations

import base64

import numpy as np
import xxhash

from bcfpipe.formats.vocabulary import Wrap, wrap_axes

__all__ = ["rasterize", "mask_mips", "pack", "unpack", "digest"]


def _spans(x: np.ndarray, y: np.ndarray, rows: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For texel-centre row ``rows[i]`` of triangle ``tri[i]``: the [lo, hi] x-range of the triangle
    on that row (lo > hi where the row misses it). Horizontal edges count with both ends."""
    lo = np.full(len(rows), np.inf)
    hi = np.full(len(rows), -np.inf)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        ax, ay, bx, by = x[tri, a], y[tri, a], x[tri, b], y[tri, b]
        hit = (np.minimum(ay, by) <= rows) & (rows <= np.maximum(ay, by))
        flat = ay == by
        with np.errstate(divide="ignore", invalid="ignore"):
            xi = np.where(flat, ax, ax + (rows - ay) * (bx - ax) / (by - ay))
        lo = np.where(hit, np.minimum(lo, np.where(flat, np.minimum(ax, bx), xi)), lo)
        hi = np.where(hit, np.maximum(hi, np.where(flat, np.maximum(ax, bx), xi)), hi)
    return lo, hi


def _fold(lo: np.ndarray, hi: np.ndarray, n: int, mode: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Spans [lo, hi] of texel indices along one axis of n texels as the texels they address:
    (the source span of each piece, lo, hi), every piece within [0, n). Repeat and mirror fold a
    span by its period (n, 2n; a mirrored piece runs backwards); clamp keeps what lies inside
    (past the edge, the dilation of `mask_mips` reaches the edge texel)."""
    idx = np.arange(len(lo))
    if mode == Wrap.CLAMP:
        ok = (hi >= 0) & (lo < n)
        return idx[ok], np.clip(lo[ok], 0, n - 1), np.clip(hi[ok], 0, n - 1)
    period = n if mode == Wrap.REPEAT else 2 * n
    full = hi - lo + 1 >= period
    shift = np.floor_divide(lo, period) * period
    lo, hi = lo - shift, hi - shift  # lo in [0, period), hi < 2 period
    pieces = [(idx[full], np.zeros(int(full.sum()), np.int64), np.full(int(full.sum()), n - 1, np.int64))]
    for k in range(2 * period // n):
        a, b = np.maximum(lo, k * n), np.minimum(hi, (k + 1) * n - 1)
        ok = ~full & (a <= b)
        a, b = a[ok] - k * n, b[ok] - k * n
        backwards = mode == Wrap.MIRROR and k % 2 == 1
        pieces.append((idx[ok], n - 1 - b if backwards else a, n - 1 - a if backwards else b))
    return tuple(np.concatenate(p) for p in zip(*pieces))


def rasterize(tris: np.ndarray, width: int, height: int, wrap=Wrap.REPEAT) -> np.ndarray:
    """(height, width) bool mask of texels covered by ``tris`` (T, 3, 2) in USD st coordinates: a
    texel whose centre lies in (or on the edge of) a triangle, or in which a triangle's vertex lies,
    with the addressing ``wrap`` (one mode, or (S, T): S across the width, T down the rows).
    Scanline fill: every (triangle, texel row) pair gives one span, accumulated per row."""
    wrap_s, wrap_t = wrap_axes(wrap)
    mask = np.zeros((height, width), bool)
    if len(tris) == 0:
        return mask
    x = tris[..., 0].astype(np.float64) * width - 0.5  # texel-centre space: the centre of texel i is at i
    y = (1.0 - tris[..., 1].astype(np.float64)) * height - 0.5
    y0, y1 = np.ceil(y.min(1)).astype(np.int64), np.floor(y.max(1)).astype(np.int64)
    n_rows = np.maximum(y1 - y0 + 1, 0)
    if (n_rows > 4 * height).any() or ((x.max(1) - x.min(1)) > 4 * width).any():  # wraps many times
        mask[:] = True
        return mask
    tri = np.repeat(np.arange(len(tris)), n_rows)
    rows = (y0[tri] + np.arange(len(tri)) - np.repeat(np.cumsum(n_rows) - n_rows, n_rows)).astype(np.int64)
    lo, hi = _spans(x, y, rows.astype(np.float64), tri)
    lo, hi = np.ceil(lo).astype(np.int64), np.floor(hi).astype(np.int64)
    keep = lo <= hi
    rows, lo, hi = rows[keep], lo[keep], hi[keep]
    # the texels the vertices lie in: one-texel spans
    vx, vy = np.floor(x + 0.5).astype(np.int64).ravel(), np.floor(y + 0.5).astype(np.int64).ravel()
    rows, lo, hi = np.concatenate([rows, vy]), np.concatenate([lo, vx]), np.concatenate([hi, vx])
    keep, rows, _ = _fold(rows, rows, height, wrap_t)
    keep, lo, hi = _fold(lo[keep], hi[keep], width, wrap_s)
    rows = rows[keep]
    diff = np.zeros((height, width + 1), np.int32)
    np.add.at(diff, (rows, lo), 1)
    np.add.at(diff, (rows, hi + 1), -1)
    mask |= np.cumsum(diff[:, :width], axis=1) > 0
    return mask


def _dilate(m: np.ndarray, wrap) -> np.ndarray:
    """3 x 3 dilation, wrapping along a repeat axis (a clamped or mirrored axis's texel past the
    edge is the edge texel itself, which adds nothing)."""
    wrap_s, wrap_t = wrap_axes(wrap)
    p = np.pad(m, ((1, 1), (0, 0)), mode="wrap" if wrap_t == Wrap.REPEAT else "constant")
    p = np.pad(p, ((0, 0), (1, 1)), mode="wrap" if wrap_s == Wrap.REPEAT else "constant")
    out = np.zeros_like(m)
    for dy in range(3):
        for dx in range(3):
            out |= p[dy:dy + m.shape[0], dx:dx + m.shape[1]]
    return out


def mask_mips(level0: np.ndarray, n_levels: int, wrap=Wrap.REPEAT) -> list[np.ndarray]:
    """The mask's chain: level 0 dilated by one texel, then 2 x 2 'any' reductions, each dilated."""
    levels = [_dilate(level0, wrap)]
    while len(levels) < n_levels:
        m = levels[-1]
        h, w = m.shape
        fy, fx = (2 if h > 1 else 1), (2 if w > 1 else 1)
        levels.append(_dilate(m.reshape(h // fy, fy, w // fx, fx).any(axis=(1, 3)), wrap))
    return levels


def pack(mask: np.ndarray) -> str:
    """A level-0 mask as text for a job (base64 of its packed bits; the shape travels with it)."""
    return base64.b64encode(np.packbits(mask, axis=None).tobytes()).decode()


def unpack(text: str, width: int, height: int) -> np.ndarray:
    bits = np.unpackbits(np.frombuffer(base64.b64decode(text), np.uint8), count=width * height)
    return bits.reshape(height, width).astype(bool)


def digest(mask: np.ndarray) -> str:
    return xxhash.xxh3_128_hexdigest(np.packbits(mask, axis=None).tobytes() + f"{mask.shape}".encode())


def job_coverage(models, size: tuple[int, int], wrap) -> tuple[str | None, float | None, str | None]:
    """(packed mask, covered fraction, digest) of the texels the members' meshes read, or Nones when
    a member has no uv triangles to rasterise or every texel is read."""
    w, h = size
    if w < 1 or h < 1:
        return None, None, None
    mask = np.zeros((h, w), bool)
    for mm in models:
        meshes = mm.density.meshes if mm.density is not None else ()
        if not meshes or mm.density.notes:
            return None, None, None
        for m in meshes:
            mask |= rasterize(m.uv_triangles, w, h, wrap)
    if mask.all():
        return None, None, None
    return pack(mask), float(mask_mips(mask, 1, wrap)[0].mean()), digest(mask)
