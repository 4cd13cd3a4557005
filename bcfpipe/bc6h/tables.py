"""Constant tables of the BC6H block format.

Every table cites the section of the Direct3D 11 "BC6H format" documentation
(learn.microsoft.com/windows/win32/direct3d11/bc6h-format) that it implements;
the BPTC chapter of the Khronos Data Format Specification describes the same
format.  Texel indices are row-major within a 4x4 block: ``index = 4*y + x``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bcfpipe import bptc

__all__ = [
    "PARTITIONS2",
    "ANCHOR2",
    "WEIGHTS3",
    "WEIGHTS4",
    "Mode",
    "MODES",
    "MODE_BY_VALUE",
    "RESERVED_MODE_VALUES",
]


#: Subset id (0/1) of each texel for the 32 BC6H two-region shapes, shape (32, 16): D3D11 BC6H
#: format, 'Partition set for 2 regions', the first 32 of BPTC's (`bcfpipe.bptc`).
PARTITIONS2: np.ndarray = bptc.PARTITIONS2[:32]

#: Anchor ("fix-up") texel of subset 1 per shape; subset 0's anchor is texel 0.
#: D3D11 BC6H/BC7 format, 'anchor index' table for two-subset shapes.
ANCHOR2: np.ndarray = bptc.ANCHOR2[:32]

#: Interpolation weights (out of 64) for 3- and 4-bit indices; D3D11 BC6H format, 'aWeight3', 'aWeight4'.
WEIGHTS3: np.ndarray = bptc.WEIGHTS[3]
WEIGHTS4: np.ndarray = bptc.WEIGHTS[4]


@dataclass(frozen=True)
class Mode:
    """One row of the D3D11 BC6H format table 'BC6H modes' (modes 1..14)."""

    number: int          #: the spec's mode number, 1..14
    value: int           #: mode field as an integer (bit i of the block = bit i of value)
    mode_bits: int       #: length of the mode field: 2 (modes 1, 2) or 5
    regions: int         #: 1 or 2
    transformed: bool    #: endpoints 1..3 stored as deltas from endpoint 0
    endpoint_bits: int   #: precision of endpoint 0 ("ep bits", same for R, G, B)
    delta_bits: tuple[int, int, int]  #: stored bits of the other endpoints per channel (R, G, B)

    @property
    def index_bits(self) -> int:
        """Bits per texel index: 3 for two-region modes, 4 for one-region ones."""
        return 3 if self.regions == 2 else 4

    @property
    def shape_bits(self) -> int:
        """Bits of the partition ("shape") field: 5 for two-region modes, else 0."""
        return 5 if self.regions == 2 else 0


#: The 14 valid BC6H modes; D3D11 BC6H format, table 'BC6H modes'.
#: For untransformed modes the "delta" bits equal the endpoint bits.
MODES: tuple[Mode, ...] = (
    Mode(1, 0b00, 2, 2, True, 10, (5, 5, 5)),
    Mode(2, 0b01, 2, 2, True, 7, (6, 6, 6)),
    Mode(3, 0b00010, 5, 2, True, 11, (5, 4, 4)),
    Mode(4, 0b00110, 5, 2, True, 11, (4, 5, 4)),
    Mode(5, 0b01010, 5, 2, True, 11, (4, 4, 5)),
    Mode(6, 0b01110, 5, 2, True, 9, (5, 5, 5)),
    Mode(7, 0b10010, 5, 2, True, 8, (6, 5, 5)),
    Mode(8, 0b10110, 5, 2, True, 8, (5, 6, 5)),
    Mode(9, 0b11010, 5, 2, True, 8, (5, 5, 6)),
    Mode(10, 0b11110, 5, 2, False, 6, (6, 6, 6)),
    Mode(11, 0b00011, 5, 1, False, 10, (10, 10, 10)),
    Mode(12, 0b00111, 5, 1, True, 11, (9, 9, 9)),
    Mode(13, 0b01011, 5, 1, True, 12, (8, 8, 8)),
    Mode(14, 0b01111, 5, 1, True, 16, (4, 4, 4)),
)

#: Mode lookup by the 5-bit value of the block's low bits (2-bit modes appear under
#: every 5-bit value whose low two bits are 00 or 01).
MODE_BY_VALUE: dict[int, Mode] = {}
for _m in MODES:
    if _m.mode_bits == 2:
        for _hi in range(8):
            MODE_BY_VALUE[_m.value | (_hi << 2)] = _m
    else:
        MODE_BY_VALUE[_m.value] = _m
del _m

#: Reserved 5-bit mode values; D3D11 BC6H format: such blocks decode to zero.
RESERVED_MODE_VALUES: tuple[int, ...] = (0b10011, 0b10111, 0b11011, 0b11111)


# ---------------------------------------------------------------------------
# Header bit layouts
# ---------------------------------------------------------------------------

#: Header layout of each mode, transcribed from the D3D11 BC6H format table
#: 'BC6H compressed endpoint format' (one row per mode, same notation).
#: Fields: m = mode, rw/gw/bw = endpoint 0 ("w"), rx.. = endpoint 1 ("x"),
#: ry.. = endpoint 2 ("y"), rz.. = endpoint 3 ("z"), d = shape.  A range
#: ``f[a:b]`` occupies consecutive block bits whose first (lowest) bit holds
#: f's bit ``b`` and whose last holds bit ``a``; so ``rw[9:0]`` is stored LSB
#: first, and the spec's ``rw[10:15]`` (modes 13/14) is stored MSB first.
#: The texel indices follow the header, from bit 82 (two-region modes) or 65.
LAYOUT_SPEC: dict[int, str] = {
    1: "m[1:0] gy[4] by[4] bz[4] rw[9:0] gw[9:0] bw[9:0] rx[4:0] gz[4] gy[3:0] gx[4:0] "
       "bz[0] gz[3:0] bx[4:0] bz[1] by[3:0] ry[4:0] bz[2] rz[4:0] bz[3] d[4:0]",
    2: "m[1:0] gy[5] gz[4] gz[5] rw[6:0] bz[0] bz[1] by[4] gw[6:0] by[5] bz[2] gy[4] bw[6:0] "
       "bz[3] bz[5] bz[4] rx[5:0] gy[3:0] gx[5:0] gz[3:0] bx[5:0] by[3:0] ry[5:0] rz[5:0] d[4:0]",
    3: "m[4:0] rw[9:0] gw[9:0] bw[9:0] rx[4:0] rw[10] gy[3:0] gx[3:0] gw[10] bz[0] gz[3:0] "
       "bx[3:0] bw[10] bz[1] by[3:0] ry[4:0] bz[2] rz[4:0] bz[3] d[4:0]",
    4: "m[4:0] rw[9:0] gw[9:0] bw[9:0] rx[3:0] rw[10] gz[4] gy[3:0] gx[4:0] gw[10] gz[3:0] "
       "bx[3:0] bw[10] bz[1] by[3:0] ry[3:0] bz[0] bz[2] rz[3:0] gy[4] bz[3] d[4:0]",
    5: "m[4:0] rw[9:0] gw[9:0] bw[9:0] rx[3:0] rw[10] by[4] gy[3:0] gx[3:0] gw[10] bz[0] "
       "gz[3:0] bx[4:0] bw[10] by[3:0] ry[3:0] bz[1] bz[2] rz[3:0] bz[4] bz[3] d[4:0]",
    6: "m[4:0] rw[8:0] by[4] gw[8:0] gy[4] bw[8:0] bz[4] rx[4:0] gz[4] gy[3:0] gx[4:0] "
       "bz[0] gz[3:0] bx[4:0] bz[1] by[3:0] ry[4:0] bz[2] rz[4:0] bz[3] d[4:0]",
    7: "m[4:0] rw[7:0] gz[4] by[4] gw[7:0] bz[2] gy[4] bw[7:0] bz[3] bz[4] rx[5:0] gy[3:0] "
       "gx[4:0] bz[0] gz[3:0] bx[4:0] bz[1] by[3:0] ry[5:0] rz[5:0] d[4:0]",
    8: "m[4:0] rw[7:0] bz[0] by[4] gw[7:0] gy[5] gy[4] bw[7:0] gz[5] bz[4] rx[4:0] gz[4] "
       "gy[3:0] gx[5:0] gz[3:0] bx[4:0] bz[1] by[3:0] ry[4:0] bz[2] rz[4:0] bz[3] d[4:0]",
    9: "m[4:0] rw[7:0] bz[1] by[4] gw[7:0] by[5] gy[4] bw[7:0] bz[5] bz[4] rx[4:0] gz[4] "
       "gy[3:0] gx[4:0] bz[0] gz[3:0] bx[5:0] by[3:0] ry[4:0] bz[2] rz[4:0] bz[3] d[4:0]",
    10: "m[4:0] rw[5:0] gz[4] bz[0] bz[1] by[4] gw[5:0] gy[5] by[5] bz[2] gy[4] bw[5:0] gz[5] "
        "bz[3] bz[5] bz[4] rx[5:0] gy[3:0] gx[5:0] gz[3:0] bx[5:0] by[3:0] ry[5:0] rz[5:0] d[4:0]",
    11: "m[4:0] rw[9:0] gw[9:0] bw[9:0] rx[9:0] gx[9:0] bx[9:0]",
    12: "m[4:0] rw[9:0] gw[9:0] bw[9:0] rx[8:0] rw[10] gx[8:0] gw[10] bx[8:0] bw[10]",
    13: "m[4:0] rw[9:0] gw[9:0] bw[9:0] rx[7:0] rw[10:11] gx[7:0] gw[10:11] bx[7:0] bw[10:11]",
    14: "m[4:0] rw[9:0] gw[9:0] bw[9:0] rx[3:0] rw[10:15] gx[3:0] gw[10:15] bx[3:0] bw[10:15]",
}

#: Field numbering used by :data:`LAYOUTS`: endpoint e (0=w, 1=x, 2=y, 3=z) and
#: channel c (0=R, 1=G, 2=B) is field ``3*e + c``; the shape is field 12 and
#: the mode bits are field 13.
FIELD_SHAPE = 12
FIELD_MODE = 13
_FIELD_NUMBER = {f"{ch}{ep}": 3 * e + c for e, ep in enumerate("wxyz") for c, ch in enumerate("rgb")}
_FIELD_NUMBER.update(d=FIELD_SHAPE, m=FIELD_MODE)


def _parse_layout(spec: str) -> np.ndarray:
    """Expand one row of 'BC6H compressed endpoint format' into (field, bit) per block bit."""
    out: list[tuple[int, int]] = []
    for tok in spec.split():
        name, rng = tok[:-1].split("[")
        field = _FIELD_NUMBER[name]
        if ":" in rng:
            a, b = (int(v) for v in rng.split(":"))
            step = 1 if a >= b else -1
            bits = range(b, a + step, step)
        else:
            bits = [int(rng)]
        out.extend((field, bit) for bit in bits)
    return np.array(out, dtype=np.int16)


def _check_layout(mode: Mode, layout: np.ndarray) -> None:
    """Check that a layout stores every bit of every field of ``mode`` exactly once."""
    header = 82 if mode.regions == 2 else 65
    assert layout.shape == (header, 2), (mode.number, layout.shape)
    n_ep = 2 * mode.regions
    want = {(FIELD_MODE, i) for i in range(mode.mode_bits)}
    want |= {(c, i) for c in range(3) for i in range(mode.endpoint_bits)}
    want |= {(3 * e + c, i) for e in range(1, n_ep) for c in range(3) for i in range(mode.delta_bits[c])}
    if mode.regions == 2:
        want |= {(FIELD_SHAPE, i) for i in range(5)}
    got = [tuple(int(v) for v in row) for row in layout]
    assert len(set(got)) == len(got) and set(got) == want, f"layout of mode {mode.number} is inconsistent"
    mode_bits = {bit: pos for pos, (f, bit) in enumerate(got) if f == FIELD_MODE}
    assert all(mode_bits[i] == i for i in range(mode.mode_bits)), mode.number


#: Per mode number (1..14): int16 array (header_bits, 2) giving, for block bits
#: 0, 1, 2, ..., the (field, bit-of-field) stored there.  Built from LAYOUT_SPEC.
LAYOUTS: dict[int, np.ndarray] = {}
for _m in MODES:
    LAYOUTS[_m.number] = _parse_layout(LAYOUT_SPEC[_m.number])
    _check_layout(_m, LAYOUTS[_m.number])
    LAYOUTS[_m.number].setflags(write=False)
del _m


def index_layout(shape: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Block bit offset and width of each texel's index; D3D11 BC6H 'index' bits with fix-up MSB dropped.

    ``shape`` is the two-region shape 0..31, or None for one-region modes.
    Returns two int arrays of shape (16,): first bit in the 128-bit block and bit count.
    """
    if shape is None:
        start, bits, anchors = 65, 4, {0}
    else:
        start, bits, anchors = 82, 3, {0, int(ANCHOR2[shape])}
    widths = np.array([bits - (t in anchors) for t in range(16)], dtype=np.int64)
    offsets = start + np.concatenate([[0], np.cumsum(widths)[:-1]])
    assert offsets[-1] + widths[-1] == 128
    return offsets, widths
