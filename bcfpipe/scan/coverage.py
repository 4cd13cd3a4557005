"""Which texels the scene reads (issue #18, item 4): the bound meshes' uv triangles rasterised
into a coverage mask per texture set, with a mip chain dilated by the filter footprint.

- Level 0 (the texture set's reference size W x H): a texel is covered when its centre lies in a
  uv triangle, or a triangle's vertex falls in it (slivers thinner than a texel still count); the
  result is dilated by one texel, the reach of a bilinear tap.
- Level k + 1: a texel is covered when any of its 2 x 2 children is, dilated by one texel again.
- Texel (i, j) of a w-texel level has its centre at ((i + 0.5) / w, (j + 0.5) / h) in bcfpipe's
  uv, whose v = 0 is the first stored row: USD's st maps to (s, 1 - t). Repeat addressing wraps
  triangles that leave [0, 1]; clamp clips them to the edge texels.

Training draws its texel-centre samples from covered texels only (the same as weighting the loss
by the mask), and quality is also reported over covered texels.
"""
from __future__ import annotations

import base64

import numpy as np
import xxhash

__all__ = ["rasterize", "mask_mips", "pack", "unpack", "digest"]


def _edge(ax, ay, bx, by, px, py):
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


def rasterize(tris: np.ndarray, width: int, height: int, wrap: str = "repeat") -> np.ndarray:
    """(height, width) bool mask of texels covered by ``tris`` (T, 3, 2) in USD st coordinates."""
    mask = np.zeros((height, width), bool)
    if len(tris) == 0:
        return mask
    x = tris[..., 0] * width - 0.5  # texel-centre space: centre of texel i is at i
    y = (1.0 - tris[..., 1]) * height - 0.5
    for (ax, bx, cx), (ay, by, cy) in zip(x, y):
        x0, x1 = int(np.floor(min(ax, bx, cx))), int(np.ceil(max(ax, bx, cx)))
        y0, y1 = int(np.floor(min(ay, by, cy))), int(np.ceil(max(ay, by, cy)))
        if wrap != "repeat":
            x0, x1, y0, y1 = max(x0, 0), min(x1, width - 1), max(y0, 0), min(y1, height - 1)
            if x0 > x1 or y0 > y1:
                continue
        if (x1 - x0 + 1) * (y1 - y0 + 1) > 4 * width * height:  # wraps many times: everything
            mask[:] = True
            return mask
        px, py = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1))
        area = _edge(ax, ay, bx, by, cx, cy)
        if area == 0:
            inside = np.zeros(px.shape, bool)
        else:
            s = np.sign(area)
            inside = ((s * _edge(ax, ay, bx, by, px, py) >= 0) & (s * _edge(bx, by, cx, cy, px, py) >= 0)
                      & (s * _edge(cx, cy, ax, ay, px, py) >= 0))
        for vx, vy in ((ax, ay), (bx, by), (cx, cy)):  # the texels the vertices fall in
            inside |= (px == int(np.floor(vx + 0.5))) & (py == int(np.floor(vy + 0.5)))
        if wrap == "repeat":
            mask[np.mod(py[inside], height), np.mod(px[inside], width)] = True
        else:
            mask[py[inside], px[inside]] = True
    return mask


def _dilate(m: np.ndarray, wrap: str) -> np.ndarray:
    """3 x 3 dilation (wrapping for repeat)."""
    if wrap == "repeat":
        out = m.copy()
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                out |= np.roll(m, (dy, dx), (0, 1))
        return out
    p = np.pad(m, 1)
    out = np.zeros_like(m)
    for dy in range(3):
        for dx in range(3):
            out |= p[dy:dy + m.shape[0], dx:dx + m.shape[1]]
    return out


def mask_mips(level0: np.ndarray, n_levels: int, wrap: str = "repeat") -> list[np.ndarray]:
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
