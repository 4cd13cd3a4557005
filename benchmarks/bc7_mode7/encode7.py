"""BC7 mode-7 encoder and the per-block choice between modes 6 and 7 (vectorized numpy), issue 29's
measurement of the partitioned modes (benchmarks/bound_t0.py, docs/benchmarks.md); the feature
textures bcfpipe trains are mode 6.

Mode 7 (:mod:`bc7_mode7.mode7`) splits a block into two subsets by one of 64 shapes. Shapes are
ranked by how well one line per subset fits the texels (the residual off each subset's principal
axis, from masked second moments). The best :data:`SHAPES_TRIED` are encoded in full, as the
mode-6 encoder does (principal-axis endpoints, then alternating nearest-index choice and
least-squares refits, errors measured on the integer decode), and the block keeps whichever of
them, or of its mode-6 encoding, decodes closest. One shape is tried: on the teapot's and the
brick's principal components four gain nothing over one (benchmarks/bound_t0.py).
"""
from __future__ import annotations

import numpy as np

from bcfpipe.bc7 import mode6
from bcfpipe.bc7.encode import encode_params as _encode6, nearest_with_pbit, principal_endpoints, refit_endpoints
from bcfpipe.bptc import PARTITIONS2

from . import mode7
from .modes import MODE6

__all__ = ["encode_params", "quantize_endpoints", "shape_order"]

SHAPES_TRIED = 1
#: A block takes mode 7 when its error is below this fraction of its mode-6 error.
MODE7_MARGIN = 1.0
ROUNDS = 4
_CHUNK = 1 << 12
_V6 = np.arange(64)
_WIDE = mode7.widen(_V6).astype(np.float64)  # the 64 representable 8-bit values


def quantize_endpoints(e: np.ndarray) -> np.ndarray:
    """Continuous 8-bit-domain endpoints (..., 4) -> the nearest widened mode-7 values (..., 4)
    uint8: for p in {0, 1} each channel takes the nearest widened 6-bit value with low bit p (ties
    to the smaller); the p with the smaller squared error wins (ties to p = 0)."""
    def grid(v, p):
        g = _WIDE[p::2]  # 32 values, increasing
        k = np.clip(np.searchsorted(g, v), 1, 31)
        lo, hi = g[k - 1], g[k]
        return np.where(v - lo <= hi - v, lo, hi)

    return nearest_with_pbit(e, grid)


def shape_order(x: np.ndarray) -> np.ndarray:
    """(n, 16, 4) texels -> (n, 64) shapes, best first, by the summed off-line residual of the two
    subsets (trace minus largest eigenvalue of each subset's scatter matrix)."""
    n = len(x)
    m1 = PARTITIONS2.astype(np.float64)  # (64, 16)
    outer = np.einsum("nti,ntj->ntij", x, x)
    tot1, tot2 = x.sum(1), outer.sum(1)
    s1 = m1 @ x  # (n, 64, 4)
    s2 = (m1 @ outer.reshape(n, 16, 16)).reshape(n, 64, 4, 4)
    c1 = m1.sum(1)[None, :, None]
    resid = np.zeros((n, 64))
    for a1, a2, cnt in ((s1, s2, c1), (tot1[:, None] - s1, tot2[:, None] - s2, 16.0 - c1)):
        scatter = a2 - np.einsum("npi,npj->npij", a1, a1) / cnt[..., None]
        resid += np.trace(scatter, axis1=2, axis2=3) - _largest_eigenvalue(scatter)
    return np.argsort(resid, axis=1, kind="stable")


def _largest_eigenvalue(s: np.ndarray) -> np.ndarray:
    """Largest eigenvalue of symmetric positive semi-definite 4x4 matrices, by power iteration from
    the column of the largest diagonal entry (never orthogonal to the top eigenvector unless the
    matrix is zero); enough to rank shapes, 4x faster than eigvalsh."""
    j = np.argmax(np.diagonal(s, axis1=-2, axis2=-1), -1)
    v = np.take_along_axis(s, j[..., None, None], -1)[..., 0]
    for _ in range(8):
        v = v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-30)
        v = np.einsum("...ij,...j->...i", s, v)
    u = v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-30)
    return np.einsum("...i,...ij,...j->...", u, s, u)


def _encode_shape(x: np.ndarray, w: np.ndarray, shape: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mode-7 encoding of every block with its given shape -> (endpoints (n, 4, 4), indices, error)."""
    sub = PARTITIONS2[shape].astype(np.int64)  # (n, 16)
    rows = np.arange(len(x))[:, None]
    cont = np.concatenate([principal_endpoints(x, sub == 0), principal_endpoints(x, sub == 1)], 1)  # (n, 4, 4)
    best_e = best_i = best_err = None
    for _ in range(ROUNDS + 1):
        e = quantize_endpoints(cont).astype(np.int32)
        pal = ((64 - mode7.WEIGHTS2[None, None, :, None]) * e[:, [0, 2], None] +
               mode7.WEIGHTS2[None, None, :, None] * e[:, [1, 3], None] + 32) >> 6  # (n, 2, 4 entries, 4)
        mine = pal[rows, sub]  # (n, 16, 4 entries, 4)
        d = (((mine / 255.0 - x[:, :, None] / 255.0) ** 2) * w).sum(-1)
        idx = d.argmin(-1)
        err = np.take_along_axis(d, idx[..., None], -1)[..., 0].sum(-1)
        if best_err is None:
            best_e, best_i, best_err = e, idx, err
        else:
            take = err < best_err
            best_e = np.where(take[:, None, None], e, best_e)
            best_i = np.where(take[:, None], idx, best_i)
            best_err = np.where(take, err, best_err)
        t = mode7.WEIGHTS2[idx] / 64.0
        cont = np.concatenate([refit_endpoints(x, t, sub == 0, cont[:, :2]), refit_endpoints(x, t, sub == 1, cont[:, 2:])], 1)
    return best_e.astype(np.uint8), best_i.astype(np.uint8), best_err


def _mode6_error(x: np.ndarray, w: np.ndarray, e: np.ndarray, idx: np.ndarray) -> np.ndarray:
    dec = mode6.interpolate(e, idx).astype(np.float64)
    return (((dec - x) / 255.0) ** 2 * w).sum((1, 2))


def _encode_chunk(x: np.ndarray, w: np.ndarray, shapes: int, margin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = len(x)
    e6, i6 = _encode6(x / 255.0, w)
    best_e = np.zeros((n, 4, 4), np.uint8)
    best_e[:, :2] = e6
    best_i, best_p = i6.copy(), np.full(n, MODE6, np.int64)
    err6 = _mode6_error(x, w, e6, i6)
    best_err = err6 * margin
    order = shape_order(x) if shapes else None
    for k in range(shapes):
        e7, i7, err = _encode_shape(x, w, order[:, k])
        take = err < best_err
        best_e[take], best_i[take], best_p[take], best_err[take] = e7[take], i7[take], order[take, k], err[take]
    return best_e, best_i, best_p


def encode_params(texels: np.ndarray, weights: np.ndarray | None = None,
                  shapes: int = SHAPES_TRIED, margin: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, 16, 4) texels in [0, 1] -> :mod:`bc7_mode7.modes` parameters (endpoints (n, 4, 4),
    indices (n, 16), partition (n,)), before the anchor fix. ``weights`` (4,): per-channel error
    weights (default equal); ``shapes``: mode-7 shapes encoded in full per block (0: mode 6 only);
    ``margin``: mode 7 is taken below this fraction of the mode-6 error (default MODE7_MARGIN)."""
    margin = MODE7_MARGIN if margin is None else margin
    x = np.clip(np.asarray(texels, np.float64).reshape(-1, 16, 4), 0.0, 1.0) * 255.0
    w = np.ones(4) if weights is None else np.asarray(weights, np.float64).reshape(4)
    parts = [_encode_chunk(x[s:s + _CHUNK], w, shapes, margin) for s in range(0, len(x), _CHUNK)]
    if not parts:
        return np.zeros((0, 4, 4), np.uint8), np.zeros((0, 16), np.uint8), np.zeros(0, np.int64)
    return tuple(np.concatenate(a) for a in zip(*parts))
