"""The BPTC tables BC6H and BC7 share (Khronos Data Format 1.3, §"BPTC": BC7 and BC6H; D3D11 "BC7
Format" and "BC6H Format", the same tables), kept once: the partition shapes of two and three
subsets, their anchor texels, and the interpolation weights of 2-, 3- and 4-bit indices. BC6H reads
the first 32 two-subset shapes and the 3- and 4-bit weights. Texel ``i`` is row-major within its
4x4 block: ``i = 4 y + x``. Tests check every shape and anchor against independent decoders
(texture2ddecoder, Mesa's BPTC through OpenGL).
"""
from __future__ import annotations

import numpy as np

__all__ = ["PARTITIONS2", "ANCHOR2", "PARTITIONS3", "ANCHOR3", "WEIGHTS"]

# Two-subset shapes (Table "Partition table for 2 subsets"): shape p's texel i belongs to subset 1
# when bit i of _MASKS2[p] is set.
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

# Three-subset shapes (Khronos Data Format 1.3, §"BC7", Table "Partition table for 3 subsets"):
# texel i of shape p belongs to subset int(_SHAPES3[p][i]), row-major within the block.
_SHAPES3 = (
    "0011001102212222", "0001001122112221", "0000200122112211", "0222002200110111",
    "0000000011221122", "0011001100220022", "0022002211111111", "0011001122112211",
    "0000000011112222", "0000111111112222", "0000111122222222", "0012001200120012",
    "0112011201120112", "0122012201220122", "0011011211221222", "0011200122002220",
    "0001001101121122", "0111001120012200", "0000112211221122", "0022002200221111",
    "0111011102220222", "0001000122212221", "0000001101220122", "0000110022102210",
    "0122012200110000", "0012001211222222", "0110122112210110", "0000011012211221",
    "0022110211020022", "0110011020022222", "0011012201220011", "0000200022112221",
    "0000000211221222", "0222002200120011", "0011001200220222", "0120012001200120",
    "0000111122220000", "0120120120120120", "0120201212010120", "0011220011220011",
    "0011112222000011", "0101010122222222", "0000000021212121", "0022112200221122",
    "0022001100220011", "0220122102201221", "0101222222220101", "0000212121212121",
    "0101010101012222", "0222011102220111", "0002111200021112", "0000211221122112",
    "0222011101110222", "0002111211120002", "0110011001102222", "0000000021122112",
    "0110011022222222", "0022001100110022", "0022112211220022", "0000000000002112",
    "0002000100020001", "0222122202221222", "0101222222222222", "0111201122012220",
)

#: Subset (0/1/2) of each texel for the 64 three-subset shapes, (64, 16) uint8.
PARTITIONS3: np.ndarray = np.array([[int(c) for c in s] for s in _SHAPES3], np.uint8)
PARTITIONS3.setflags(write=False)

#: The texels of subsets 1 and 2 whose indices are stored with one bit less (Tables "Anchor index
#: values for the second subset of three-subset partitioning" and "... third subset ..."), (64, 2).
ANCHOR3: np.ndarray = np.array([
    (3, 15), (3, 8), (15, 8), (15, 3), (8, 15), (3, 15), (15, 3), (15, 8),
    (8, 15), (8, 15), (6, 15), (6, 15), (6, 15), (5, 15), (3, 15), (3, 8),
    (3, 15), (3, 8), (8, 15), (15, 3), (3, 15), (3, 8), (6, 15), (10, 8),
    (5, 3), (8, 15), (8, 6), (6, 10), (8, 15), (5, 15), (15, 10), (15, 8),
    (8, 15), (15, 3), (3, 15), (5, 10), (6, 10), (10, 8), (8, 9), (15, 10),
    (15, 6), (3, 15), (15, 8), (5, 15), (15, 3), (15, 6), (15, 6), (15, 8),
    (3, 15), (15, 3), (5, 15), (5, 15), (5, 15), (8, 15), (5, 15), (10, 15),
    (5, 15), (10, 15), (8, 15), (13, 15), (15, 3), (12, 15), (3, 15), (3, 8),
], np.uint8)
ANCHOR3.setflags(write=False)


#: Interpolation weights in 64ths for 2-, 3- and 4-bit indices (Khronos "aWeight2/3/4"; D3D11
#: BC6H format, 'aWeight3', 'aWeight4'), read-only.
WEIGHTS: dict[int, np.ndarray] = {
    2: np.array([0, 21, 43, 64], np.int32),
    3: np.array([0, 9, 18, 27, 37, 46, 55, 64], np.int32),
    4: np.array([0, 4, 9, 13, 17, 21, 26, 30, 34, 38, 43, 47, 51, 55, 60, 64], np.int32),
}
for _w in WEIGHTS.values():
    _w.setflags(write=False)
