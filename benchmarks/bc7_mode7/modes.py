"""BC7 blocks of mode 6 (one subset, 4-bit indices) or mode 7 (two subsets of one of 64 shapes,
2-bit indices), the modes bcfpipe reads. Issue 29 measured the two together against mode 6 alone:
at one byte per texel they hold 2.1 and 2.6 dB more of the teapot's and the brick's principal
components at mip 1, but trained features gain nothing from them (docs/benchmarks.md, "Partitioned
BC7 modes, trained"), so ``--features bc7`` writes mode 6 alone.

Parameters of n blocks, one representation for both modes:

* ``endpoints`` uint8 (n, 4, 4): the 8-bit values the decoder interpolates; endpoints 0 and 1 are
  subset 0's, 2 and 3 subset 1's (zero and unused in a mode-6 block);
* ``indices`` uint8 (n, 16): 4-bit (mode 6) or 2-bit (mode 7);
* ``partition`` int64 (n,): the mode-7 shape, or -1 for a mode-6 block.
"""
from __future__ import annotations

import numpy as np

from bcfpipe.bc7 import mode6
from bcfpipe.bptc import PARTITIONS2

from . import mode7

__all__ = ["MODE6", "pack", "unpack", "interpolate", "subsets"]

MODE6 = -1


def subsets(partition: np.ndarray) -> np.ndarray:
    """(n, 16) uint8: each texel's subset (all 0 in a mode-6 block)."""
    p = np.asarray(partition, np.int64)
    return np.where((p >= 0)[:, None], PARTITIONS2[np.maximum(p, 0)], 0).astype(np.uint8)


def pack(endpoints: np.ndarray, indices: np.ndarray, partition: np.ndarray) -> np.ndarray:
    """(n, 16) uint8 blocks; see :func:`bcfpipe.bc7.mode6.pack` and :func:`bc7_mode7.mode7.pack`."""
    e = np.asarray(endpoints, np.uint8).reshape(-1, 4, 4)
    idx = np.asarray(indices, np.uint8).reshape(-1, 16)
    p = np.asarray(partition, np.int64).reshape(-1)
    out = np.empty((len(p), 16), np.uint8)
    six = p < 0
    if six.any():
        out[six] = mode6.pack(e[six, :2], idx[six])
    if (~six).any():
        out[~six] = mode7.pack(e[~six], idx[~six], p[~six])
    return out


def unpack(blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mode-6 and mode-7 blocks -> (endpoints, indices, partition); ValueError names any other mode."""
    b = np.asarray(blocks, np.uint8).reshape(-1, 16)
    six, seven = mode6.is_mode6(b), mode7.is_mode7(b)
    bad = ~(six | seven)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        b0 = int(b[k, 0])
        mode = (b0 & -b0).bit_length() - 1 if b0 else None
        what = f"mode {mode}" if mode is not None and mode < 8 else "the reserved mode 8"
        raise ValueError(f"BC7 block {k} uses {what}; bcfpipe reads BC7 modes 6 and 7 only (its feature textures are mode 6) "
                         f"({int(bad.sum())} such block(s))")
    n = len(b)
    e = np.zeros((n, 4, 4), np.uint8)
    idx = np.zeros((n, 16), np.uint8)
    part = np.full(n, MODE6, np.int64)
    if six.any():
        e[six, :2], idx[six] = mode6.unpack(b[six])
    if seven.any():
        e[seven], idx[seven], part[seven] = mode7.unpack(b[seven])
    return e, idx, part


def interpolate(endpoints: np.ndarray, indices: np.ndarray, partition: np.ndarray) -> np.ndarray:
    """Texel values (n, 16, 4) uint8."""
    e = np.asarray(endpoints, np.uint8).reshape(-1, 4, 4)
    idx = np.asarray(indices, np.uint8).reshape(-1, 16)
    p = np.asarray(partition, np.int64).reshape(-1)
    out = np.empty((len(p), 16, 4), np.uint8)
    six = p < 0
    if six.any():
        out[six] = mode6.interpolate(e[six, :2], idx[six])
    if (~six).any():
        out[~six] = mode7.interpolate(e[~six], idx[~six], p[~six])
    return out
