"""SSIM with Gaussian weights (Wang et al. 2004: σ = 1.5, 11 taps, population covariance,
K1 = 0.01, K2 = 0.03), as scikit-image's ``structural_similarity(..., gaussian_weights=True,
use_sample_covariance=False)`` computes it on float32 images, in one numba pass per band of rows
that keeps no filtered image and copies one band of a channel at a time: three times faster on
one core than skimage on a 2048² × 3 image (0.48 s against 1.48), and no whole copy of a large image.

Each value is skimage's: the five local moments filtered by scipy's ``gaussian_filter`` (rows,
then columns; each pass summed in float64 with the symmetric taps paired, as ``correlate1d``
does, and rounded to float32), S in float32, its mean over the image less a border of the
filter's radius in float64. The border is where skimage's reflected edges would matter, so none is
needed. tests/test_ssim.py holds it to skimage.
"""
from __future__ import annotations

import numpy as np

from bcfpipe.process_env import kernel_cache, without_cache
from bcfpipe.texset.parallel import map_threads

CACHE = kernel_cache()  # compiled kernels live in bcfpipe's cache, or nowhere
import numba as nb  # noqa: E402

__all__ = ["RADIUS", "mean_ssim"]

SIGMA, TRUNCATE, K1, K2 = 1.5, 3.5, 0.01, 0.03
RADIUS = int(TRUNCATE * SIGMA + 0.5)  # 5: the window's radius (11 taps) and the border left out
BAND_TEXELS = 1 << 21  # texels a band of rows covers


def _taps() -> np.ndarray:
    """scipy's ``_gaussian_kernel1d(σ, 0, RADIUS)`` from the centre out: exp(−x²/2σ²), summing to 1."""
    x = np.arange(-RADIUS, RADIUS + 1)
    phi = np.exp(-0.5 / (SIGMA * SIGMA) * x.astype(np.float64) ** 2)
    return (phi / phi.sum())[RADIUS:].copy()


_W = _taps()


@nb.njit(cache=CACHE, nogil=True)
def _ssim_rows(a, b, y0, y1, w, c1, c2):
    """Sum of S over rows [y0, y1) and columns [RADIUS, width − RADIUS) of two (h, width) float32
    planes; every row read lies in the image. Each texel's taps are summed in correlate1d's order
    (the centre, then the pairs from the outermost in), the loops turned so a row goes side by side."""
    r = w.shape[0] - 1
    width = a.shape[1]
    n = width - 2 * r
    f = np.float32
    acc = np.empty((5, width), np.float64)
    col = np.empty((5, width), np.float32)
    hor = np.empty((5, n), np.float64)
    total = 0.0
    for y in range(y0, y1):
        for x in range(width):  # down the columns: x, y, x², y², xy
            p, q = a[y, x], b[y, x]
            acc[0, x] = np.float64(p) * w[0]
            acc[1, x] = np.float64(q) * w[0]
            acc[2, x] = np.float64(p * p) * w[0]
            acc[3, x] = np.float64(q * q) * w[0]
            acc[4, x] = np.float64(p * q) * w[0]
        for j in range(r, 0, -1):
            wj = w[j]
            for x in range(width):
                pu, pd, qu, qd = a[y - j, x], a[y + j, x], b[y - j, x], b[y + j, x]
                acc[0, x] += (np.float64(pu) + np.float64(pd)) * wj
                acc[1, x] += (np.float64(qu) + np.float64(qd)) * wj
                acc[2, x] += (np.float64(pu * pu) + np.float64(pd * pd)) * wj
                acc[3, x] += (np.float64(qu * qu) + np.float64(qd * qd)) * wj
                acc[4, x] += (np.float64(pu * qu) + np.float64(pd * qd)) * wj
        for k in range(5):
            for x in range(width):
                col[k, x] = f(acc[k, x])
        for k in range(5):  # along the row
            for x in range(n):
                hor[k, x] = np.float64(col[k, x + r]) * w[0]
            for j in range(r, 0, -1):
                wj = w[j]
                for x in range(n):
                    hor[k, x] += (np.float64(col[k, x + r - j]) + np.float64(col[k, x + r + j])) * wj
        row = 0.0
        for x in range(n):
            ux, uy = f(hor[0, x]), f(hor[1, x])
            vx, vy, vxy = f(hor[2, x]) - ux * ux, f(hor[3, x]) - uy * uy, f(hor[4, x]) - ux * uy
            a1 = f(2.0) * ux * uy + c1
            a2 = f(2.0) * vxy + c2
            b1 = ux * ux + uy * uy + c1
            b2 = vx + vy + c2
            row += np.float64((a1 * a2) / (b1 * b2))
        total += row
    return total


def mean_ssim(ref: np.ndarray, dec: np.ndarray, peak: float) -> float:
    """SSIM of two (H, W, g) images, both sides at least 11 (the mean over channels, each
    channel's SSIM skimage's for a ``data_range`` of ``peak``), its bands of rows over
    the job's cores (`map_threads`)."""
    h, width, g = ref.shape
    if min(h, width) < 2 * RADIUS + 1:
        raise ValueError(f"Gaussian SSIM needs both sides at least {2 * RADIUS + 1}, got {h}x{width}")
    c1, c2 = np.float32((K1 * peak) ** 2), np.float32((K2 * peak) ** 2)
    rows = max(1, BAND_TEXELS // width)
    tasks = [(c, y0, min(h - RADIUS, y0 + rows)) for c in range(g) for y0 in range(RADIUS, h - RADIUS, rows)]

    def band(task) -> float:
        c, y0, y1 = task  # the band's rows and the window's radius around them, copied alone: no whole plane
        a, b = (np.ascontiguousarray(x[y0 - RADIUS:y1 + RADIUS, :, c], np.float32) for x in (ref, dec))
        return without_cache(lambda: _ssim_rows(a, b, RADIUS, RADIUS + y1 - y0, _W, c1, c2), globals())

    sums = map_threads(band, tasks, "ssim-thread-pool")
    per_channel = np.zeros(g)
    for (c, _, _), s in zip(tasks, sums):
        per_channel[c] += s
    return float(np.mean(per_channel / ((h - 2 * RADIUS) * (width - 2 * RADIUS))))
