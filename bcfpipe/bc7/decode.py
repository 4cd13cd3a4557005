"""Bit-exact BC7 decoder (vectorized numpy) of every mode: bcfpipe's trained feature levels are
mode 6, and a T_0 that holds the set's principal components is encoded in any mode by ISPC
(:mod:`bcfpipe.bc7.anymode`, issue 29).

Follows the BPTC decoding of the Khronos Data Format specification (§"BC7"): mode from the lowest
set bit of byte 0, then that mode's field layout and interpolation; the reserved mode 8 decodes to
zero, as D3D11 and Mesa do.
"""
from __future__ import annotations

import numpy as np

from . import anymode

__all__ = ["decode", "decode_to_u8"]


def decode_to_u8(blocks: np.ndarray) -> np.ndarray:
    """(n, 16) uint8 blocks -> (n, 16, 4) uint8 texels (row-major within each block)."""
    return anymode.decode_to_u8(blocks)


def decode(blocks: np.ndarray, width: int, height: int) -> np.ndarray:
    """Row-major blocks of a ``width`` x ``height`` image -> float32 (height, width, 4) in [0, 1]."""
    bw, bh = -(-width // 4), -(-height // 4)
    b = np.asarray(blocks, np.uint8).reshape(-1, 16)
    if b.shape[0] != bw * bh:
        raise ValueError(f"a {width}x{height} image needs {bw * bh} blocks, got {b.shape[0]}")
    texels = decode_to_u8(b).reshape(bh, bw, 4, 4, 4).transpose(0, 2, 1, 3, 4).reshape(bh * 4, bw * 4, 4)
    return texels[:height, :width].astype(np.float32) / np.float32(255.0)
