"""Bit-exact BC6H decoder (vectorized numpy).

Implements the decoding process of the Direct3D 11 "BC6H format" documentation
(learn.microsoft.com/windows/win32/direct3d11/bc6h-format): header parsing
with the per-mode bit layouts, sign extension, inverse delta transform,
unquantize, interpolation with the 3/4-bit weight tables and
finish_unquantize, for all 14 modes, unsigned (BC6H_UF16) and signed
(BC6H_SF16).  Reserved modes decode to zero.

All blocks are processed together: a per-mode table of bit runs (built once
from :data:`bcfpipe.bc6h.tables.LAYOUTS`) gathers the header fields of each
mode's blocks, and everything after that is elementwise with per-block
parameters.
"""

from __future__ import annotations

import numpy as np

from .tables import (
    FIELD_MODE,
    FIELD_SHAPE,
    LAYOUTS,
    MODES,
    PARTITIONS2,
    RESERVED_MODE_VALUES,
    WEIGHTS3,
    WEIGHTS4,
    index_layout,
)

__all__ = ["decode", "decode_to_u16", "block_modes"]

#: Blocks decoded per pass (bounds the temporaries to a few hundred MB).
_CHUNK = 1 << 18


def _build_runs() -> list[list[tuple[int, int, int, int, int]]]:
    """Compress each mode's (field, bit) layout into runs (field, word, shift, length, field_shift).

    A run is a stretch of consecutive block bits holding consecutive ascending
    bits of one field within one 64-bit word, so that it can be read as
    ``((word >> shift) & mask) << field_shift``.
    """
    runs_per_mode = []
    for mode in MODES:
        layout = LAYOUTS[mode.number]
        runs: list[list[int]] = []
        for pos, (field, bit) in enumerate(layout.tolist()):
            if field == FIELD_MODE:
                continue
            prev = runs[-1] if runs else None
            if (
                prev is not None
                and prev[0] == field
                and prev[1] == pos // 64
                and prev[2] + prev[3] == pos % 64
                and prev[4] + prev[3] == bit
            ):
                prev[3] += 1
            else:
                runs.append([field, pos // 64, pos % 64, 1, bit])
        runs_per_mode.append([tuple(r) for r in runs])
    return runs_per_mode


_RUNS = _build_runs()

# Per-mode parameters, indexed by mode index 0..13 (spec mode number - 1).
_EP_BITS = np.array([m.endpoint_bits for m in MODES], dtype=np.int32)
_DELTA_BITS = np.array([m.delta_bits for m in MODES], dtype=np.int32)
_TRANSFORMED = np.array([m.transformed for m in MODES], dtype=bool)
_TWO_REGIONS = np.array([m.regions == 2 for m in MODES], dtype=bool)

# Mode index of each value of the low five block bits; -1 for reserved modes.
_MODE_OF_LOW5 = np.full(32, -1, dtype=np.int8)
for _i, _m in enumerate(MODES):
    if _m.mode_bits == 2:
        _MODE_OF_LOW5[[_m.value | (hi << 2) for hi in range(8)]] = _i
    else:
        _MODE_OF_LOW5[_m.value] = _i
assert sorted(np.nonzero(_MODE_OF_LOW5 < 0)[0].tolist()) == sorted(RESERVED_MODE_VALUES)
del _i, _m

# Texel index positions within the high 64-bit word (all index bits lie in
# bits 65..127).  Rows 0..31: two-region shapes; row 32: one-region modes.
_IDX_SHIFT = np.zeros((33, 16), dtype=np.uint64)
_IDX_MASK = np.zeros((33, 16), dtype=np.uint64)
for _s in range(33):
    _off, _wid = index_layout(_s if _s < 32 else None)
    _IDX_SHIFT[_s] = _off - 64
    _IDX_MASK[_s] = (1 << _wid) - 1
del _s, _off, _wid

# Subset of each texel; row 32 (one-region modes) is all zeros.
_SUBSETS = np.zeros((33, 16), dtype=np.intp)
_SUBSETS[:32] = PARTITIONS2

# Weight lookup: rows 0..31 use the 3-bit table, row 32 the 4-bit table.
_WEIGHTS = np.zeros((2, 16), dtype=np.int32)
_WEIGHTS[0, :8] = WEIGHTS3
_WEIGHTS[1] = WEIGHTS4


def _check_blocks(blocks: np.ndarray) -> np.ndarray:
    """Validate a BC6H block array and return it C-contiguous."""
    if not isinstance(blocks, np.ndarray):
        raise ValueError(f"blocks must be a numpy array, got {type(blocks).__name__}")
    if blocks.dtype != np.uint8:
        raise ValueError(f"blocks must have dtype uint8, got {blocks.dtype}")
    if blocks.ndim != 2 or blocks.shape[1] != 16:
        raise ValueError(f"blocks must have shape (n, 16), got {blocks.shape}")
    return np.ascontiguousarray(blocks)


def block_modes(blocks: np.ndarray) -> np.ndarray:
    """Spec mode number (1..14) of each block, 0 for reserved modes (D3D11 BC6H 'BC6H modes')."""
    blocks = _check_blocks(blocks)
    return (_MODE_OF_LOW5[blocks[:, 0] & 0x1F].astype(np.int16) + 1).astype(np.uint8)


def _sign_extend(x: np.ndarray, bits: np.ndarray) -> np.ndarray:
    """Sign-extend the low ``bits`` bits of int32 ``x`` (D3D11 BC6H 'Sign extension for endpoint values')."""
    sh = 32 - bits
    return np.left_shift(x, sh) >> sh


def _unquantize(x: np.ndarray, bits: np.ndarray, signed: bool) -> np.ndarray:
    """D3D11 BC6H 'Unquantization of color endpoints' (``unquantize``), elementwise, int32."""
    if not signed:
        mid = (np.left_shift(x, 16) + 0x8000) >> np.minimum(bits, 15)
        out = np.where(x == 0, 0, np.where(x == (1 << bits) - 1, 0xFFFF, mid))
        return np.where(bits >= 15, x, out).astype(np.int32)
    neg = x < 0
    mag = np.abs(x)
    b1 = np.minimum(bits, 16) - 1
    mid = (np.left_shift(mag, 15) + 0x4000) >> np.minimum(b1, 14)
    out = np.where(mag == 0, 0, np.where(mag >= (1 << b1) - 1, 0x7FFF, mid))
    out = np.where(neg, -out, out)
    return np.where(bits >= 16, x, out).astype(np.int32)


def _finish_unquantize(x: np.ndarray, signed: bool) -> np.ndarray:
    """D3D11 BC6H 'finish_unquantize': scale to half bits (x31/64 unsigned, x31/32 signed magnitude)."""
    if not signed:
        return ((x * 31) >> 6).astype(np.uint16)
    mag = (np.abs(x) * 31) >> 5
    sign = np.where((x < 0) & (mag != 0), 0x8000, 0)
    return (mag | sign).astype(np.uint16)


def _decode_chunk(blocks: np.ndarray, signed: bool) -> np.ndarray:
    n = blocks.shape[0]
    words = blocks.view("<u8").reshape(n, 2)
    mode = _MODE_OF_LOW5[blocks[:, 0] & 0x1F].astype(np.intp)
    reserved = mode < 0
    mode[reserved] = 10  # decode as mode 11 (no shape), zeroed at the end

    # --- header fields: (n, 13) = 12 endpoint components + shape
    fields = np.zeros((n, 13), dtype=np.int32)
    for mi, runs in enumerate(_RUNS):
        sel = np.flatnonzero(mode == mi)
        if sel.size == 0:
            continue
        w = words[sel]
        f = np.zeros((sel.size, 13), dtype=np.uint64)
        for field, word, shift, length, fshift in runs:
            f[:, field] |= ((w[:, word] >> np.uint64(shift)) & np.uint64((1 << length) - 1)) << np.uint64(fshift)
        fields[sel] = f.astype(np.int32)

    ep = fields[:, :12].reshape(n, 4, 3)  # [block, endpoint w/x/y/z, channel]
    shape = fields[:, FIELD_SHAPE]
    two = _TWO_REGIONS[mode]
    epb = _EP_BITS[mode][:, None, None]            # (n,1,1)
    db = _DELTA_BITS[mode][:, None, :]             # (n,1,3)
    tr = _TRANSFORMED[mode][:, None, None]         # (n,1,1)

    # --- sign extension and inverse transform
    e0 = ep[:, :1]
    rest = ep[:, 1:]
    if signed:
        e0 = _sign_extend(e0, epb)
        rest = _sign_extend(rest, db)
    else:
        rest = np.where(tr, _sign_extend(rest, db), rest)
    inv = (rest + e0) & ((1 << epb) - 1)
    if signed:
        inv = _sign_extend(inv, epb)
    rest = np.where(tr, inv, rest)
    ep = np.concatenate([e0, rest], axis=1)

    # --- unquantize endpoints
    uq = _unquantize(ep, epb, signed)              # (n,4,3)

    # --- per-texel indices, subsets and weights
    row = np.where(two, shape, 32)
    idx = (words[:, 1:2] >> _IDX_SHIFT[row]) & _IDX_MASK[row]          # (n,16)
    wgt = _WEIGHTS[(~two).astype(np.intp)[:, None], idx.astype(np.intp)]  # (n,16)
    sub = _SUBSETS[row]                                                 # (n,16)
    bi = np.arange(n)[:, None]
    a = uq[bi, 2 * sub]                                                 # (n,16,3)
    b = uq[bi, 2 * sub + 1]
    wgt = wgt[:, :, None]
    interp = (a * (64 - wgt) + b * wgt + 32) >> 6

    out = _finish_unquantize(interp, signed)
    out[reserved] = 0
    return out


def decode_to_u16(blocks: np.ndarray, signed: bool = False) -> np.ndarray:
    """Decode BC6H blocks to raw half-float bits, shape (n, 16, 3) uint16.

    Texels are row-major within each block (index 4*y + x); channels R, G, B.
    Unsigned blocks (BC6H_UF16) never produce a sign bit.
    """
    blocks = _check_blocks(blocks)
    n = blocks.shape[0]
    out = np.empty((n, 16, 3), dtype=np.uint16)
    for start in range(0, n, _CHUNK):
        out[start:start + _CHUNK] = _decode_chunk(blocks[start:start + _CHUNK], bool(signed))
    return out


def decode(blocks: np.ndarray, width: int, height: int, signed: bool = False) -> np.ndarray:
    """Decode a BC6H image to float16 RGB of shape (height, width, 3).

    ``blocks``: uint8 array (n, 16) in row-major block order with
    n = ceil(width/4) * ceil(height/4); texels beyond width/height are cropped.
    """
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
    width, height = int(width), int(height)
    blocks = _check_blocks(blocks)
    bw, bh = -(-width // 4), -(-height // 4)
    if blocks.shape[0] != bw * bh:
        raise ValueError(
            f"a {width}x{height} BC6H image needs {bw}x{bh} = {bw * bh} blocks, got {blocks.shape[0]}"
        )
    u16 = decode_to_u16(blocks, signed)
    img = u16.reshape(bh, bw, 4, 4, 3).transpose(0, 2, 1, 3, 4).reshape(bh * 4, bw * 4, 3)
    return np.ascontiguousarray(img[:height, :width]).view(np.float16)
