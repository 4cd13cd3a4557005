"""BC7's two-subset partition shapes and their anchors (Khronos Data Format 1.3, §"BC7",
Table "Partition table for 2 subsets" and Table "Anchor index values for the second subset of
two-subset partitioning"; D3D11 "BC7 Format", the same tables). Texel ``i`` is row-major within
its 4x4 block; shape ``p``'s texel ``i`` belongs to subset 1 when bit ``i`` of ``_MASKS2[p]`` is set.

The first 32 shapes are BC6H's (:data:`bcfpipe.bc6h.tables.PARTITIONS2`); tests check that, and
every shape and anchor against an independent decoder.
"""
from __future__ import annotations

import numpy as np

__all__ = ["PARTITIONS2", "ANCHOR2"]

_MASKS2 = (
    0xCCCC, 0x8888, 0xEEEE, 0xECC8, 0xC880, 0xFEEC, 0xFEC8, 0xEC80,
    0xC800, 0xFFEC, 0xFE80, 0xE800, 0xFFE8, 0xFF00, 0xFFF0, 0xF000,
    0xF710, 0x008E, 0x7100, 0x08CE, 0x008C, 0x7310, 0x3100, 0x8CCE,
    0x088C, 0x3110, 0x6666, 0x366C, 0x17E8, 0x0FF0, 0x718E, 0x399C,
    0xAAAA, 0xF0F0, 0x5A5A, 0x33CC, 0x3C3C, 0x55AA, 0x9696, 0xA55A,
    0x73CE, 0x13C8, 0x324C, 0x3BDC, 0x6996, 0xC33C, 0x9966, 0x0660,
    0x0272, 0x04E4, 0x4E40, 0x2720, 0xC936, 0x936C, 0x39C6, 0x639C,
    0x9336, 0x9CC6, 0x817E, 0xE718, 0xCCF0, 0x0FCC, 0x7744, 0xEE22,
)

#: Subset (0/1) of each texel for the 64 two-subset shapes, (64, 16) uint8.
PARTITIONS2: np.ndarray = ((np.array(_MASKS2, np.uint32)[:, None] >> np.arange(16, dtype=np.uint32)) & 1).astype(np.uint8)
PARTITIONS2.setflags(write=False)

#: The texel of subset 1 whose index is stored with one bit less (subset 0's is texel 0).
ANCHOR2: np.ndarray = np.array([
    15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15, 15,
    15, 2, 8, 2, 2, 8, 8, 15, 2, 8, 2, 2, 8, 8, 2, 2,
    15, 15, 6, 8, 2, 8, 15, 15, 2, 8, 2, 2, 2, 15, 15, 6,
    6, 2, 6, 8, 15, 15, 2, 2, 15, 15, 15, 15, 15, 2, 2, 15,
], np.uint8)
ANCHOR2.setflags(write=False)
