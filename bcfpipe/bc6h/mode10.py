"""Pack / unpack BC6H blocks of D3D mode 10 (mode bits ``11110``).

This is the only BC6H mode bcfpipe *writes*: two regions, 6-bit endpoints stored
untransformed (no deltas) for 4 endpoints x 3 channels, a 5-bit partition
("shape") id and 3-bit texel indices (46 index bits: the anchor texel of each
subset stores only 2 bits, its MSB being implicitly 0).

Numbering follows the D3D11 "BC6H format" page (and :mod:`bcfpipe.bc6h.tables`):
the block's low 5 bits are ``m[4:0] = 0b11110`` (value 0x1E, i.e. bit 0 is 0 and
bits 1..4 are 1); the header layout is

    m[4:0] rw[5:0] gz[4] bz[0] bz[1] by[4] gw[5:0] gy[5] by[5] bz[2] gy[4] bw[5:0]
    gz[5] bz[3] bz[5] bz[4] rx[5:0] gy[3:0] gx[5:0] gz[3:0] bx[5:0] by[3:0]
    ry[5:0] rz[5:0] d[4:0]

(w, x = endpoints 0, 1 of subset 0; y, z = endpoints 2, 3 of subset 1; d = shape),
followed at bit 82 by the texel indices in row-major texel order.  The same
layout is in iOrange/bcdec (``case 0b11110``) and DirectXTex (``Mode 10 (0x1e)``).

Parameter conventions used throughout bcfpipe:

* ``endpoints``: int (n, 4, 3) -- (e0, e1) of subset 0, (e2, e3) of subset 1,
  channels R, G, B.  Unsigned format: the stored 6-bit value in [0, 63].  Signed
  format (``signed=True``): the sign-extended two's-complement value in
  [-32, 31] (mode 10 sign-extends *every* endpoint when the format is signed).
* ``indices``: int (n, 16) in [0, 7], row-major texel order (texel = 4*y + x).
* ``partition``: int (n,) in [0, 31]; subset membership from
  :data:`bcfpipe.bc6h.tables.PARTITIONS2`.

The module also holds the exact integer decode pipeline of this mode
(:func:`unquantize`, :func:`interpolate`, :func:`finish_unquantize`,
:func:`decode_params`), used by the encoder and as a second oracle in tests.
"""

from __future__ import annotations

import numpy as np

from .tables import ANCHOR2, PARTITIONS2, WEIGHTS3

__all__ = [
    "MODE_VALUE",
    "SPEC_MODE",
    "DESCRIPTION",
    "pack",
    "unpack",
    "is_mode10",
    "canonicalize",
    "unquantize",
    "unquantize_table",
    "interpolate",
    "finish_unquantize",
    "half_bits_to_float",
    "decode_params",
]

#: Value of the 5 mode bits m[4:0] of this mode (bit i of the block = bit i of the value).
MODE_VALUE = 0b11110
#: The D3D11 spec's number for this mode ('BC6H modes' table, row 10).
SPEC_MODE = 10
#: How bcfpipe's files name the mode (material.json ``bc6h.block_mode``).
DESCRIPTION = "11110 (two regions, 6-bit endpoints, 3-bit indices)"
#: Endpoint precision of this mode.
ENDPOINT_BITS = 6
HEADER_BITS = 82

# Header layout: for block bits 5..81, (field, bit-of-field).  Fields 0..11 are
# endpoint e, channel c as 3*e + c; field 12 is the shape id d.  Transcribed from
# the D3D11 table row of mode 10 (see module docstring).
_LAYOUT_SPEC = (
    "rw[5:0] gz[4] bz[0] bz[1] by[4] gw[5:0] gy[5] by[5] bz[2] gy[4] bw[5:0] "
    "gz[5] bz[3] bz[5] bz[4] rx[5:0] gy[3:0] gx[5:0] gz[3:0] bx[5:0] by[3:0] "
    "ry[5:0] rz[5:0] d[4:0]"
)


def _parse_layout(spec: str) -> np.ndarray:
    field_no = {f"{ch}{ep}": 3 * e + c for e, ep in enumerate("wxyz") for c, ch in enumerate("rgb")}
    field_no["d"] = 12
    out = []
    for tok in spec.split():
        name, rng = tok[:-1].split("[")
        if ":" in rng:
            hi, lo = (int(v) for v in rng.split(":"))
            bits = range(lo, hi + 1)  # ``f[hi:lo]`` is stored LSB first
        else:
            bits = [int(rng)]
        out.extend((field_no[name], b) for b in bits)
    arr = np.array(out, dtype=np.int64)
    assert arr.shape == (HEADER_BITS - 5, 2)
    # every bit of every field exactly once
    assert len({tuple(r) for r in arr.tolist()}) == len(arr)
    assert sorted(r[1] for r in arr.tolist() if r[0] == 12) == [0, 1, 2, 3, 4]
    for f in range(12):
        assert sorted(r[1] for r in arr.tolist() if r[0] == f) == list(range(6))
    return arr


#: (77, 2) int: (field, bit) of block bits 5..81.
HEADER_LAYOUT = _parse_layout(_LAYOUT_SPEC)
HEADER_LAYOUT.setflags(write=False)


def _index_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per shape: which (texel, bit) each index bit 82..127 holds, and per texel its offset/width."""
    pos_texel = np.zeros((32, 46), np.int64)
    pos_bit = np.zeros((32, 46), np.int64)
    offset = np.zeros((32, 16), np.int64)
    width = np.zeros((32, 16), np.int64)
    for p in range(32):
        anchors = {0, int(ANCHOR2[p])}
        pos = HEADER_BITS
        k = 0
        for t in range(16):
            w = 2 if t in anchors else 3
            offset[p, t], width[p, t] = pos, w
            for j in range(w):
                pos_texel[p, k], pos_bit[p, k] = t, j
                k += 1
            pos += w
        assert pos == 128 and k == 46
    return pos_texel, pos_bit, offset, width


_POS_TEXEL, _POS_BIT, _IDX_OFFSET, _IDX_WIDTH = _index_tables()


def _as_int(a, name: str, shape_tail: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype.kind == "f":
        if not np.all(np.isfinite(a)) or np.any(a != np.round(a)):
            raise ValueError(f"{name} must hold integers")
    elif a.dtype.kind not in "iub":
        raise ValueError(f"{name} must be an integer array, got dtype {a.dtype}")
    a = a.astype(np.int64)
    if a.shape[1:] != shape_tail:
        raise ValueError(f"{name} must have shape (n, {', '.join(map(str, shape_tail))}), got {a.shape}")
    return a


def _check_params(endpoints, indices, partition, signed: bool):
    partition = np.asarray(partition)
    if partition.ndim != 1:
        raise ValueError(f"partition must have shape (n,), got {partition.shape}")
    partition = _as_int(partition.reshape(-1, 1), "partition", (1,))[:, 0]
    endpoints = _as_int(endpoints, "endpoints", (4, 3))
    indices = _as_int(indices, "indices", (16,))
    n = partition.shape[0]
    if endpoints.shape[0] != n or indices.shape[0] != n:
        raise ValueError("endpoints, indices and partition disagree on the number of blocks")
    lo, hi = (-32, 31) if signed else (0, 63)
    if n and (endpoints.min() < lo or endpoints.max() > hi):
        raise ValueError(f"endpoints must lie in [{lo}, {hi}] ({'signed' if signed else 'unsigned'} format)")
    if n and (indices.min() < 0 or indices.max() > 7):
        raise ValueError("indices must lie in [0, 7]")
    if n and (partition.min() < 0 or partition.max() > 31):
        raise ValueError("partition must lie in [0, 31]")
    return endpoints, indices, partition


def canonicalize(endpoints, indices, partition):
    """Apply the anchor rule: returns copies where each subset's anchor index has MSB 0.

    If a subset's anchor texel (texel 0 for subset 0, ``ANCHOR2[p]`` for subset 1)
    has an index >= 4, that subset's two endpoints are swapped and its indices
    replaced by ``7 - i``.  Because ``WEIGHTS3[7 - i] == 64 - WEIGHTS3[i]`` this
    leaves the decoded texels bit-identical.  No range checks are done here.
    """
    e = np.array(endpoints, dtype=np.int64, copy=True)
    idx = np.array(indices, dtype=np.int64, copy=True)
    part = np.asarray(partition, dtype=np.int64)
    n = part.shape[0]
    subset1 = PARTITIONS2[part].astype(bool)  # (n, 16)
    rows = np.arange(n)
    for s, anchor in ((0, np.zeros(n, np.int64)), (1, ANCHOR2[part].astype(np.int64))):
        flip = idx[rows, anchor] >= 4  # (n,)
        if not flip.any():
            continue
        in_s = subset1 if s == 1 else ~subset1
        m = flip[:, None] & in_s
        idx[m] = 7 - idx[m]
        a, b = e[flip, 2 * s].copy(), e[flip, 2 * s + 1].copy()
        e[flip, 2 * s], e[flip, 2 * s + 1] = b, a
    return e, idx, part


def pack(endpoints, indices, partition, signed: bool = False) -> np.ndarray:
    """Build mode-10 (``11110``) BC6H blocks; returns uint8 (n, 16).

    ``endpoints`` int (n, 4, 3): [0, 63], or [-32, 31] when ``signed``;
    ``indices`` int (n, 16) in [0, 7] (texel order); ``partition`` int (n,) in [0, 31].
    The anchor rule is enforced here (see :func:`canonicalize`), so any parameters
    give a valid block that decodes to the texels they describe.
    """
    endpoints, indices, partition = _check_params(endpoints, indices, partition, signed)
    endpoints, indices, partition = canonicalize(endpoints, indices, partition)
    n = partition.shape[0]
    fields = np.concatenate([(endpoints & 63).reshape(n, 12), partition[:, None]], axis=1)  # (n, 13)
    bits = np.zeros((n, 128), np.uint8)
    for b in range(5):
        bits[:, b] = (MODE_VALUE >> b) & 1
    bits[:, 5:HEADER_BITS] = (fields[:, HEADER_LAYOUT[:, 0]] >> HEADER_LAYOUT[:, 1]) & 1
    tex = _POS_TEXEL[partition]  # (n, 46)
    bit = _POS_BIT[partition]
    bits[:, HEADER_BITS:] = (np.take_along_axis(indices, tex, axis=1) >> bit) & 1
    return np.packbits(bits, axis=1, bitorder="little")


def _as_blocks(blocks) -> np.ndarray:
    b = np.asarray(blocks)
    if b.dtype != np.uint8:
        raise ValueError(f"blocks must be uint8, got {b.dtype}")
    if b.ndim == 1 and b.size % 16 == 0:
        b = b.reshape(-1, 16)
    if b.ndim != 2 or b.shape[1] != 16:
        raise ValueError(f"blocks must have shape (n, 16), got {b.shape}")
    return b


def is_mode10(blocks) -> np.ndarray:
    """bool (n,): which blocks use mode bits ``11110``."""
    b = _as_blocks(blocks)
    return (b[:, 0] & 0x1F) == MODE_VALUE


def unpack(blocks, signed: bool = False):
    """Inverse of :func:`pack`: ``(endpoints (n,4,3), indices (n,16), partition (n,))``, int64.

    Raises ValueError if any block does not use mode bits ``11110``.  Endpoints are
    sign-extended to [-32, 31] when ``signed``.  The anchor indices come back with
    their (implicit) MSB 0, i.e. in canonical form.
    """
    b = _as_blocks(blocks)
    bad = ~is_mode10(b)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"{int(bad.sum())} block(s) are not mode 11110 (first: block {i}, mode bits {b[i, 0] & 0x1F:05b})"
        )
    n = b.shape[0]
    bits = np.unpackbits(b, axis=1, bitorder="little").astype(np.int64)  # (n, 128)
    fields = np.zeros((n, 13), np.int64)
    for f in range(13):
        sel = HEADER_LAYOUT[:, 0] == f
        fields[:, f] = bits[:, 5:HEADER_BITS][:, sel] @ (1 << HEADER_LAYOUT[sel, 1])
    endpoints = fields[:, :12].reshape(n, 4, 3)
    if signed:
        endpoints = np.where(endpoints >= 32, endpoints - 64, endpoints)
    partition = fields[:, 12]
    off = _IDX_OFFSET[partition]  # (n, 16)
    wid = _IDX_WIDTH[partition]
    indices = np.zeros((n, 16), np.int64)
    for j in range(3):
        pos = np.minimum(off + j, 127)
        indices += np.where(j < wid, np.take_along_axis(bits, pos, axis=1), 0) << j
    return endpoints, indices, partition


# ---------------------------------------------------------------------------
# Exact integer decode pipeline of this mode (D3D11 "Unquantization of Color
# Endpoints" + interpolation + finish_unquantize), vectorized.
# ---------------------------------------------------------------------------


def unquantize(e, signed: bool = False) -> np.ndarray:
    """6-bit endpoint -> 16-bit interpolation domain (int64), exactly as the spec.

    Unsigned: 0 -> 0, 63 -> 0xFFFF, else ``((e << 16) + 0x8000) >> 6`` (= 1024 e + 512).
    Signed (e in [-32, 31]): ``|e| = 0 -> 0``, ``|e| >= 31 -> 0x7FFF``, else
    ``((|e| << 15) + 0x4000) >> 5`` (= 1024 |e| + 512), with e's sign.
    """
    e = np.asarray(e, dtype=np.int64)
    if not signed:
        u = ((e << 16) + 0x8000) >> ENDPOINT_BITS
        return np.where(e == 0, 0, np.where(e == 63, 0xFFFF, u))
    a = np.abs(e)
    u = ((a << 15) + 0x4000) >> (ENDPOINT_BITS - 1)
    u = np.where(a == 0, 0, np.where(a >= 31, 0x7FFF, u))
    return np.where(e < 0, -u, u)


def unquantize_table(signed: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(endpoint values, their unquantized values) for every representable endpoint."""
    e = np.arange(-32, 32) if signed else np.arange(64)
    return e, unquantize(e, signed)


def interpolate(ua, ub, weight) -> np.ndarray:
    """``(a*(64-w) + b*w + 32) >> 6`` (arithmetic shift, also for negative values)."""
    ua, ub, w = (np.asarray(v, dtype=np.int64) for v in (ua, ub, weight))
    return (ua * (64 - w) + ub * w + 32) >> 6


def finish_unquantize(v, signed: bool = False) -> np.ndarray:
    """Interpolated value -> 16 half-float bits (uint16): ``v*31 >> 6`` (unsigned) or
    sign-magnitude ``|v|*31 >> 5`` (signed)."""
    v = np.asarray(v, dtype=np.int64)
    if not signed:
        return ((v * 31) >> 6).astype(np.uint16)
    m = (np.abs(v) * 31) >> 5
    # spec/bcdec: the sign bit is set only when the truncated result is negative
    return np.where((v < 0) & (m != 0), m | 0x8000, m).astype(np.uint16)


def half_bits_to_float(h) -> np.ndarray:
    """Bit-cast uint16 -> float16."""
    return np.asarray(h, dtype=np.uint16).view(np.float16)


def decode_params(endpoints, indices, partition, signed: bool = False) -> np.ndarray:
    """Decode mode-10 parameters exactly (no bit packing); float16 (n, 16, 3).

    Does not apply the anchor rule (it does not change the result), so it accepts
    any index in [0, 7] at any texel.
    """
    e = np.asarray(endpoints, dtype=np.int64)
    idx = np.asarray(indices, dtype=np.int64)
    part = np.asarray(partition, dtype=np.int64)
    u = unquantize(e, signed)  # (n, 4, 3)
    s1 = PARTITIONS2[part].astype(bool)[:, :, None]  # (n, 16, 1)
    ua = np.where(s1, u[:, None, 2], u[:, None, 0])  # (n, 16, 3)
    ub = np.where(s1, u[:, None, 3], u[:, None, 1])
    w = WEIGHTS3[idx][:, :, None]
    return half_bits_to_float(finish_unquantize(interpolate(ua, ub, w), signed))
