"""Bit-exact BC7 decoder for mode-6 blocks (vectorized numpy), the format bcfpipe writes.

Follows the BPTC decoding of the Khronos Data Format specification (§"BC7"): mode from the lowest
set bit of byte 0, then :mod:`bcfpipe.bc7.mode6`'s field layout and interpolation. A block of any
other mode is refused with ValueError naming it: bcfpipe's feature textures hold mode 6 only, and
a file with other modes was not written by it.
"""
from __future__ import annotations

import numpy as np

from . import mode6

__all__ = ["decode", "decode_to_u8"]


def decode_to_u8(blocks: np.ndarray) -> np.ndarray:
    """(n, 16) uint8 blocks -> (n, 16, 4) uint8 texels (row-major within each block)."""
    b = np.asarray(blocks, np.uint8).reshape(-1, 16)
    bad = ~mode6.is_mode6(b)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        b0 = int(b[k, 0])
        mode = (b0 & -b0).bit_length() - 1 if b0 else None
        what = f"mode {mode}" if mode is not None and mode < 8 else "the reserved mode 8"
        raise ValueError(f"BC7 block {k} uses {what}; bcfpipe's BC7 feature textures hold mode 6 only "
                         f"({int(bad.sum())} such block(s))")
    return mode6.interpolate(*mode6.unpack(b))


def decode(blocks: np.ndarray, width: int, height: int) -> np.ndarray:
    """Row-major blocks of a ``width`` x ``height`` image -> float32 (height, width, 4) in [0, 1]."""
    bw, bh = -(-width // 4), -(-height // 4)
    b = np.asarray(blocks, np.uint8).reshape(-1, 16)
    if b.shape[0] != bw * bh:
        raise ValueError(f"a {width}x{height} image needs {bw * bh} blocks, got {b.shape[0]}")
    texels = decode_to_u8(b).reshape(bh, bw, 4, 4, 4).transpose(0, 2, 1, 3, 4).reshape(bh * 4, bw * 4, 4)
    return texels[:height, :width].astype(np.float32) / np.float32(255.0)
