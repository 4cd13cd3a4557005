"""The oracle's inner loop in numba (issue 58): a small mip magnified bilinearly to a finer one and
its peak-normalised squared error per channel, in one pass over the texels measured, with no
magnified image or gathered copy made.

Each texel is `layout.classic.magnify`'s (GL's LINEAR filter at the target's texel centres, the taps
addressed as `formats.addressing.address` does, the weights in float32), and its error is
`texset.metrics.mse_per_channel`'s: an HDR channel in its log domain (`texset.encoding.encode`),
the difference in float64. The oracle runs once for every T_0 size a layout weighs, seven times a
2048² set; in numpy each pass took 0.2 s, most of the brick's 1.5 s before its layout was decided.
"""
from __future__ import annotations

import numpy as np

from bcfpipe.formats.addressing import WRAP_CODES, wrap_codes
from bcfpipe.formats.vocabulary import Wrap
from bcfpipe.process_env import kernel_cache, without_cache

CACHE = kernel_cache()  # compiled kernels live in bcfpipe's cache, or nowhere
import numba as nb  # noqa: E402

__all__ = ["magnified_sse"]


_REPEAT, _MIRROR = WRAP_CODES[Wrap.REPEAT], WRAP_CODES[Wrap.MIRROR]


@nb.njit(inline="always", cache=CACHE, nogil=True)
def _address(i, n, mode):
    """`formats.addressing.address` for one texel, by `WRAP_CODES`. The fused kernel has its own: numba's
    cache does not see a change to a kernel it inlines from another file, so each module keeps its own."""
    if mode == _REPEAT:
        return i % n
    if mode == _MIRROR:
        j = i % (2 * n)
        return j if j < n else 2 * n - 1 - j
    return min(max(i, 0), n - 1)


@nb.njit(inline="always", cache=CACHE, nogil=True)
def _tap(at, n_out, n_in, mode):
    """`classic._taps` for one target texel: the two source texels and the second one's weight."""
    x = (at + 0.5) * n_in / n_out - 0.5
    x0 = np.floor(x)
    f = np.float32(x - x0)
    i = np.int64(x0)
    return _address(i, n_in, mode), _address(i + 1, n_in, mode), f


@nb.njit(inline="always", cache=CACHE, nogil=True)
def _learnt(v, g):
    """`texset.encoding.encode` for one value (g > 0)."""
    return np.float32(np.log2(1.0 + max(np.float64(v), 0.0) * (np.exp2(np.float64(g)) - 1.0)) / g)


@nb.njit(cache=CACHE, nogil=True)
def _sse(src, truth, picks, mask, gains, wrap_s, wrap_t, out):
    """Squared errors of ``src`` magnified to ``truth``'s size against ``truth``, summed per channel
    into ``out``, over the row-major texels ``picks`` (every texel when empty) that ``mask`` keeps
    (every one when it is empty); returns how many were summed."""
    h, w, c = truth.shape
    hs, ws = src.shape[0], src.shape[1]
    n = picks.shape[0] if picks.shape[0] else h * w
    count = 0
    for p in range(n):
        t = picks[p] if picks.shape[0] else p
        if mask.shape[0] and not mask[t]:
            continue
        y, x = t // w, t % w
        ya, yb, fy = _tap(y, h, hs, wrap_t)
        xa, xb, fx = _tap(x, w, ws, wrap_s)
        for k in range(c):
            top = src[ya, xa, k] * (np.float32(1) - fx) + src[ya, xb, k] * fx
            v = top * (np.float32(1) - fy) + (src[yb, xa, k] * (np.float32(1) - fx) + src[yb, xb, k] * fx) * fy
            r = truth[y, x, k]
            if gains[k] > 0:
                v, r = _learnt(v, gains[k]), _learnt(r, gains[k])
            d = np.float64(v) - np.float64(r)
            out[k] += d * d
        count += 1
    return count


def magnified_sse(src: np.ndarray, truth: np.ndarray, picks: np.ndarray | None, mask: np.ndarray | None,
                  gains: np.ndarray, wrap) -> tuple[np.ndarray, int]:
    """(per channel, the sum of squared errors; the texels summed) of ``src`` ((h, w, C) float32)
    magnified to ``truth``'s (H, W, C) with ``wrap`` (one mode or the (S, T) pair), over ``picks``
    (row-major texels of ``truth``; None: all) that ``mask`` ((H, W) bool; None: all) keeps, the
    channels with a gain (``gains``, per channel) in their log domain."""
    out = np.zeros(truth.shape[2])
    none = np.zeros(0, np.int64)
    s, t = wrap_codes(wrap)
    args = (np.ascontiguousarray(src, np.float32), np.ascontiguousarray(truth, np.float32),
            none if picks is None else np.ascontiguousarray(picks, np.int64),
            np.zeros(0, bool) if mask is None else np.ascontiguousarray(mask).reshape(-1),
            np.ascontiguousarray(gains, np.float32), s, t, out)
    count = without_cache(lambda: _sse(*args), globals())
    return out, int(count)
