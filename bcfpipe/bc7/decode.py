"""Bit-exact BC7 decoder for modes 6 and 7 (vectorized numpy): bcfpipe's feature textures are mode 6,
and mode 7 is issue 29's measured alternative (:mod:`bcfpipe.bc7.modes`).

Follows the BPTC decoding of the Khronos Data Format specification (§"BC7"): mode from the lowest
set bit of byte 0, then :mod:`bcfpipe.bc7.mode6`'s or :mod:`bcfpipe.bc7.mode7`'s field layout and
interpolation. A block of any other mode is refused with ValueError naming it: such a file was not
written by bcfpipe.
"""
from __future__ import annotations

import numpy as np

from . import modes

__all__ = ["decode", "decode_to_u8"]


def decode_to_u8(blocks: np.ndarray) -> np.ndarray:
    """(n, 16) uint8 blocks -> (n, 16, 4) uint8 texels (row-major within each block)."""
    return modes.interpolate(*modes.unpack(blocks))


def decode(blocks: np.ndarray, width: int, height: int) -> np.ndarray:
    """Row-major blocks of a ``width`` x ``height`` image -> float32 (height, width, 4) in [0, 1]."""
    bw, bh = -(-width // 4), -(-height // 4)
    b = np.asarray(blocks, np.uint8).reshape(-1, 16)
    if b.shape[0] != bw * bh:
        raise ValueError(f"a {width}x{height} image needs {bw * bh} blocks, got {b.shape[0]}")
    texels = decode_to_u8(b).reshape(bh, bw, 4, 4, 4).transpose(0, 2, 1, 3, 4).reshape(bh * 4, bw * 4, 4)
    return texels[:height, :width].astype(np.float32) / np.float32(255.0)
