"""How far the GLSL decoder may differ from the ONNX path at each sample point.

Tolerance (``glsl``), per sample point p and output channel c, derived from the material itself:

  * The two paths decode identical BC6H texels (bit-exact fp16 on both sides; Mesa's -0 for signed
    texels that round to zero is the same value) and use identical fp16 weights, so they differ only
    by (a) the filtering precision of the texture unit and (b) fp32 rounding.
  * (a) Texture units fix the bilinear sub-texel fractions and the mip blend fraction to limited
    precision; 8 fractional bits is the norm (D3D11 requires 8 sub-texel bits; NVIDIA documents
    9-bit weights with 8 fractional bits). We allow an error of delta = 2^-FILTER_BITS (one full step:
    rounding or truncation) on each fraction that is not exactly on that fixed-point grid (texel
    centres and edges of power-of-two levels and exact lods are). Bilinear filtering is exactly
    ``B = t00 + fx*dx + fy*dy + fx*fy*cross``, so a fraction error moves a layer's 3 features along
    the vector dB/dfx (resp. dB/dfy) of the cell it falls in, and a mip-blend error along
    B_k+1 - B_k; the remaining terms are second order (delta^2 * cross, delta * bilinear error).
  * Through the MLP: hidden units that are active with a margin larger than their possible input
    change form the exact linear map J = diag(out_scale) W2 diag(active) W1 (fp16 weights), and each
    first-order term contributes delta * max over its candidate cells of |J v| (signs kept: the
    three channels of a layer move together); second-order terms go through |J|; units that may
    switch (|h_j| <= r_j = sum_i |W1_ji| e_i) add |out_scale| |W2_cj| r_j (ReLU is 1-Lipschitz). The
    clamp to the output range can only shrink the change; normal z = sqrt(1 - x^2 - y^2) changes by
    at most min(sqrt(D), D / (z + sqrt(max(0, z^2 - D)))) with D = 2|x|e_x + 2|y|e_y + e_x^2 + e_y^2.
  * (b) fp32: the standard dot-product rounding bound (n_hidden + max(16, n_in)) * 2^-23 * (sum of |terms|)
    with the network's actual magnitudes, and 2^-20 of the largest feature for the filter arithmetic.

  * BC7 layers (UNORM8, ``--features bc7``) are filtered by many texture units, llvmpipe included,
    in 8-bit fixed point: each of trilinear filtering's three lerps may leave its result up to one
    8-bit step off (rounded or truncated), so such a layer's features get UNORM8_FILTER_STEPS / 255
    more on top of the fraction terms.

The bound is checked against a simulated 8-bit texture unit (rounding and truncating) in the tests:
it holds and is nearly reached (max error / bound ~0.9-0.98 with truncation). llvmpipe filters in
fp32 and agrees to ~1e-7. The check fails when any |GL - ONNX| exceeds its bound (``--tolerance X``
replaces it by a fixed X). The bound grows with the features' texel-to-texel differences: the
report says for how many values it exceeds the 2e-3 target (materials whose features have large
values are sensitive to hardware filtering precision).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from bcfpipe.formats.addressing import address, reduce_coord
from bcfpipe.formats.vocabulary import wrap_axes



FILTER_BITS = 8
UNORM8_FILTER_STEPS = 3  # lerps of a trilinear sample, each up to one 8-bit step off on a UNORM8 layer
FP32_ULP = 2.0 ** -23
TARGET = 2e-3


def _off_grid(x: np.ndarray, delta: float) -> np.ndarray:
    """1.0 where ``x`` is not a multiple of ``delta`` (a fixed-point fraction would round or
    truncate it), 0.0 where it is exact (texel centres and edges of power-of-two levels, exact lods)."""
    q = x / delta
    return (np.abs(q - np.round(q)) > 1e-6).astype(np.float64)


def _bilinear_terms(tex: np.ndarray, uv: np.ndarray, wrap, delta: float):
    """Bilinear value B, the slopes dB/dfx and dB/dfy of every cell within ``delta`` of each point
    (2 candidates each, zero where the coordinate is exact on the fixed-point grid), the second-order
    bound and the abs error bound of B for fraction errors up to ``delta``."""
    h, w, _ = tex.shape
    wrap_s, wrap_t = wrap_axes(wrap)
    uv = uv.astype(np.float64)
    uv = np.stack([reduce_coord(uv[:, 0], wrap_s), reduce_coord(uv[:, 1], wrap_t)], 1)  # as bcfReduceUv, in float64
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    ax, ay = _off_grid(x, delta)[:, None], _off_grid(y, delta)[:, None]

    def texel(cx, cy):
        return tex[address(cy.astype(np.int64), h, wrap_t), address(cx.astype(np.int64), w, wrap_s)]

    t00, t01, t10, t11 = texel(x0, y0), texel(x0 + 1, y0), texel(x0, y0 + 1), texel(x0 + 1, y0 + 1)
    value = (t00 * (1 - fx) + t01 * fx) * (1 - fy) + (t10 * (1 - fx) + t11 * fx) * fy
    dx = [ax * ((1 - fy) * (texel(cx + 1, y0) - texel(cx, y0)) + fy * (texel(cx + 1, y0 + 1) - texel(cx, y0 + 1)))
          for cx in (np.floor(x - delta), np.floor(x + delta))]
    dy = [ay * ((1 - fx) * (texel(x0, cy + 1) - texel(x0, cy)) + fx * (texel(x0 + 1, cy + 1) - texel(x0 + 1, cy)))
          for cy in (np.floor(y - delta), np.floor(y + delta))]
    cross = 0
    for cx in (np.floor(x - delta), np.floor(x + delta)):
        for cy in (np.floor(y - delta), np.floor(y + delta)):
            cross = np.maximum(cross, np.abs(texel(cx, cy) - texel(cx + 1, cy) - texel(cx, cy + 1)
                                             + texel(cx + 1, cy + 1)))
    second = delta * delta * cross * ax * ay
    err = delta * (np.maximum(*map(np.abs, dx)) + np.maximum(*map(np.abs, dy))) + second
    return value, dx, dy, second, err


@dataclass
class FilterError:
    """How hardware filtering precision can move the features at each point.

    ``groups``: first-order terms; each is (K, N, F) candidate feature-change vectors v_k, meaning
    the features move by up to delta * v for one unknown fraction error in [-1, 1] * delta and some
    k (the cell or mip pair it falls in). ``second``: (N, F) abs bound of the rest (second order and
    fp32 filtering arithmetic). ``total``: (N, F) abs bound of the whole feature error.
    """

    delta: float
    groups: list[np.ndarray]
    second: np.ndarray
    total: np.ndarray


def filter_error(levels: Sequence[Sequence[np.ndarray]], biases: Sequence[float], uv: np.ndarray,
                 s: np.ndarray, wrap, filter_bits: int = FILTER_BITS,
                 exact_lods: np.ndarray | bool = True, unorm8: bool = False) -> FilterError:
    """Feature-error terms of trilinear filtering with 2^-filter_bits precision on the bilinear
    fractions and on the mip blend fraction (see the module docstring). ``exact_lods`` False (per
    point or for all) marks lods the runtime computes itself (from derivatives, in fp32): those may
    sit off the fixed-point grid even where ``s`` is on it. ``unorm8``: the layers are 8-bit UNORM
    (BC7), filtered in 8-bit fixed point."""
    delta = 2.0 ** -filter_bits
    n_pts = uv.shape[0]
    widths = [layer[0].shape[-1] for layer in levels]  # features per layer: 3 (BC6H) or 4 (BC7)
    starts = np.concatenate([[0], np.cumsum(widths)]).astype(int)
    n_feat = int(starts[-1])
    groups, second, total = [], np.zeros((n_pts, n_feat)), np.zeros((n_pts, n_feat))
    for i, (layer, b) in enumerate(zip(levels, biases)):
        sl = slice(int(starts[i]), int(starts[i + 1]))
        n = len(layer)
        # clipped a little beyond [0, n - 1] so that +-inf and 1e30 stay integers below
        lam = np.clip((s.astype(np.float32) + np.float32(b)).astype(np.float64), -2.0, n + 1.0)
        lc = np.clip(lam, 0, n - 1)
        lo = np.floor(lc).astype(np.int64)
        t = (lc - lo)[:, None]
        hi = np.minimum(lo + 1, n - 1)
        terms = [_bilinear_terms(tex.astype(np.float64), uv, wrap, delta) for tex in layer]
        vals = np.stack([tr[0] for tr in terms])  # (n, N, C)
        pick = lambda arr, k: np.take_along_axis(arr, k[None, :, None], 0)[0]  # noqa: E731
        for weight, k in ((1 - t, lo), (t, hi)):
            for part in (1, 2):  # dB/dfx, dB/dfy candidates of the level in use
                cand = np.stack([pick(np.stack([tr[part][c] for tr in terms]), k) for c in range(2)]) * weight
                g = np.zeros((2, n_pts, n_feat))
                g[:, :, sl] = cand
                groups.append(g)
                total[:, sl] += delta * np.abs(cand).max(0)
            second[:, sl] += weight * pick(np.stack([tr[3] for tr in terms]), k)
        # mip blend: slopes B_k+1 - B_k of the segments within delta of the lod (0 outside [0, n-1])
        al = np.maximum(_off_grid(lam, delta), 1.0 - np.asarray(exact_lods, np.float64))  # exact: blends exactly
        k1 = np.floor(lam - delta * al).astype(np.int64)
        k2 = np.floor(lam + delta * al).astype(np.int64)
        seg = np.zeros((2, n_pts, n_feat))
        for c, k in enumerate((k1, k2)):
            ok = ((k >= 0) & (k <= n - 2))[:, None]
            kk = np.clip(k, 0, max(n - 2, 0))
            d = pick(vals, np.minimum(kk + 1, n - 1)) - pick(vals, kk)
            seg[c, :, sl] = np.where(ok, d, 0.0) * al[:, None]
        groups.append(seg)
        total[:, sl] += delta * np.abs(seg[:, :, sl]).max(0)
        # blend error x bilinear errors of every level that can take part, and fp32 filtering arithmetic
        errs = np.stack([tr[4] for tr in terms])
        for k in range(n):
            inside = ((k >= np.clip(k1, 0, n - 1)) & (k <= np.clip(k2 + 1, 0, n - 1)))[:, None]
            second[:, sl] += np.where(inside, delta * al[:, None] * errs[k], 0.0)
        second[:, sl] += 2.0 ** -20 * max(float(np.abs(tex).max()) for tex in layer)
        if unorm8:
            second[:, sl] += UNORM8_FILTER_STEPS / 255.0
    total += second
    return FilterError(delta, groups, second, total)


def _through_log_expansion(g: np.ndarray, cy: np.ndarray, e: np.ndarray, lo: np.ndarray,
                           hi: np.ndarray) -> np.ndarray:
    """The bound ``e`` on the clamped log-domain value ``cy``, carried through the HDR expansion
    v = (2^(g t) - 1) / (2^g - 1) of the channels with g > 0 (bcfpipe.texset.encoding): it is
    increasing and convex, so the interval's ends bound it; plus exp2's own rounding, which
    GLSL allows to be (3 + 2 |x|) ulp, on values up to 2^g before the subtraction."""
    hdr = g > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(hdr, 1.0 / (np.exp2(g) - 1.0), 0.0)

    def expand(t):
        return np.where(hdr, (np.exp2(g * t) - 1.0) * inv, t)

    up, down = np.minimum(cy + e, hi), np.maximum(cy - e, lo)
    through = np.maximum(expand(up) - expand(cy), expand(cy) - expand(down))
    rounding = (8.0 + 2.0 * g * up) * FP32_ULP * np.exp2(g * up) * inv
    return np.where(hdr, through + rounding + FP32_ULP, e)


def output_tolerance(weights, kinds: tuple[str, ...], feats: np.ndarray, fe: FilterError,
                     ref_out: np.ndarray) -> np.ndarray:
    """Per point, per output channel (incl. normal z): bound on |GL - ONNX| (see module docstring)."""
    from bcfpipe.model.decoder import normal_xy_index, output_ranges  # lazy: start-up

    w1, b1, w2, b2, sc, bi = (np.asarray(a, np.float64) for a in weights.arrays()[:6])
    f = feats.astype(np.float64)
    h = f @ w1.T + b1
    r = fe.total @ np.abs(w1).T  # bound on each hidden pre-activation's change
    safe_on = (h > r).astype(np.float64)  # active whatever the filtering error: linear there
    kink = np.abs(h) <= r  # may switch: treated with |.| (ReLU is 1-Lipschitz)
    jac = np.einsum("nh,ch,hi->nci", safe_on, w2, w1) * sc[None, :, None]  # (N, C, F)
    first = np.zeros(jac.shape[:2])
    for g in fe.groups:
        first += np.abs(np.einsum("nci,kni->knc", jac, g)).max(0)
    dy = fe.delta * first + np.einsum("nci,ni->nc", np.abs(jac), fe.second)
    dy += np.abs(sc) * (np.where(kink, r, 0.0) @ np.abs(w2).T)
    # fp32 rounding of both evaluations (dot-product bound with the actual magnitudes)
    a1 = np.abs(f) @ np.abs(w1).T + np.abs(b1)
    mag = np.abs(sc) * (a1 @ np.abs(w2).T + np.abs(b2)) + np.abs(bi)
    dy += (w1.shape[0] + max(16, w1.shape[1])) * FP32_ULP * mag + FP32_ULP  # n_hidden + n_in (at least 16)
    y = (np.maximum(h, 0) @ w2.T + b2) * sc + bi
    lo, hi = (np.asarray(a, np.float64) for a in output_ranges(kinds))
    cy = np.clip(y, lo, hi)
    e = np.maximum(np.clip(y + dy, lo, hi) - cy, cy - np.clip(y - dy, lo, hi)) + FP32_ULP
    if weights.log_gain is not None:
        e = _through_log_expansion(np.asarray(weights.log_gain, np.float64), cy, e, lo, hi)
    n = normal_xy_index(kinds)
    if n is None:
        return e
    x, yy = ref_out[:, n].astype(np.float64), ref_out[:, n + 1].astype(np.float64)
    ex, ey = e[:, n], e[:, n + 1]
    d = 2 * np.abs(x) * ex + 2 * np.abs(yy) * ey + ex * ex + ey * ey
    z = np.sqrt(np.maximum(0.0, 1 - x * x - yy * yy))
    with np.errstate(divide="ignore", invalid="ignore"):
        ez = np.minimum(np.sqrt(d), d / (z + np.sqrt(np.maximum(0.0, z * z - d))))
    ez = np.where(np.isfinite(ez), ez, np.sqrt(d)) + 4 * FP32_ULP
    return np.concatenate([e[:, :n + 2], ez[:, None], e[:, n + 2:]], 1)
