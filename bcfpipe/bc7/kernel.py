"""bcfpipe's BC7 decoder, every mode, in numba: the row-major blocks of a (w, h) level decoded
straight into its cropped RGBA image, one block at a time, on the calling thread (issue 59).

Khronos Data Format 1.3 §"BPTC" (BC7), Table "Mode-dependent BPTC parameters" (`anymode.MODES`);
the reserved mode 8 decodes to zero, as D3D11 and Mesa do. Bit for bit texture2ddecoder (the tests'
oracle, tests/test_s3tc.py). Compiled code lives in bcfpipe's cache (`process_env.kernel_cache`).
"""
from __future__ import annotations

import numpy as np

from bcfpipe.bc7.anymode import MODES
from bcfpipe.bptc import ANCHOR2, ANCHOR3, PARTITIONS2, PARTITIONS3, WEIGHTS
from bcfpipe.process_env import kernel_cache, without_cache

CACHE = kernel_cache()  # compiled kernels live in bcfpipe's cache, or nowhere
import numba as nb  # noqa: E402

__all__ = ["bc7_image", "block_words"]


def _mode_table(field: str) -> np.ndarray:
    """Column ``field`` of MODES, one entry per mode 0-7, then 0 for the reserved mode 8."""
    return np.array([getattr(s, field) for s in MODES] + [0], np.int64)


_NS, _PB, _RB, _ISB = _mode_table("ns"), _mode_table("pb"), _mode_table("rb"), _mode_table("isb")
_CB, _AB, _EPB, _SPB = _mode_table("cb"), _mode_table("ab"), _mode_table("epb"), _mode_table("spb")
_IB, _IB2 = _mode_table("ib"), _mode_table("ib2")


def _shape_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row (subsets - 1) * 64 + partition: each texel's subset, (192, 16); the anchor texels as a
    16-bit mask (texel 0 always); and their count."""
    subset = np.zeros((192, 16), np.int64)
    subset[64:128], subset[128:] = PARTITIONS2, PARTITIONS3
    anchors = np.ones(192, np.int64)
    anchors[64:128] |= 1 << ANCHOR2.astype(np.int64)
    anchors[128:] |= (1 << ANCHOR3[:, 0].astype(np.int64)) | (1 << ANCHOR3[:, 1].astype(np.int64))
    count = np.array([bin(int(a)).count("1") for a in anchors], np.int64)
    return subset, anchors, count


_SUBSET, _ANCHORS, _N_ANCHORS = _shape_tables()
_WEIGHTS = np.zeros((5, 16), np.int64)  # row = index bits
for _bits, _w in WEIGHTS.items():
    _WEIGHTS[_bits, :len(_w)] = _w


@nb.njit(inline="always", cache=CACHE, nogil=True)
def _get(lo, hi, pos, n):
    """The ``n`` (< 64) bits from bit ``pos`` of the 128-bit block ``hi:lo``, bit 0 first."""
    if pos >= 64:
        v = hi >> (pos - 64)
    elif pos == 0:
        v = lo
    else:
        v = ((lo >> pos) & ~(np.int64(-1) << (64 - pos))) | (hi << (64 - pos))
    return v & ~(np.int64(-1) << n)


@nb.njit(inline="always", cache=CACHE, nogil=True)
def _widen(v, bits):
    """Khronos §"BPTC": an endpoint of ``bits`` bits widened to 8 by repeating its top bits."""
    return (v << (8 - bits)) | (v >> (2 * bits - 8))


@nb.njit(cache=CACHE, nogil=True)
def _bc7(q, w, h, o32):
    """Khronos §"BPTC" (BC7): the mode from the lowest set bit of byte 0, then its fields (Table
    "Mode-dependent BPTC parameters"): partition, rotation, index selection, colour and alpha
    endpoints, p-bits (per endpoint or per subset), primary and secondary indices (one bit less at
    each subset's anchor texel); a texel is ((64 - w) e0 + w e1 + 32) >> 6, alpha with the
    secondary weights in modes 4 and 5 (swapped by index selection), then rotation swaps alpha
    with a colour channel. A block of the reserved mode 8 decodes to zero. ``o32`` is the
    (h, w) image as one little-endian RGBA word per texel."""
    bw = (w + 3) // 4
    e = np.zeros((6, 4), np.int64)
    wc = np.empty(16, np.int64)
    wa = np.empty(16, np.int64)
    for k in range(q.shape[0]):
        by, bx = k // bw, k % bw
        ny, nx = min(4, h - 4 * by), min(4, w - 4 * bx)
        lo, hi = q[k, 0], q[k, 1]
        b0 = lo & 255
        if b0 == 0:
            for ty in range(ny):
                for tx in range(nx):
                    o32[4 * by + ty, 4 * bx + tx] = 0
            continue
        m = 0
        while (b0 >> m) & 1 == 0:
            m += 1
        ns, cb, ab, ib, ib2 = _NS[m], _CB[m], _AB[m], _IB[m], _IB2[m]
        ne = 2 * ns
        pos = m + 1
        part = _get(lo, hi, pos, _PB[m])
        pos += _PB[m]
        rot = _get(lo, hi, pos, _RB[m])
        pos += _RB[m]
        isb = _get(lo, hi, pos, _ISB[m])
        pos += _ISB[m]
        for ch in range(3):
            for j in range(ne):
                e[j, ch] = _get(lo, hi, pos, cb)
                pos += cb
        for j in range(ne):
            e[j, 3] = _get(lo, hi, pos, ab)
            pos += ab
        cbits, abits = cb, ab
        if _EPB[m] or _SPB[m]:
            for j in range(ne):
                p = _get(lo, hi, pos + (j if _EPB[m] else j // 2), 1)
                for ch in range(4):
                    e[j, ch] = (e[j, ch] << 1) | p
            pos += ne if _EPB[m] else ns
            cbits += 1
            abits += 1 if ab else 0
        for j in range(ne):
            for ch in range(3):
                e[j, ch] = _widen(e[j, ch], cbits)
            e[j, 3] = _widen(e[j, 3], abits) if abits else 255
        row = (ns - 1) * 64 + part
        anchors = _ANCHORS[row]
        n1 = 16 * ib - _N_ANCHORS[row]
        bits = _get(lo, hi, pos, n1)
        for i in range(16):
            width = ib - ((anchors >> i) & 1)
            wc[i] = _WEIGHTS[ib, bits & ~(np.int64(-1) << width)]
            bits >>= width
        if ib2:
            bits = _get(lo, hi, pos + n1, 16 * ib2 - 1)
            for i in range(16):
                width = ib2 - (1 if i == 0 else 0)
                wa[i] = _WEIGHTS[ib2, bits & ~(np.int64(-1) << width)]
                bits >>= width
            if isb:
                for i in range(16):
                    wc[i], wa[i] = wa[i], wc[i]
        else:
            for i in range(16):
                wa[i] = wc[i]
        # rotation r swaps alpha with channel r - 1: where each interpolated channel goes
        d0 = 24 if rot == 1 else 0
        d1 = 24 if rot == 2 else 8
        d2 = 24 if rot == 3 else 16
        d3 = 8 * (rot - 1) if rot else 24
        for ty in range(ny):
            for tx in range(nx):
                i = 4 * ty + tx
                s = 2 * _SUBSET[row, i]
                c, a = wc[i], wa[i]
                o32[4 * by + ty, 4 * bx + tx] = (
                    (((64 - c) * e[s, 0] + c * e[s + 1, 0] + 32) >> 6) << d0
                    | (((64 - c) * e[s, 1] + c * e[s + 1, 1] + 32) >> 6) << d1
                    | (((64 - c) * e[s, 2] + c * e[s + 1, 2] + 32) >> 6) << d2
                    | (((64 - a) * e[s, 3] + a * e[s + 1, 3] + 32) >> 6) << d3)


def block_words(blocks: np.ndarray, block_bytes: int, width: int, height: int) -> np.ndarray:
    """The level's blocks as (n, block_bytes / 8) int64, each 8 bytes little-endian, checked
    against its size; writable (a read-only array is copied: the kernels are compiled for one
    type of array)."""
    b = np.ascontiguousarray(np.asarray(blocks, np.uint8).reshape(-1, block_bytes))
    n = -(-width // 4) * -(-height // 4)
    if b.shape[0] != n:
        raise ValueError(f"a {width}x{height} image needs {n} blocks, got {b.shape[0]}")
    q = b.view("<i8").astype(np.int64, copy=False)
    return q if q.flags.writeable else q.copy()


def bc7_image(blocks: np.ndarray, width: int, height: int) -> np.ndarray:
    """(n, 16) BC7 blocks of any mode -> (height, width, 4) uint8 RGBA."""
    width, height = int(width), int(height)
    o32 = np.empty((height, width), np.uint32)
    q = block_words(blocks, 16, width, height)
    without_cache(lambda: _bc7(q, width, height, o32), globals())
    return o32.astype("<u4", copy=False).view(np.uint8).reshape(height, width, 4)
