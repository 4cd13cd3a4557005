"""BC1, BC4 and BC5 decoders (issue 59: bcfpipe's own decoder for every BC format it ships).

Khronos Data Format 1.3, §"S3TC" (BC1: "BC1 with no alpha") and §"RGTC" (BC4 unsigned, BC5 as two
BC4 blocks); D3D "Block compression", the same formats. Each block is decoded whole, vectorized
over blocks. Interpolated values take the integer form that quicktex and texture2ddecoder (the
tests' oracles) both use, floor((w0 e0 + w1 e1) / n), on 8-bit endpoints; BC1's 5:6:5 endpoints are
widened by bit replication. Texel ``i`` of a block is row-major: ``i = 4 y + x``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["bc1_texels", "bc4_texels", "bc5_texels", "to_image"]


def _le(b: np.ndarray, start: int, count: int) -> np.ndarray:
    """Little-endian unsigned integers of ``count`` bytes from byte ``start`` of every block."""
    out = np.zeros(len(b), np.uint64)
    for i in range(count):
        out |= b[:, start + i].astype(np.uint64) << np.uint64(8 * i)
    return out


def _indices(bits: np.ndarray, width: int) -> np.ndarray:
    """(n, 16) texel indices of ``width`` bits each, texel 0 in the lowest bits."""
    shifts = np.uint64(width) * np.arange(16, dtype=np.uint64)
    return ((bits[:, None] >> shifts) & np.uint64((1 << width) - 1)).astype(np.int64)


def _rgb565(c: np.ndarray) -> np.ndarray:
    """5:6:5 colours -> (n, 3) 8-bit, bit-replicated (S3TC: "RGB565 ... expanded")."""
    r, g, b = (c >> 11) & 31, (c >> 5) & 63, c & 31
    return np.stack([(r << 3) | (r >> 2), (g << 2) | (g >> 4), (b << 3) | (b >> 2)], -1)


def bc1_texels(blocks: np.ndarray) -> np.ndarray:
    """(n, 8) BC1 blocks -> (n, 16, 3) uint8 RGB. c0 > c1: four colours, 2/3 and 1/3 between the
    endpoints; else three, the midpoint and black (its transparent texel is read as black RGB)."""
    b = np.ascontiguousarray(np.asarray(blocks, np.uint8).reshape(-1, 8))
    n = len(b)
    ends = b[:, :4].copy().view("<u2").astype(np.int32)  # c0, c1 (little-endian 5:6:5)
    c0, c1 = ends[:, 0], ends[:, 1]
    e0, e1 = _rgb565(c0), _rgb565(c1)
    four = (c0 > c1)[:, None]
    palette = np.stack([e0, e1, np.where(four, (2 * e0 + e1) // 3, (e0 + e1) // 2),
                        np.where(four, (e0 + 2 * e1) // 3, 0)], 1).astype(np.uint8)
    bits = b[:, 4:].copy().view("<u4")[:, 0]
    sel = (bits[:, None] >> (2 * np.arange(16, dtype=np.uint32))) & 3  # texel i's 2 bits at 2 i
    return palette.reshape(-1, 3)[sel.astype(np.intp) + 4 * np.arange(n, dtype=np.intp)[:, None]]


def bc4_texels(blocks: np.ndarray) -> np.ndarray:
    """(n, 8) BC4 (unsigned) blocks -> (n, 16) uint8. a0 > a1: eight values, six between; else six,
    four between, then 0 and 255."""
    b = np.asarray(blocks, np.uint8).reshape(-1, 8)
    a0, a1 = b[:, :1].astype(np.int32), b[:, 1:2].astype(np.int32)
    k = np.arange(1, 7)
    eight = np.concatenate([a0, a1, ((7 - k) * a0 + k * a1) // 7], 1)
    six = np.concatenate([a0, a1, ((5 - k[:4]) * a0 + k[:4] * a1) // 5, 0 * a0, 0 * a0 + 255], 1)
    palette = np.where(a0 > a1, eight, six)
    return np.take_along_axis(palette, _indices(_le(b, 2, 6), 3), 1).astype(np.uint8)


def bc5_texels(blocks: np.ndarray) -> np.ndarray:
    """(n, 16) BC5 (unsigned) blocks -> (n, 16, 2) uint8: a BC4 block for red, then one for green."""
    b = np.asarray(blocks, np.uint8).reshape(-1, 16)
    return np.stack([bc4_texels(b[:, :8]), bc4_texels(b[:, 8:])], -1)


def to_image(texels: np.ndarray, width: int, height: int) -> np.ndarray:
    """(n, 16[, c]) texels of row-major blocks -> (height, width[, c]), the padding cropped."""
    bw, bh = -(-width // 4), -(-height // 4)
    if texels.shape[0] != bw * bh:
        raise ValueError(f"a {width}x{height} image needs {bw * bh} blocks, got {texels.shape[0]}")
    c = texels.shape[2:]
    img = texels.reshape(bh, bw, 4, 4, *c).swapaxes(1, 2).reshape(bh * 4, bw * 4, *c)
    return img[:height, :width]
