"""bcfpipe's BC1, BC4 and BC5 decoders in numba: the row-major blocks of a (w, h) level decoded
straight into its cropped (h, w, channels) uint8 image, one block at a time, on the calling thread
(issue 59).

Khronos Data Format 1.3 §"S3TC" (BC1, "BC1 with no alpha": its transparent texel reads as black
RGB) and §"RGTC" (BC4 unsigned; BC5 as two BC4 blocks). Interpolated values take the integer form
quicktex and texture2ddecoder (the tests' oracles, tests/test_s3tc.py) both use,
floor((w0 e0 + w1 e1) / n), on 8-bit endpoints. Compiled code lives in bcfpipe's cache
(`process_env.kernel_cache`).
"""
from __future__ import annotations

import sys

import numpy as np

from bcfpipe.bc7.kernel import block_words
from bcfpipe.process_env import kernel_cache, without_cache

CACHE = kernel_cache()  # compiled kernels live in bcfpipe's cache, or nowhere
import numba as nb  # noqa: E402

__all__ = ["bc1_image", "bc4_image", "bc5_image"]


@nb.njit(inline="always", cache=CACHE, nogil=True)
def _rgb565(c):
    """Khronos §"S3TC": a 5:6:5 colour widened to 8-bit R, G, B by bit replication."""
    r, g, b = (c >> 11) & 31, (c >> 5) & 63, c & 31
    return (r << 3) | (r >> 2), (g << 2) | (g >> 4), (b << 3) | (b >> 2)


@nb.njit(cache=CACHE, nogil=True)
def _bc1(q, w, h, out, o32, words):
    """Khronos §"S3TC", BC1: c0 > c1 (as 16-bit integers) four colours, floor((2 e0 + e1) / 3) and
    floor((e0 + 2 e1) / 3) between; else three, floor((e0 + e1) / 2) and black. With ``words``
    (rows of whole 32-bit words), a whole block's row of 4 texels is three words of ``o32``."""
    pal = np.empty(4, np.int64)
    bw = (w + 3) // 4
    for by in range((h + 3) // 4):
        ny = min(4, h - 4 * by)
        for bx in range(bw):
            nx = min(4, w - 4 * bx)
            v = q[by * bw + bx]
            c0, c1, sel = v & 0xFFFF, (v >> 16) & 0xFFFF, v >> 32
            r0, g0, b0 = _rgb565(c0)
            r1, g1, b1 = _rgb565(c1)
            pal[0] = r0 | g0 << 8 | b0 << 16
            pal[1] = r1 | g1 << 8 | b1 << 16
            if c0 > c1:
                pal[2] = (2 * r0 + r1) // 3 | ((2 * g0 + g1) // 3) << 8 | ((2 * b0 + b1) // 3) << 16
                pal[3] = (r0 + 2 * r1) // 3 | ((g0 + 2 * g1) // 3) << 8 | ((b0 + 2 * b1) // 3) << 16
            else:
                pal[2] = (r0 + r1) // 2 | ((g0 + g1) // 2) << 8 | ((b0 + b1) // 2) << 16
                pal[3] = 0
            if words and ny == 4 and nx == 4:
                for ty in range(4):
                    p0, p1, p2, p3 = pal[sel & 3], pal[(sel >> 2) & 3], pal[(sel >> 4) & 3], pal[(sel >> 6) & 3]
                    sel >>= 8
                    y = 4 * by + ty
                    o32[y, 3 * bx] = p0 | p1 << 24
                    o32[y, 3 * bx + 1] = p1 >> 8 | p2 << 16
                    o32[y, 3 * bx + 2] = p2 >> 16 | p3 << 8
                continue
            for ty in range(ny):
                for tx in range(nx):
                    p = pal[(sel >> (2 * (4 * ty + tx))) & 3]
                    y, x = 4 * by + ty, 4 * bx + tx
                    out[y, x, 0] = p & 255
                    out[y, x, 1] = (p >> 8) & 255
                    out[y, x, 2] = p >> 16


@nb.njit(inline="always", cache=CACHE, nogil=True)
def _bc4_block(v, pal):
    """Khronos §"RGTC", BC4 unsigned: the palette of block ``v`` (its 8 bytes, little-endian) into
    ``pal``: a0 > a1 eight values, floor(((7 - j) a0 + j a1) / 7) between; else six,
    floor(((5 - j) a0 + j a1) / 5) between, then 0 and 255. Returns its 48 bits of 3-bit indices."""
    a0, a1 = v & 255, (v >> 8) & 255
    pal[0], pal[1] = a0, a1
    if a0 > a1:
        for j in range(1, 7):
            pal[1 + j] = ((7 - j) * a0 + j * a1) // 7
    else:
        for j in range(1, 5):
            pal[1 + j] = ((5 - j) * a0 + j * a1) // 5
        pal[6], pal[7] = 0, 255
    return (v >> 16) & 0xFFFFFFFFFFFF


@nb.njit(cache=CACHE, nogil=True)
def _bc4(q, w, h, out, o32, words):
    """Khronos §"RGTC", BC4 unsigned. With ``words``, a whole block's row of 4 texels is one 32-bit
    word of ``o32``."""
    bw = (w + 3) // 4
    pal = np.empty(8, np.int64)
    for by in range((h + 3) // 4):
        ny = min(4, h - 4 * by)
        for bx in range(bw):
            nx = min(4, w - 4 * bx)
            sel = _bc4_block(q[by * bw + bx], pal)
            if words and ny == 4 and nx == 4:
                for ty in range(4):
                    o32[4 * by + ty, bx] = (pal[sel & 7] | pal[(sel >> 3) & 7] << 8 | pal[(sel >> 6) & 7] << 16
                                            | pal[(sel >> 9) & 7] << 24)
                    sel >>= 12
                continue
            for ty in range(ny):
                for tx in range(nx):
                    out[4 * by + ty, 4 * bx + tx, 0] = pal[(sel >> (3 * (4 * ty + tx))) & 7]


@nb.njit(cache=CACHE, nogil=True)
def _bc5(q, w, h, out, o32, words):
    """Khronos §"RGTC", BC5 unsigned: a BC4 block for red, then one for green. With ``words``, a
    whole block's row of 4 texels is two 32-bit words of ``o32``."""
    bw = (w + 3) // 4
    pr = np.empty(8, np.int64)
    pg = np.empty(8, np.int64)
    for by in range((h + 3) // 4):
        ny = min(4, h - 4 * by)
        for bx in range(bw):
            nx = min(4, w - 4 * bx)
            k = by * bw + bx
            r, g = _bc4_block(q[k, 0], pr), _bc4_block(q[k, 1], pg)
            if words and ny == 4 and nx == 4:
                for ty in range(4):
                    y = 4 * by + ty
                    o32[y, 2 * bx] = pr[r & 7] | pg[g & 7] << 8 | pr[(r >> 3) & 7] << 16 | pg[(g >> 3) & 7] << 24
                    o32[y, 2 * bx + 1] = (pr[(r >> 6) & 7] | pg[(g >> 6) & 7] << 8 | pr[(r >> 9) & 7] << 16
                                          | pg[(g >> 9) & 7] << 24)
                    r >>= 12
                    g >>= 12
                continue
            for ty in range(ny):
                for tx in range(nx):
                    t, y, x = 3 * (4 * ty + tx), 4 * by + ty, 4 * bx + tx
                    out[y, x, 0] = pr[(r >> t) & 7]
                    out[y, x, 1] = pg[(g >> t) & 7]


def _words(out: np.ndarray) -> tuple[np.ndarray, bool]:
    """``out`` as rows of little-endian 32-bit words, and whether it is one (else a dummy)."""
    h, w, c = out.shape
    if (w * c) % 4 or sys.byteorder != "little":
        return np.zeros((1, 1), np.uint32), False
    return out.reshape(h, w * c).view(np.uint32), True


def _image(kernel, blocks: np.ndarray, block_bytes: int, channels: int, width: int, height: int) -> np.ndarray:
    """``kernel``'s (height, width, channels) uint8 image of a level's blocks."""
    width, height = int(width), int(height)
    q = block_words(blocks, block_bytes, width, height)
    out = np.empty((height, width, channels), np.uint8)
    without_cache(lambda: kernel(q if block_bytes == 16 else q[:, 0], width, height, out, *_words(out)), globals())
    return out


def bc1_image(blocks: np.ndarray, width: int, height: int) -> np.ndarray:
    """(n, 8) BC1 blocks of a ``width`` x ``height`` level -> (height, width, 3) uint8 RGB."""
    return _image(_bc1, blocks, 8, 3, width, height)


def bc4_image(blocks: np.ndarray, width: int, height: int) -> np.ndarray:
    """(n, 8) BC4 (unsigned) blocks -> (height, width, 1) uint8."""
    return _image(_bc4, blocks, 8, 1, width, height)


def bc5_image(blocks: np.ndarray, width: int, height: int) -> np.ndarray:
    """(n, 16) BC5 (unsigned) blocks -> (height, width, 2) uint8."""
    return _image(_bc5, blocks, 16, 2, width, height)
