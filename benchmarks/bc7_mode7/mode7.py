"""BC7 mode 7: two subsets (one of 64 shapes), RGBA, 5-bit endpoints with one p-bit each, 2-bit indices.

Block layout (Khronos Data Format 1.3, §"BC7", Table "Mode 7"; D3D11 "BC7 Format Mode Reference"),
bit 0 first::

    bits   0-7   mode, 0b10000000 (seven zeros, then a one)
    bits   8-13  partition (shape) p, :data:`bcfpipe.bptc.PARTITIONS2`
    bits  14-93  R0 R1 R2 R3 G0 .. G3 B0 .. B3 A0 .. A3, 5 bits each
    bits  94-97  P0 P1 P2 P3, one per endpoint
    bits  98-127 indices, texel 0 first: 2 bits each, except 1 bit for the two anchors
                 (texel 0 and ANCHOR2[p]), whose top bit is implicitly 0

Endpoints 0 and 1 belong to subset 0, endpoints 2 and 3 to subset 1. Channel j of endpoint k is
the 6-bit value v = (c << 1) | P_k, widened to 8 bits as (v << 2) | (v >> 4). A texel of subset s
reads ((64 - w) e_{2s} + w e_{2s+1} + 32) >> 6 with w = WEIGHTS2[index], as UNORM8 (value / 255).

Parameters are carried as ``endpoints`` uint8 (n, 4, 4), the widened 8-bit values, ``indices``
uint8 (n, 16) in [0, 3], and ``partition`` (n,) in [0, 63].
"""
from __future__ import annotations

import numpy as np

from bcfpipe.bptc import ANCHOR2, PARTITIONS2

MODE_BITS = 0b10000000
#: BC7 2-bit interpolation weights in 64ths (Khronos Data Format, BC7 "aWeight2").
WEIGHTS2 = np.array([0, 21, 43, 64], np.int32)


def _index_offsets() -> tuple[np.ndarray, np.ndarray]:
    """Per shape, each texel's index bit offset from bit 98 and its width (1 at an anchor)."""
    width = np.full((64, 16), 2, np.int64)
    width[:, 0] = 1
    width[np.arange(64), ANCHOR2] = 1
    offset = np.concatenate([np.zeros((64, 1), np.int64), np.cumsum(width, 1)[:, :-1]], 1)
    return offset, width


_OFFSET, _WIDTH = _index_offsets()


def widen(v6: np.ndarray) -> np.ndarray:
    """6-bit endpoint values -> the 8-bit values the decoder interpolates."""
    v = np.asarray(v6).astype(np.int32)
    return ((v << 2) | (v >> 4)).astype(np.uint8)


def is_mode7(blocks: np.ndarray) -> np.ndarray:
    """Per block, whether its mode field says mode 7 (byte 0 is exactly 0x80 in its mode bits)."""
    b0 = np.asarray(blocks, np.uint8).reshape(-1, 16)[:, 0]
    return b0 == MODE_BITS


def _bits(blocks: np.ndarray) -> np.ndarray:
    return np.unpackbits(np.ascontiguousarray(blocks, np.uint8).reshape(-1, 16), axis=1, bitorder="little")


def _field(bits: np.ndarray, start: int, width: int) -> np.ndarray:
    return (bits[:, start:start + width].astype(np.int64) << np.arange(width)).sum(1)


def unpack(blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, 16) uint8 mode-7 blocks -> (endpoints (n, 4, 4) uint8, indices (n, 16) uint8, partition (n,) int64)."""
    bits = _bits(blocks)
    n = bits.shape[0]
    part = _field(bits, 8, 6)
    c5 = np.stack([_field(bits, 14 + 5 * f, 5) for f in range(16)], 1).reshape(n, 4, 4).transpose(0, 2, 1)
    p = np.stack([bits[:, 94 + k] for k in range(4)], 1).astype(np.int64)
    endpoints = widen((c5 << 1) | p[:, :, None])
    off, wid = _OFFSET[part] + 98, _WIDTH[part]
    rows = np.arange(n)[:, None]
    lo = bits[rows, off].astype(np.int64)
    hi = np.where(wid == 2, bits[rows, np.minimum(off + 1, 127)], 0).astype(np.int64)
    return endpoints, (lo | (hi << 1)).astype(np.uint8), part


def anchor_fix(endpoints: np.ndarray, indices: np.ndarray, partition: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per subset whose anchor has an index >= 2, swap its endpoints and invert its indices
    (3 - i), so that the anchor's top bit is 0; the decoded texels are unchanged."""
    e = np.array(endpoints, np.uint8).reshape(-1, 4, 4)
    idx = np.array(indices, np.uint8).reshape(-1, 16)
    part = np.asarray(partition, np.int64).reshape(-1)
    subset = PARTITIONS2[part]
    rows = np.arange(len(part))
    for s, anchor in ((0, np.zeros_like(part)), (1, ANCHOR2[part].astype(np.int64))):
        flip = idx[rows, anchor] >= 2
        e[flip, 2 * s:2 * s + 2] = e[flip, 2 * s:2 * s + 2][:, ::-1]
        texels = flip[:, None] & (subset == s)
        idx = np.where(texels, 3 - idx, idx).astype(np.uint8)
    return e, idx


def pack(endpoints: np.ndarray, indices: np.ndarray, partition: np.ndarray) -> np.ndarray:
    """Inverse of :func:`unpack` after :func:`anchor_fix` -> (n, 16) uint8. Raises ValueError for
    an endpoint off the widened 6-bit grid, channels that do not share one p-bit, an index out of
    range or a shape outside [0, 63]."""
    e = np.asarray(endpoints, np.uint8).reshape(-1, 4, 4)
    idx = np.asarray(indices, np.uint8).reshape(-1, 16)
    part = np.asarray(partition, np.int64).reshape(-1)
    if not (e.shape[0] == idx.shape[0] == part.shape[0]):
        raise ValueError(f"{e.shape[0]} endpoint sets, {idx.shape[0]} index sets, {part.shape[0]} shapes")
    if (idx > 3).any():
        raise ValueError("mode-7 indices are 2 bits")
    if ((part < 0) | (part > 63)).any():
        raise ValueError("mode-7 shapes are 0..63")
    v6 = (e >> 2).astype(np.int64)
    if (widen(v6) != e).any():
        raise ValueError("a mode-7 endpoint value must be a widened 6-bit value, (v << 2) | (v >> 4)")
    p = v6 & 1
    if (p != p[:, :, :1]).any():
        raise ValueError("the four channels of a mode-7 endpoint share one p-bit")
    e, idx = anchor_fix(e, idx, part)
    v6 = (e >> 2).astype(np.int64)
    n = len(part)
    bits = np.zeros((n, 128), np.uint8)

    def put(start: int, width: int, value: np.ndarray) -> None:
        bits[:, start:start + width] = (value[:, None] >> np.arange(width)) & 1

    put(0, 8, np.full(n, MODE_BITS, np.int64))
    put(8, 6, part)
    c5 = (v6 >> 1).transpose(0, 2, 1).reshape(n, 16)  # R0..R3 G0..G3 ...
    for f in range(16):
        put(14 + 5 * f, 5, c5[:, f])
    for k in range(4):
        bits[:, 94 + k] = v6[:, k, 0] & 1
    off, wid = _OFFSET[part] + 98, _WIDTH[part]
    rows = np.arange(n)[:, None]
    bits[rows, off] = idx & 1
    two = wid == 2
    bits[np.broadcast_to(rows, off.shape)[two], (off + 1)[two]] = (idx >> 1)[two]
    return np.packbits(bits, axis=1, bitorder="little")


def interpolate(endpoints: np.ndarray, indices: np.ndarray, partition: np.ndarray) -> np.ndarray:
    """Texel values (n, 16, 4) uint8 of mode-7 parameters."""
    e = endpoints.astype(np.int32).reshape(-1, 2, 2, 4)
    s = PARTITIONS2[np.asarray(partition, np.int64)].astype(np.int64)  # (n, 16)
    rows = np.arange(len(s))[:, None]
    ea, eb = e[rows, s, 0], e[rows, s, 1]  # (n, 16, 4)
    w = WEIGHTS2[indices.astype(np.int64)][:, :, None]
    return (((64 - w) * ea + w * eb + 32) >> 6).astype(np.uint8)
