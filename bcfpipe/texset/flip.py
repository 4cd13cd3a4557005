"""LDR-FLIP (Andersson et al., HPG 2020) of an sRGB-encoded colour group, in numba: the error map that
NVlabs' ``flip_evaluator`` computes (its FLIP.h, ``LDR_FLIP`` with separable filters), in the same
float32 operations and summation order, about six times faster on one core.

FLIP was the final measure's largest cost: 6.1 CPU-seconds for one 2048² colour group in
``flip_evaluator``, paid once per colour group by every measured layout. tests/test_flip.py holds
this map to ``flip_evaluator``'s, texel by texel, on real textures and edge cases.

The pipeline (FLIP.h): sRGB → linear RGB → YCxCz; the colour path filters Y, Cx and Cz with the
contrast sensitivity Gaussians (Cz's a sum of two, separated), goes back to linear RGB clamped to
[0, 1], then to CIELab with the Hunt adjustment, and takes the HyAB distance, compressed by
q_c = 0.7 and remapped so that p_c·c_max lands on p_t; the feature path filters Y (as L*/116 + 16/116)
with a Gaussian's first and second derivatives (edges and points); the error is
ΔE_c^(1 − ΔE_f). Filters clamp at the image's edges. The constants, filters and colour transforms
are FLIP.h's (NVIDIA, BSD-3-Clause), read from github.com/NVlabs/flip.
"""
from __future__ import annotations

import math

import numpy as np

from bcfpipe.process_env import kernel_cache, without_cache
from bcfpipe.texset.parallel import map_threads

CACHE = kernel_cache()  # compiled kernels live in bcfpipe's cache, or nowhere
import numba as nb  # noqa: E402

__all__ = ["PPD", "flip_map", "mean_flip"]

_F = np.float32
_PI = _F(3.14159265358979)  # FLIP.h's PI
# calculatePPD(0.7 m, 3840 px, 0.7 m): FLIP's default viewing conditions, 67.0 pixels per degree
PPD = _F(_F(0.7) * _F(_F(3840.0) / _F(0.7)) * _F(_PI / _F(180.0)))
GQC, GPC, GPT, GW, GQF = 0.7, 0.4, 0.95, 0.082, 0.5  # FLIPConstants
BAND_TEXELS = 1 << 20  # texels of one band's rows: its 20 float32 planes take 80 MiB


def _f(x) -> np.float32:
    return _F(x)


def _scaled_gaussian(x2, a, b, root: bool) -> np.float32:
    """FLIP.h's Gaussian(x², a, b) = a·sqrt(π/b)·exp(−π²x²/b); with ``root``, GaussianSqrt, whose
    a·sqrt(π/b) is square-rooted (the two Gaussians of Cz's filter separated)."""
    pi_sq = _f(_PI * _PI)
    scale = _f(_f(a) * _f(np.sqrt(_f(_PI / _f(b)))))
    return _f((_f(np.sqrt(scale)) if root else scale) * _f(np.exp(_f(_f(-pi_sq * _f(x2)) / _f(b)))))


def spatial_filters(ppd: float = PPD) -> np.ndarray:
    """(4, 2r + 1) float32 taps (FLIP.h ``setSpatialFilters``): Y's and Cx's Gaussians, each summing
    to 1, and Cz's two separated Gaussians, normalised together; r from the widest Gaussian
    (``calculateSpatialFilterRadius``: 10 at 67 pixels per degree)."""
    ppd = _f(ppd)
    pi_sq = _f(_PI * _PI)
    r = int(math.ceil(_f(_f(_f(3.0) * _f(np.sqrt(_f(_f(0.04) / _f(_f(2.0) * pi_sq))))) * ppd)))
    taps = np.zeros((4, 2 * r + 1), np.float32)
    for x in range(2 * r + 1):
        ix = _f(_f(x - r) * _f(_f(1.0) / ppd))
        ix2 = _f(ix * ix)
        taps[:, x] = (_scaled_gaussian(ix2, 1.0, 0.0047, False), _scaled_gaussian(ix2, 1.0, 0.0053, False),
                      _scaled_gaussian(ix2, 34.1, 0.04, True), _scaled_gaussian(ix2, 13.5, 0.025, True))
    sums = np.zeros(4, np.float32)
    for x in range(2 * r + 1):  # float32, in order, as FLIP.h sums
        sums += taps[:, x]
    taps[0] *= _f(1.0) / sums[0]
    taps[1] *= _f(1.0) / sums[1]
    taps[2:] *= _f(1.0) / _f(np.sqrt(_f(sums[2] * sums[2] + sums[3] * sums[3])))
    return taps


def feature_filter(ppd: float = PPD) -> np.ndarray:
    """(3, 2r + 1) float32 taps (FLIP.h ``setFeatureFilter``): a Gaussian of σ = w·ppd/2 summing to 1,
    its first and second derivatives with their positive and negative taps each summing to ±1."""
    sd = _f(_f(_f(0.5) * _f(GW)) * _f(ppd))
    r = int(math.ceil(_f(_f(3.0) * sd)))
    taps = np.zeros((3, 2 * r + 1), np.float32)
    g_sum = d_pos = d_neg = dd_pos = dd_neg = _f(0.0)
    for x in range(2 * r + 1):
        xx = _f(x - r)
        g = _f(np.exp(_f(_f(-(xx * xx)) / _f(_f(2.0) * sd * sd))))
        dg = _f(-xx * g)
        ddg = _f(_f(_f(xx * xx) / _f(sd * sd) - _f(1.0)) * g)
        g_sum = _f(g_sum + g)
        d_pos, d_neg = (_f(d_pos + dg), d_neg) if dg > 0 else (d_pos, _f(d_neg - dg))
        dd_pos, dd_neg = (_f(dd_pos + ddg), dd_neg) if ddg > 0 else (dd_pos, _f(dd_neg - ddg))
        taps[:, x] = (g, dg, ddg)
    for x in range(2 * r + 1):
        g, dg, ddg = taps[:, x]
        taps[:, x] = (g / g_sum, dg / (d_pos if dg > 0 else d_neg), ddg / (dd_pos if ddg > 0 else dd_neg))
    return taps


# linear RGB → XYZ (D65), FLIP.h LinearRGBToXYZ; the kernels read both as constants
_M = np.array([[10135552.0 / 24577794.0, 8788810.0 / 24577794.0, 4435075.0 / 24577794.0],
               [2613072.0 / 12288897.0, 8788810.0 / 12288897.0, 887015.0 / 12288897.0],
               [1425312.0 / 73733382.0, 8788810.0 / 73733382.0, 70074185.0 / 73733382.0]], np.float32)
_INV_WHITE = np.array([1.052156925, 1.0, 0.918357670], np.float32)  # INV_DEFAULT_ILLUMINANT


def _lab_hunt_py(rgb) -> tuple[np.float32, np.float32, np.float32]:
    """A linear RGB colour in CIELab with the Hunt-adjusted a* and b* (for ``colour_cap``)."""
    d = _f(_f(6.0) / _f(29.0))
    cube, factor, term = _f(d * _f(d * d)), _f(_f(1.0) / _f(_f(3.0) * _f(d * d))), _f(_f(4.0) / _f(29.0))
    v = []
    for i in range(3):
        x = _f(_f(_f(_f(_M[i, 0] * _f(rgb[0])) + _f(_M[i, 1] * _f(rgb[1]))) + _f(_M[i, 2] * _f(rgb[2]))) * _INV_WHITE[i])
        v.append(_f(np.power(x, _f(_f(1.0) / _f(3.0)))) if x > cube else _f(_f(factor * x) + term))
    lum = _f(_f(116.0) * v[1] - _f(16.0))
    a, b = _f(_f(500.0) * _f(v[0] - v[1])), _f(_f(200.0) * _f(v[1] - v[2]))
    return lum, _f(_f(_f(0.01) * lum) * a), _f(_f(_f(0.01) * lum) * b)


def colour_cap() -> tuple[np.float32, np.float32]:
    """(c_max, p_c·c_max): the compressed HyAB distance of pure green to pure blue, FLIP's largest
    colour difference (FLIP.h ``computeMaxDistance``), and where its remap bends."""
    g, b = _lab_hunt_py((0.0, 1.0, 0.0)), _lab_hunt_py((0.0, 0.0, 1.0))
    hyab = _f(abs(_f(g[0] - b[0])) + _f(np.sqrt(_f(_f(_f(g[1] - b[1]) ** 2) + _f(_f(g[2] - b[2]) ** 2)))))
    cmax = _f(np.power(hyab, _f(GQC)))
    return cmax, _f(_f(GPC) * cmax)


@nb.njit(inline="always", cache=CACHE, nogil=True)
def _linear(c):
    """sRGB → linear (FLIP.h sRGBToLinearRGB), clamped to [0, 1] as ``evaluate`` clamps its input."""
    v = c / np.float32(12.92) if c <= np.float32(0.04045) else ((c + np.float32(0.055)) / np.float32(1.055)) ** np.float32(2.4)
    return min(max(v, np.float32(0.0)), np.float32(1.0))


@nb.njit(cache=CACHE, nogil=True)
def _to_ycxcz(img, out):
    """(h, w, 3) sRGB in [0, 1] → (3, h, w) YCxCz (XYZToYCxCz of LinearRGBToXYZ)."""
    h, w = img.shape[0], img.shape[1]
    m, inv_white = _M, _INV_WHITE
    for y in range(h):
        for x in range(w):
            r, g, b = _linear(img[y, x, 0]), _linear(img[y, x, 1]), _linear(img[y, x, 2])
            cx = (m[0, 0] * r + m[0, 1] * g + m[0, 2] * b) * inv_white[0]
            cy = (m[1, 0] * r + m[1, 1] * g + m[1, 2] * b) * inv_white[1]
            cz = (m[2, 0] * r + m[2, 1] * g + m[2, 2] * b) * inv_white[2]
            out[0, y, x] = np.float32(116.0) * cy - np.float32(16.0)
            out[1, y, x] = np.float32(500.0) * (cx - cy)
            out[2, y, x] = np.float32(200.0) * (cy - cz)


@nb.njit(inline="always", cache=CACHE, nogil=True)
def _lab_hunt(lum, cx, cz):
    """A filtered YCxCz colour back to linear RGB clamped to [0, 1], then CIELab with the Hunt
    adjustment (FLIP.h YCxCzToXYZ, XYZToLinearRGB, clamp, LinearRGBToXYZ, XYZToCIELab, Hunt)."""
    f = np.float32
    m, inv_white = _M, _INV_WHITE
    yy = (lum + f(16.0)) / f(116.0)
    x0 = (yy + cx / f(500.0)) * f(0.950428545)
    y0 = yy * f(1.0)
    z0 = (yy - cz / f(200.0)) * f(1.088900371)
    r = min(max(f(3.241003275) * x0 + f(-1.537398934) * y0 + f(-0.498615861) * z0, f(0.0)), f(1.0))
    g = min(max(f(-0.969224334) * x0 + f(1.875930071) * y0 + f(0.041554224) * z0, f(0.0)), f(1.0))
    b = min(max(f(0.055639423) * x0 + f(-0.204011202) * y0 + f(1.057148933) * z0, f(0.0)), f(1.0))
    vx = (m[0, 0] * r + m[0, 1] * g + m[0, 2] * b) * inv_white[0]
    vy = (m[1, 0] * r + m[1, 1] * g + m[1, 2] * b) * inv_white[1]
    vz = (m[2, 0] * r + m[2, 1] * g + m[2, 2] * b) * inv_white[2]
    d = f(6.0) / f(29.0)
    cube = d * (d * d)
    factor = f(1.0) / (f(3.0) * (d * d))
    term = f(4.0) / f(29.0)
    third = f(1.0) / f(3.0)
    vx = vx ** third if vx > cube else factor * vx + term
    vy = vy ** third if vy > cube else factor * vy + term
    vz = vz ** third if vz > cube else factor * vz + term
    big_l = f(116.0) * vy - f(16.0)
    return big_l, f(0.01) * big_l * (f(500.0) * (vx - vy)), f(0.01) * big_l * (f(200.0) * (vy - vz))


# the passes: accumulator k sums taps[TAPS[k]] times padded row ROWS[k] (along a row) or plane
# PLANES[k] (down the columns). Colour: Y, Cx and Cz's two Gaussians of the reference, then the
# test's. Features: along a row each image's first and second derivative and Gaussian; down the
# columns its x-derivatives under the Gaussian, then its Gaussian under the y-derivatives
_COLOUR_TAPS, _COLOUR_PLANES = np.array([0, 1, 2, 3, 0, 1, 2, 3]), np.arange(8)
_COLOUR_ROWS = np.array([0, 1, 2, 2, 3, 4, 5, 5])
_FEATURE_ROW_TAPS, _FEATURE_ROWS = np.array([1, 2, 0, 1, 2, 0]), np.array([0, 0, 0, 1, 1, 1])
_FEATURE_TAPS, _FEATURE_PLANES = np.array([0, 0, 0, 0, 1, 1, 2, 2]), np.array([0, 3, 1, 4, 2, 5, 2, 5])


@nb.njit(inline="always", cache=CACHE, nogil=True)
def _across(pad, taps, tap_of, row_of, acc):
    """One row's pass along it into ``acc`` (one accumulator per ``tap_of``): ``pad`` holds the rows
    with their edge texels repeated by the filter's radius."""
    w = acc.shape[1]
    n = tap_of.shape[0]
    acc[:n] = 0
    for t in range(taps.shape[1]):
        for k in range(n):
            wt = taps[tap_of[k], t]
            q = row_of[k]
            for x in range(w):
                acc[k, x] += wt * pad[q, x + t]


@nb.njit(inline="always", cache=CACHE, nogil=True)
def _down(mid, y, taps, tap_of, plane_of, acc):
    """Row ``y`` of the column pass into ``acc`` (8, w): each texel's taps summed in FLIP.h's order,
    the rows clamped at the image's edges."""
    h, w = mid.shape[1], mid.shape[2]
    r = taps.shape[1] // 2
    acc[:] = 0
    for t in range(2 * r + 1):
        yy = min(max(0, y + t - r), h - 1)
        for k in range(8):
            wt = taps[tap_of[k], t]
            p = plane_of[k]
            for x in range(w):
                acc[k, x] += wt * mid[p, yy, x]


@nb.njit(cache=CACHE, nogil=True)
def _error(ref, tst, ws, wf, cmax, pccmax, out):
    """FLIP of YCxCz planes ``ref`` and ``tst`` (3, h, w) into ``out`` (h, w) (FLIP.h
    computeColorDifference, then computeFeatureDifferenceAndFinalError). Each filter tap is summed
    in FLIP.h's order, its loops turned so that a row's texels go side by side."""
    f = np.float32
    h, w = ref.shape[1], ref.shape[2]
    rs = ws.shape[1] // 2
    rf = wf.shape[1] // 2
    r = max(rs, rf)
    pad = np.empty((6, w + 2 * r), np.float32)
    acc = np.empty((8, w), np.float32)
    mid = np.empty((8, h, w), np.float32)
    # colour: rows (x), then columns (y) and the colour difference
    for y in range(h):
        for x in range(w + 2 * rs):
            xx = min(max(0, x - rs), w - 1)
            for c in range(3):
                pad[c, x] = ref[c, y, xx]
                pad[3 + c, x] = tst[c, y, xx]
        _across(pad, ws, _COLOUR_TAPS, _COLOUR_ROWS, acc)
        mid[:, y, :] = acc
    gpt, gqc = f(GPT), f(GQC)
    for y in range(h):
        _down(mid, y, ws, _COLOUR_TAPS, _COLOUR_PLANES, acc)
        for x in range(w):
            l1, a1, b1 = _lab_hunt(acc[0, x], acc[1, x], acc[2, x] + acc[3, x])
            l2, a2, b2 = _lab_hunt(acc[4, x], acc[5, x], acc[6, x] + acc[7, x])
            cd = (abs(l1 - l2) + np.sqrt((a1 - a2) * (a1 - a2) + (b1 - b2) * (b1 - b2))) ** gqc
            if cd < pccmax:
                cd *= gpt / pccmax
            else:
                cd = gpt + ((cd - pccmax) / (cmax - pccmax)) * (f(1.0) - gpt)
            out[y, x] = cd
    # features: Y as [0, 1]; rows with the derivatives and the Gaussian, then columns
    o116, s116 = f(1.0) / f(116.0), f(16.0) / f(116.0)
    for y in range(h):
        for x in range(w + 2 * rf):
            xx = min(max(0, x - rf), w - 1)
            pad[0, x] = ref[0, y, xx] * o116 + s116
            pad[1, x] = tst[0, y, xx] * o116 + s116
        _across(pad, wf, _FEATURE_ROW_TAPS, _FEATURE_ROWS, acc)
        mid[:6, y, :] = acc[:6]
    norm, gqf = f(1.0) / np.sqrt(f(2.0)), f(GQF)
    for y in range(h):
        _down(mid, y, wf, _FEATURE_TAPS, _FEATURE_PLANES, acc)
        for x in range(w):
            edge_r = np.sqrt(acc[0, x] * acc[0, x] + acc[4, x] * acc[4, x])
            edge_t = np.sqrt(acc[1, x] * acc[1, x] + acc[5, x] * acc[5, x])
            point_r = np.sqrt(acc[2, x] * acc[2, x] + acc[6, x] * acc[6, x])
            point_t = np.sqrt(acc[3, x] * acc[3, x] + acc[7, x] * acc[7, x])
            fd = (norm * max(abs(edge_r - edge_t), abs(point_r - point_t))) ** gqf
            out[y, x] = out[y, x] ** (f(1.0) - fd)


_WS, _WF = spatial_filters(), feature_filter()
_CAP = colour_cap()
HALO = max(_WS.shape[1], _WF.shape[1]) // 2  # rows a band reads beyond its own: the widest filter's radius


def flip_map(ref: np.ndarray, test: np.ndarray) -> np.ndarray:
    """(h, w) float32 LDR-FLIP errors of two (h, w, 3) sRGB-encoded images (clamped to [0, 1])."""
    h, w = ref.shape[:2]
    planes = np.empty((2, 3, h, w), np.float32)
    out = np.empty((h, w), np.float32)
    cmax, pccmax = _CAP

    def run():
        for i, img in enumerate((ref, test)):
            _to_ycxcz(np.ascontiguousarray(img, np.float32), planes[i])
        _error(planes[0], planes[1], _WS, _WF, cmax, pccmax, out)

    without_cache(run, globals())
    return out


def mean_flip(ref: np.ndarray, test: np.ndarray) -> float:
    """Mean LDR-FLIP of two (H, W, 3) sRGB-encoded images, in bands of rows over `encode_workers()`
    threads: each band reads `HALO` rows beyond its own, so every error is the whole image's."""
    h, w = ref.shape[:2]
    rows = max(4 * HALO, BAND_TEXELS // max(w, 1))
    starts = list(range(0, h, rows))

    def band(y0: int) -> float:
        y1 = min(h, y0 + rows)
        a, b = max(0, y0 - HALO), min(h, y1 + HALO)
        err = flip_map(ref[a:b], test[a:b])
        return float(err[y0 - a:y1 - a].sum(dtype=np.float64))

    return sum(map_threads(band, starts, "flip-thread-pool")) / (h * w)
