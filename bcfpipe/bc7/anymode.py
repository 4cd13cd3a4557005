"""BC7's mode table (every mode 0-7; 8 is reserved), which bcfpipe's decoder of every mode reads
(`bcfpipe.bc7.kernel`).

A T_0 that holds the texture set's principal components is encoded once by a full BC7 encoder
(Intel's ISPC, every mode; issue 29), so bcfpipe reads every mode a conforming encoder writes.
Each mode's fields follow the Khronos Data Format 1.3, §"BC7", Table "Mode-dependent BPTC
parameters" (the D3D11 "BC7 Format Mode Reference" is the same), bit 0 first:

    mode bits (m zeros, then a one) | partition (PB) | rotation (RB) | index selection (ISB) |
    endpoints R0 R1 .. G0 G1 .. B0 B1 .. (CB bits each), A0 A1 .. (AB bits each) |
    p-bits (one per endpoint: EPB, or one per subset: SPB) | primary indices (IB bits, one less at
    each subset's anchor texel) | secondary indices (IB2 bits, one less at texel 0)

An endpoint with a p-bit is (c << 1) | p; every endpoint widens to 8 bits by repeating its top bits.
A texel reads ((64 - w) e0 + w e1 + 32) >> 6 with w from the index's weight table; modes 4 and 5
interpolate colour and alpha with separate indices (swapped by ISB) and then swap alpha with one
colour channel (rotation). A block of the reserved mode 8 decodes to zero in every channel (what
D3D11, Mesa and texture2ddecoder do).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


__all__ = ["MODES", "block_modes"]


@dataclass(frozen=True)
class ModeSpec:
    """One row of the Khronos table: subsets, partition/rotation/index-selection bits, colour and
    alpha endpoint bits, endpoint/shared p-bits, primary and secondary index bits."""

    ns: int
    pb: int
    rb: int
    isb: int
    cb: int
    ab: int
    epb: int
    spb: int
    ib: int
    ib2: int


MODES: tuple[ModeSpec, ...] = (
    ModeSpec(3, 4, 0, 0, 4, 0, 1, 0, 3, 0),
    ModeSpec(2, 6, 0, 0, 6, 0, 0, 1, 3, 0),
    ModeSpec(3, 6, 0, 0, 5, 0, 0, 0, 2, 0),
    ModeSpec(2, 6, 0, 0, 7, 0, 1, 0, 2, 0),
    ModeSpec(1, 0, 2, 1, 5, 6, 0, 0, 2, 3),
    ModeSpec(1, 0, 2, 0, 7, 8, 0, 0, 2, 2),
    ModeSpec(1, 0, 0, 0, 7, 7, 1, 0, 4, 0),
    ModeSpec(2, 6, 0, 0, 5, 5, 1, 0, 2, 0),
)


def block_modes(blocks: np.ndarray) -> np.ndarray:
    """(n,) int: each block's mode, the index of the lowest set bit of byte 0 (8: reserved)."""
    b0 = np.asarray(blocks, np.uint8).reshape(-1, 16)[:, 0].astype(np.int32)
    low = b0 & -b0
    return np.where(b0 == 0, 8, np.log2(np.maximum(low, 1)).astype(np.int32))
