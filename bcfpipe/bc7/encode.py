"""BC7 mode-6 encoder (vectorized numpy): principal-axis endpoints, then alternating index choice
and least-squares endpoint refits, with the p-bits searched exactly.

Each round quantizes the continuous endpoints of every block with :func:`quantize_endpoints`
(per endpoint, the p-bit whose 7-bit grid lies nearest), picks each texel's index as the nearest
of the 16 palette entries the spec decoder would produce (integer interpolation, so the error is
the decoded error), and refits the endpoints in closed form for those indices. The best
quantized result over all rounds is kept, block by block.
"""
from __future__ import annotations

import numpy as np

from . import mode6

__all__ = ["encode", "encode_params", "quantize_endpoints"]

ROUNDS = 4
_CHUNK = 1 << 14  # blocks per pass: bounds the (n, 16, 16) palette distances to ~64 MB


def quantize_endpoints(e: np.ndarray) -> np.ndarray:
    """Continuous 8-bit-domain endpoints (..., 4) -> the nearest mode-6 endpoints (..., 4) uint8:
    for p in {0, 1}, each channel rounds to the nearest value of 2k + p in [p, 254 + p]; the p
    with the smaller squared error wins (ties to p = 0)."""
    return nearest_with_pbit(e, lambda v, p: np.clip(2.0 * np.floor((v - p) / 2.0 + 0.5) + p, p, 254 + p))


def nearest_with_pbit(e: np.ndarray, grid) -> np.ndarray:
    """Per endpoint (..., 4), the p-bit whose ``grid(v, p)`` (each channel's nearest representable
    value with that low bit) lies nearer in squared error, ties to p = 0 -> uint8 values."""
    v = np.clip(np.asarray(e, np.float64), 0.0, 255.0)
    best, best_err = None, None
    for p in (0, 1):
        q = grid(v, p)
        err = ((q - v) ** 2).sum(-1)
        if best is None:
            best, best_err = q, err
        else:
            take = err < best_err
            best = np.where(take[..., None], q, best)
            best_err = np.where(take, err, best_err)
    return best.astype(np.uint8)


def _pick_indices(texels: np.ndarray, endpoints: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest decoded palette entry per texel -> (indices (n, 16), weighted squared error (n,))."""
    e = endpoints.astype(np.int32)
    w = mode6.WEIGHTS4[None, :, None]
    palette = ((64 - w) * e[:, None, 0] + w * e[:, None, 1] + 32) >> 6  # (n, 16 entries, 4)
    d = (((palette[:, None, :, :] / 255.0 - texels[:, :, None, :]) ** 2) * weights).sum(-1)  # (n, 16, 16)
    idx = d.argmin(-1)
    return idx.astype(np.uint8), np.take_along_axis(d, idx[..., None], -1)[..., 0].sum(-1)


def principal_endpoints(x: np.ndarray, member: np.ndarray) -> np.ndarray:
    """Per block, endpoints (n, 2, 4) at the extremes of the member texels' principal axis; ``x``
    (n, 16, 4) in the 8-bit domain, ``member`` (n, 16) bool (mode 6: all; mode 7: one subset)."""
    m = member[..., None].astype(np.float64)
    cnt = np.maximum(m.sum(1), 1.0)
    mean = (m * x).sum(1) / cnt
    c = (x - mean[:, None]) * m
    cov = np.einsum("nki,nkj->nij", c, c)
    # power iteration from the texel farthest from the mean (a fixed start such as (1, 1, 1, 1)
    # is orthogonal to some blocks' axis and would collapse them to their mean)
    far = np.linalg.norm(c, axis=2).argmax(1)
    axis = c[np.arange(len(x)), far]
    axis = axis / np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-12)
    for _ in range(8):
        axis = np.einsum("nij,nj->ni", cov, axis)
        axis /= np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-12)
    proj = np.einsum("nki,ni->nk", x - mean[:, None], axis)
    lo = np.where(member, proj, np.inf).min(1)
    hi = np.where(member, proj, -np.inf).max(1)
    return np.stack([mean + lo[:, None] * axis, mean + hi[:, None] * axis], 1)


def refit_endpoints(x: np.ndarray, t: np.ndarray, member: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Least-squares endpoints (n, 2, 4), 8-bit domain, of the member texels for fixed weights
    t = w / 64: minimise sum ||(1 - t) e0 + t e1 - x||^2 per block in closed form (``fallback``
    where the system is singular)."""
    a, b = (1.0 - t) * member, t * member
    aa, ab, bb = (a * (1.0 - t)).sum(1), (a * t).sum(1), (b * t).sum(1)
    ax, bx = (a[..., None] * x).sum(1), (b[..., None] * x).sum(1)
    det = aa * bb - ab * ab
    ok = np.abs(det) > 1e-9
    safe = np.where(ok, det, 1.0)[:, None]
    out = np.stack([(bb[:, None] * ax - ab[:, None] * bx) / safe, (aa[:, None] * bx - ab[:, None] * ax) / safe], 1)
    return np.where(ok[:, None, None], out, fallback)


def _initial(texels: np.ndarray) -> np.ndarray:
    return principal_endpoints(texels * 255.0, np.ones(texels.shape[:2], bool))


def _refit(texels: np.ndarray, indices: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    t = mode6.WEIGHTS4[indices.astype(np.int64)] / 64.0
    return refit_endpoints(texels * 255.0, t, np.ones(t.shape, np.float64), fallback)


def _encode_chunk(texels: np.ndarray, weights: np.ndarray, rounds: int) -> tuple[np.ndarray, np.ndarray]:
    cont = _initial(texels)
    best_e = best_i = best_err = None
    for _ in range(rounds + 1):
        e = quantize_endpoints(cont)
        idx, err = _pick_indices(texels, e, weights)
        if best_err is None:
            best_e, best_i, best_err = e, idx, err
        else:
            take = err < best_err
            best_e = np.where(take[:, None, None], e, best_e)
            best_i = np.where(take[:, None], idx, best_i)
            best_err = np.where(take, err, best_err)
        cont = _refit(texels, idx, cont)
    return best_e, best_i


def encode_params(texels: np.ndarray, weights: np.ndarray | None = None,
                  rounds: int = ROUNDS) -> tuple[np.ndarray, np.ndarray]:
    """(n, 16, 4) texels in [0, 1] -> (endpoints (n, 2, 4) uint8, indices (n, 16) uint8) of mode-6
    blocks, before the anchor fix. ``weights`` (4,): per-channel error weights (default equal)."""
    x = np.clip(np.asarray(texels, np.float64).reshape(-1, 16, 4), 0.0, 1.0)
    w = np.ones(4) if weights is None else np.asarray(weights, np.float64).reshape(4)
    es, ids = [], []
    for s in range(0, len(x), _CHUNK):
        e, i = _encode_chunk(x[s:s + _CHUNK], w, rounds)
        es.append(e)
        ids.append(i)
    if not es:
        return np.zeros((0, 2, 4), np.uint8), np.zeros((0, 16), np.uint8)
    return np.concatenate(es), np.concatenate(ids)


def encode(image: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 4) image in [0, 1], H and W multiples of 4 -> (n, 16) uint8 mode-6 blocks, row-major."""
    img = np.asarray(image)
    h, w = img.shape[:2]
    if h % 4 or w % 4 or img.ndim != 3 or img.shape[2] != 4:
        raise ValueError(f"BC7 encode needs an (H, W, 4) image with H, W multiples of 4, got {img.shape}")
    texels = img.reshape(h // 4, 4, w // 4, 4, 4).transpose(0, 2, 1, 3, 4).reshape(-1, 16, 4)
    return mode6.pack(*encode_params(texels, weights))
