"""BC7 mode 6: one subset, RGBA, 7-bit endpoints with one p-bit each, 4-bit indices.

Block layout (Khronos Data Format 1.3, §"BC7", Table "Mode 6"; D3D11 "BC7 Format Mode Reference"),
bit 0 first::

    bits   0-6   mode, 0b1000000 (six zeros, then a one)
    bits   7-62  R0 R1 G0 G1 B0 B1 A0 A1, 7 bits each
    bit   63     P0        bit 64  P1
    bits  65-67  index of texel 0 (its implicit top bit is 0: the anchor)
    bits  68-127 indices of texels 1..15, 4 bits each, texel i at bit 64 + 4 i

Endpoint channel j of endpoint k is the 8-bit value (c << 1) | P_k; the p-bit is shared by the
four channels of one endpoint. Texel value = ((64 - w) e0 + w e1 + 32) >> 6 with w = WEIGHTS4[index],
read as UNORM8 (value / 255).

Parameters are carried as ``endpoints`` uint8 (n, 2, 4), the 8-bit endpoint values (each
endpoint's four low bits equal, its p-bit), and ``indices`` uint8 (n, 16) in [0, 15].
"""
from __future__ import annotations

import numpy as np

from bcfpipe.bptc import WEIGHTS

MODE_BITS = 0b1000000
#: The mode's name in material.json (like bcfpipe.bc6h.mode10.DESCRIPTION).
DESCRIPTION = "BC7 mode 6 (one subset, RGBA, 7-bit endpoints + p-bit, 4-bit indices)"
#: BC7 4-bit interpolation weights in 64ths (Khronos Data Format, BC7 "aWeight4"); the same table
#: as BC6H's 4-bit weights.
WEIGHTS4 = WEIGHTS[4]  # 4-bit indices' weights in 64ths (`bcfpipe.bptc`)


def _words(blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    b = np.ascontiguousarray(blocks, np.uint8).reshape(-1, 16)
    w = b.view("<u8")
    return w[:, 0], w[:, 1]


def is_mode6(blocks: np.ndarray) -> np.ndarray:
    """Per block, whether its mode field says mode 6 (lowest set bit of byte 0 is bit 6)."""
    b0 = np.asarray(blocks, np.uint8).reshape(-1, 16)[:, 0]
    return (b0 & 0x7F) == MODE_BITS


def unpack(blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, 16) uint8 mode-6 blocks -> (endpoints (n, 2, 4) uint8, indices (n, 16) uint8)."""
    lo, hi = _words(blocks)
    n = lo.shape[0]
    c7 = np.stack([(lo >> np.uint64(7 + 7 * f)) & np.uint64(0x7F) for f in range(8)], 1)  # R0 R1 G0 ... A1
    c7 = c7.reshape(n, 4, 2).transpose(0, 2, 1)  # (n, endpoint, channel)
    p = np.stack([lo >> np.uint64(63), hi & np.uint64(1)], 1)
    endpoints = ((c7 << np.uint64(1)) | p[:, :, None]).astype(np.uint8)
    shifts = np.array([1] + [4 * i for i in range(1, 16)], np.uint64)
    masks = np.array([7] + [15] * 15, np.uint64)
    indices = ((hi[:, None] >> shifts) & masks).astype(np.uint8)
    return endpoints, indices


def anchor_fix(endpoints: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Swap the endpoints and invert every index of blocks whose texel 0 has an index >= 8, so
    that the anchor's top bit is 0 (the decoded texels are unchanged)."""
    flip = indices[:, 0] >= 8
    e = np.where(flip[:, None, None], endpoints[:, ::-1], endpoints)
    i = np.where(flip[:, None], 15 - indices, indices)
    return e.astype(np.uint8), i.astype(np.uint8)


def pack(endpoints: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Inverse of :func:`unpack` after :func:`anchor_fix` -> (n, 16) uint8. Raises ValueError for
    an endpoint whose channels do not share one p-bit, or an index out of range."""
    e = np.asarray(endpoints, np.uint8).reshape(-1, 2, 4)
    idx = np.asarray(indices, np.uint8).reshape(-1, 16)
    if e.shape[0] != idx.shape[0]:
        raise ValueError(f"{e.shape[0]} endpoint pairs for {idx.shape[0]} index sets")
    p = e & 1
    if (p != p[:, :, :1]).any():
        raise ValueError("the four channels of a mode-6 endpoint share one p-bit (low bit)")
    if (idx > 15).any():
        raise ValueError("mode-6 indices are 4 bits")
    e, idx = anchor_fix(e, idx)
    c7 = (e >> 1).astype(np.uint64).transpose(0, 2, 1).reshape(-1, 8)  # R0 R1 G0 G1 ...
    lo = np.full(e.shape[0], MODE_BITS, np.uint64)
    for f in range(8):
        lo |= c7[:, f] << np.uint64(7 + 7 * f)
    lo |= (e[:, 0, 0] & 1).astype(np.uint64) << np.uint64(63)
    hi = (e[:, 1, 0] & 1).astype(np.uint64)
    hi |= idx[:, 0].astype(np.uint64) << np.uint64(1)
    for i in range(1, 16):
        hi |= idx[:, i].astype(np.uint64) << np.uint64(4 * i)
    return np.stack([lo, hi], 1).astype("<u8").view(np.uint8).reshape(-1, 16)


def interpolate(endpoints: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Texel values (n, 16, 4) uint8: ((64 - w) e0 + w e1 + 32) >> 6."""
    e = endpoints.astype(np.int32)
    w = WEIGHTS4[indices.astype(np.int64)][:, :, None]
    return (((64 - w) * e[:, None, 0] + w * e[:, None, 1] + 32) >> 6).astype(np.uint8)
