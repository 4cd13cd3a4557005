"""The fused training step in numba: per sample, the 8 trilinear taps of each layer decoded straight
from the parameters, the MLP forward and backward, the loss, and the gradients scattered into the
touched texels or blocks (issue 30).

Every per-texel decode repeats, in float32 and in the same order, the operations of the torch
emulation it stands for, so the decoded values are bit-identical:

* ``FREE_BC6H``  :func:`bcfpipe.model.features.endpoint_value` of a clamped free parameter;
* ``FREE_BC7``   a clamped free parameter / 255;
* ``BLOCK_BC6H`` :func:`bcfpipe.bc6h.emulate.decode_blocks` (mode 11110, one of two subsets);
* ``BLOCK_BC7``  :func:`bcfpipe.bc7.emulate.decode_blocks` (mode 6);

optionally quantization-aware (the forward of the rounded parameters, gradients straight through).
Bilinear and trilinear weights follow :mod:`bcfpipe.model.sampling`. The MLP's sums run in a
different order from torch's matrix products, so the loss and gradients agree to float rounding.

Threads: samples are split into ``n_chunks`` fixed ranges, each accumulating into its own gradient
buffers, which are then added in chunk order: the result depends on the chunk count, never on
scheduling.
"""
from __future__ import annotations

import numpy as np

from bcfpipe.texset.reference import KEYS_A
from bcfpipe.train.fused.common import (BLOCK_BC6H, BLOCK_BC7, FIXED, FREE_BC6H, FREE_BC7, TRAINED, WRAP_MIRROR,
                                        WRAP_REPEAT)
from bcfpipe.process_env import kernel_cache, without_cache


CACHE = kernel_cache()  # compiled kernels live in bcfpipe's cache, or nowhere
import numba as nb  # noqa: E402


_F32 = np.float32
_SNAP6 = np.float32(7.0 * 1e-4)  # bc6h.emulate: |7x - round(7x)| below this snaps
_SNAP7 = np.float32(1e-4 * 15)  # bc7.emulate
_POW2 = (2.0 ** np.arange(-64, 64)).astype(np.float32)  # _POW2[64 + e] = 2^e, exact: no pow() per texel


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _rint(v):
    """Round half to even (torch.round) of a float32 with |v| < 2^22."""
    r = np.floor(v)
    d = v - r
    if d > 0.5 or (d == 0.5 and (r % 2.0) != 0.0):
        r += 1.0
    return _F32(r)


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _half(f):
    """Value of the IEEE half whose bits are the integer-valued float32 ``f`` (0 <= f <= 31743)."""
    b = int(f)
    e = b >> 10
    m = b & 1023
    if e == 0:
        return _F32(m) * _POW2[64 - 24]
    return _F32(1024 + m) * _POW2[64 + e - 25]


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _unquantize(e, lo, hi, quantized, table, slope):
    """(bc6h.emulate unquantize, d/de) of a continuous endpoint."""
    pos = min(max(e, lo), hi)
    inside = _F32(1.0) if pos == e else _F32(0.0)
    if quantized:
        pos = pos + (_rint(pos) - pos)
    pos = pos - lo
    k0 = min(max(np.floor(pos), 0.0), 62.0)
    k = int(k0)
    return table[k] + (pos - _F32(k0)) * slope[k], slope[k] * inside


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _weight3(x, quantized, w3, w3s):
    """(bc6h.emulate index_weight, d/dx) of a continuous index."""
    t = min(max(x, _F32(0.0)), _F32(1.0))
    inside = _F32(1.0) if t == x else _F32(0.0)
    t = t * _F32(7.0)
    d = _rint(t) - t
    if quantized:
        t = t + d
    elif abs(d) < _SNAP6:
        t = t + d
    k0 = min(max(np.floor(t), 0.0), 6.0)
    k = int(k0)
    return w3[k] + (t - _F32(k0)) * w3s[k], w3s[k] * inside * _F32(7.0)


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _weight4(x, quantized):
    """(bc7.emulate weight, d/dx without the clamp's mask, clamp mask) of a continuous index."""
    xc = min(max(x, _F32(0.0)), _F32(1.0))
    inside = _F32(1.0) if xc == x else _F32(0.0)
    if quantized:
        xc = _rint(xc * _F32(15.0)) / _F32(15.0)
    t = min(max(xc, _F32(0.0)), _F32(1.0)) * _F32(15.0)
    near = _rint(t)
    if abs(t - near) < _SNAP7:
        t = near
    k = min(np.floor(t), 14.0)
    lo = np.floor((_F32(64.0) * _F32(k) + _F32(7.0)) / _F32(15.0))
    hi = np.floor((_F32(64.0) * _F32(k + 1.0) + _F32(7.0)) / _F32(15.0))
    step = _F32(hi - lo)
    return _F32(lo) + (t - _F32(k)) * step, step * _F32(15.0), inside


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _q7(e, j):
    """bc7.emulate.quantize_endpoints of clamped endpoint ``e[j]`` (4 channels): both p-bit choices
    into rows 2 and 3 of ``e``; returns the one chosen."""
    err0 = _F32(0.0)
    err1 = _F32(0.0)
    for c in range(4):
        v = e[j, c]
        q0 = min(max(_F32(2.0) * _F32(np.floor((v - _F32(0.0)) / _F32(2.0) + _F32(0.5))) + _F32(0.0), _F32(0.0)), _F32(254.0))
        q1 = min(max(_F32(2.0) * _F32(np.floor((v - _F32(1.0)) / _F32(2.0) + _F32(0.5))) + _F32(1.0), _F32(1.0)), _F32(255.0))
        err0 += (q0 - v) * (q0 - v)
        err1 += (q1 - v) * (q1 - v)
        e[2, c] = q0
        e[3, c] = q1
    return 1 if err1 < err0 else 0


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _texel(fmt, quantized, signed, P, X, M, po, xo, mo, plane, blk, pos, C, lo, hi, utab, uslope, w3, w3s, scratch, val, t, deriv, i, lv):
    """Decode one texel into ``val`` (C,); ``deriv`` receives what its backward needs.

    The level's parameters start at ``P[po]`` (free: C planes of ``plane`` texels, ``blk`` the
    texel; blocks: ``blk`` * 12 or 8 endpoint values), its indices at ``X[xo]`` and its BC6H subset
    masks at ``M[mo]`` (16 per block). Free formats: ``deriv[i, lv, t, c]`` = d value / d p.
    BC6H blocks: 4 endpoints x 3 channels; deriv = [g-scale per channel (3),
    ub - ua (3), d ua/de (3), d ub/de (3), w, dw/dx, subset].
    BC7 blocks: 2 endpoints x 4 channels; deriv = [e1 - e0 (4), endpoint masks (8),
    w, d w/dx (clamp mask applied unless quantized)].
    """
    if fmt == FREE_BC7:
        for c in range(C):
            v = P[po + c * plane + blk]
            vc = min(max(v, lo), hi)
            val[t, c] = vc / _F32(255.0)
            deriv[i, lv, t, c] = (_F32(1.0) / _F32(255.0)) if vc == v else _F32(0.0)
    elif fmt == FREE_BC6H:
        scale = _F32(31.0 / 32.0) if signed else _F32(31.0 / 64.0)
        elo = _F32(-32.0) if signed else _F32(0.0)
        for c in range(C):
            v = P[po + c * plane + blk]
            vc = min(max(v, lo), hi)
            inside = _F32(1.0) if vc == v else _F32(0.0)
            u, du = _unquantize(vc, elo, elo + _F32(63.0), False, utab, uslope)
            y = u * scale
            ay = abs(y)
            h = max(np.floor(ay / _F32(1024.0)) - _F32(1.0), _F32(0.0))
            sg = _F32(0.0) if y == 0 else (_F32(1.0) if y > 0 else _F32(-1.0))
            e2 = _POW2[64 + int(h) - 14]
            val[t, c] = e2 * (y / _F32(1024.0) - sg * _F32(h))
            deriv[i, lv, t, c] = e2 / _F32(1024.0) * scale * du * inside
    elif fmt == BLOCK_BC6H:
        sub = M[mo + blk * 16 + pos]
        elo = _F32(-32.0) if signed else _F32(0.0)
        w, dw = _weight3(X[xo + blk * 16 + pos], quantized, w3, w3s)
        for c in range(3):
            ua, dua = _unquantize(P[po + blk * 12 + (2 * sub) * 3 + c], elo, elo + _F32(63.0), quantized, utab, uslope)
            ub, dub = _unquantize(P[po + blk * 12 + (2 * sub + 1) * 3 + c], elo, elo + _F32(63.0), quantized, utab, uslope)
            f = ua * (_F32(64.0) - w) + ub * w
            f = _F32(np.floor((f + _F32(32.0)) / _F32(64.0)))
            if signed:
                f = _F32(np.trunc(f * _F32(31.0 / 32.0))) + _F32(0.0)
            else:
                f = _F32(np.floor(f * _F32(31.0 / 64.0)))
            af = abs(f)
            v = _half(af)
            val[t, c] = -v if f < 0 else v
            be = int(af) >> 10
            deriv[i, lv, t, c] = _POW2[64 + max(be, 1) - 15]
            deriv[i, lv, t, 3 + c] = ub - ua
            deriv[i, lv, t, 6 + c] = dua
            deriv[i, lv, t, 9 + c] = dub
        deriv[i, lv, t, 12] = w
        deriv[i, lv, t, 13] = dw
        deriv[i, lv, t, 14] = sub
    else:  # BLOCK_BC7
        for j in range(2):
            for c in range(4):
                v = P[po + blk * 8 + 4 * j + c]
                vc = min(max(v, _F32(0.0)), _F32(255.0))
                deriv[i, lv, t, 4 + 4 * j + c] = _F32(1.0) if vc == v else _F32(0.0)
                scratch[j, c] = vc
        if quantized:
            for j in range(2):
                pick = _q7(scratch, j)
                for c in range(4):
                    scratch[j, c] = scratch[2 + pick, c]
        w, dw, inside = _weight4(X[xo + blk * 16 + pos], quantized)
        for c in range(4):
            ea = scratch[0, c]
            d = scratch[1, c] - ea
            val[t, c] = _F32(np.floor((w * d + (_F32(64.0) * ea + _F32(32.0))) / _F32(64.0))) / _F32(255.0)
            deriv[i, lv, t, c] = d
        deriv[i, lv, t, 12] = w
        deriv[i, lv, t, 13] = dw if quantized else dw * inside


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _texel_backward(fmt, signed, C, po, xo, plane, blk, pos, g, deriv, i, lv, t, gP, gX, q):
    """Add the gradient ``g`` (C,) of one decoded texel into row ``q`` of ``gP`` and ``gX`` (laid out
    as ``P`` and ``X``)."""
    if fmt == FREE_BC7 or fmt == FREE_BC6H:
        for c in range(C):
            gP[q, po + c * plane + blk] += g[c] * deriv[i, lv, t, c]
    elif fmt == BLOCK_BC6H:
        k = _F32((31.0 / 32.0 if signed else 31.0 / 64.0) * 2.0 ** -16)
        sub = int(deriv[i, lv, t, 14])
        w = deriv[i, lv, t, 12]
        acc = _F32(0.0)
        for c in range(3):
            gq = g[c] * deriv[i, lv, t, c]
            acc += deriv[i, lv, t, 3 + c] * gq
            gP[q, po + blk * 12 + (2 * sub) * 3 + c] += (_F32(64.0) - w) * gq * deriv[i, lv, t, 6 + c] * k
            gP[q, po + blk * 12 + (2 * sub + 1) * 3 + c] += w * gq * deriv[i, lv, t, 9 + c] * k
        gX[q, xo + blk * 16 + pos] += acc * deriv[i, lv, t, 13] * k
    else:
        s = _F32(1.0 / (64.0 * 255.0))
        w = deriv[i, lv, t, 12]
        acc = _F32(0.0)
        for c in range(4):
            acc += g[c] * deriv[i, lv, t, c]
            gP[q, po + blk * 8 + c] += (_F32(64.0) - w) * g[c] * s * deriv[i, lv, t, 4 + c]
            gP[q, po + blk * 8 + 4 + c] += w * g[c] * s * deriv[i, lv, t, 8 + c]
        gX[q, xo + blk * 16 + pos] += acc * s * deriv[i, lv, t, 13]


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _dense_backward(dout, inp, w, gw, gb, q, din):
    """Back through ``out = w @ inp + b``: adds into row ``q`` of ``gw`` and ``gb``, sets ``din``."""
    for k in range(din.shape[0]):
        din[k] = 0.0
    for o in range(dout.shape[0]):
        d = dout[o]
        gb[q, o] += d
        for k in range(inp.shape[0]):
            gw[q, o, k] += d * inp[k]
            din[k] += d * w[o, k]


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _address(i, n, mode):
    """Texel i of n along an axis for its mode (common.py: repeat, clamp, mirror; sampling.address)."""
    if mode == WRAP_REPEAT:
        return i % n
    if mode == WRAP_MIRROR:
        j = i % (2 * n)
        return j if j < n else 2 * n - 1 - j
    return min(max(i, 0), n - 1)


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _reduce(x, mode):
    """One coordinate range-reduced for its axis's mode, in float32 (sampling.reduce_coord)."""
    if mode == WRAP_REPEAT:
        return x - _F32(np.floor(x))
    if mode == WRAP_MIRROR:
        return x - _F32(2.0) * _F32(np.floor(x * _F32(0.5)))
    return min(max(x, _F32(-1.0)), _F32(2.0))


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _features(fmt, quantized, signed, wrap, n, uv, P, X, M, slots, blend, C, plo, phi, utab, uslope,
              w3, w3s, feats, val, deriv, blks, poss, fxy, scratch, lvl):
    """Sample n's features into ``feats``; its taps, their weights and their decode derivatives
    into ``blks``, ``poss``, ``fxy`` and ``deriv`` for the backward."""
    free = fmt == FREE_BC6H or fmt == FREE_BC7
    for i in range(blend.shape[0]):
        for lv in range(2):
            j = 2 * i + lv
            if slots[j, 0] == 0:
                continue
            r = slots[j, 1]
            po = slots[j, 2]
            xo = slots[j, 3]
            mo = slots[j, 4]
            plane = slots[j, 5]
            u = uv[n, 0]
            v = uv[n, 1]
            u = _reduce(u, wrap & 3)
            v = _reduce(v, (wrap >> 2) & 3)
            xf = u * _F32(r) - _F32(0.5)
            yf = v * _F32(r) - _F32(0.5)
            x0 = np.floor(xf)
            y0 = np.floor(yf)
            fx = xf - _F32(x0)
            fy = yf - _F32(y0)
            fxy[i, lv, 0] = fx
            fxy[i, lv, 1] = fy
            xa = _address(int(x0), r, wrap & 3)
            xb = _address(int(x0) + 1, r, wrap & 3)
            ya = _address(int(y0), r, (wrap >> 2) & 3)
            yb = _address(int(y0) + 1, r, (wrap >> 2) & 3)
            fixed = slots[j, 0] == FIXED
            for t in range(4):
                ty = ya if t < 2 else yb
                tx = xa if t % 2 == 0 else xb
                if free or fixed:
                    blk = ty * r + tx
                    pos = 0
                else:
                    blk = (ty // 4) * (r // 4) + tx // 4
                    pos = (ty % 4) * 4 + tx % 4
                blks[i, lv, t] = blk
                poss[i, lv, t] = pos
                if fixed:  # a level written as encoded (UNORM8 values): no parameters, no gradient
                    for c in range(C):
                        val[t, c] = P[po + c * plane + blk] / _F32(255.0)
                else:
                    _texel(fmt, quantized, signed, P, X, M, po, xo, mo, plane, blk, pos, C, plo, phi, utab, uslope,
                           w3, w3s, scratch, val, t, deriv, i, lv)
            for c in range(C):
                top = val[0, c] + (val[1, c] - val[0, c]) * fx
                bot = val[2, c] + (val[3, c] - val[2, c]) * fx
                lvl[lv, c] = top + (bot - top) * fy
        for c in range(C):
            f = lvl[0, c]
            if slots[2 * i + 1, 0] != 0:
                f = f + (lvl[1, c] - f) * blend[i]
            feats[C * i + c] = f

@nb.njit(cache=CACHE)
def scratch_size(n_in, hidden, n_out, C):
    """Floats of scratch one chunk needs (see :func:`_split`); n_in // C layers."""
    L = n_in // C
    return 2 * n_in + 3 * hidden + n_out + 4 * C + L * 2 * 4 * 16 + L * 2 * 2 + 16 + 2 * C + 2 * C + n_in


@nb.njit(inline="always", cache=CACHE, _nrt=False)
def _split(sf, n_in, hidden, n_out, C):
    """Views of a chunk's float32 scratch: feats, pre, hid, draw, val (4, C), deriv (L, 2, 4, 16),
    fxy (L, 2, 2), scratch (4, 4), lvl (2, C), g, gl, dfe, for L = n_in // C layers."""
    L = n_in // C
    o = 0
    feats = sf[o:o + n_in]
    o += n_in
    pre = sf[o:o + 2 * hidden]  # pre-activations, then the hidden gradient
    o += 2 * hidden
    hid = sf[o:o + hidden]
    o += hidden
    draw = sf[o:o + n_out]
    o += n_out
    val = sf[o:o + 4 * C].reshape((4, C))
    o += 4 * C
    deriv = sf[o:o + L * 128].reshape((L, 2, 4, 16))
    o += L * 128
    fxy = sf[o:o + L * 4].reshape((L, 2, 2))
    o += L * 4
    scratch = sf[o:o + 16].reshape((4, 4))
    o += 16
    lvl = sf[o:o + 2 * C].reshape((2, C))
    o += 2 * C
    g = sf[o:o + C]
    o += C
    gl = sf[o:o + C]
    o += C
    dfe = sf[o:o + n_in]
    return feats, pre, hid, draw, val, deriv, fxy, scratch, lvl, g, gl, dfe


@nb.njit(cache=CACHE, _nrt=False)
def _chunk(fmt, quantized, signed, wrap, q, a, b, uv, target, weight, P, X, M, slots, blend, C,
           plo, phi, utab, uslope, w3, w3s, w1, w1t, b1, w2, b2, out_scale, out_bias, loss_scale, gP, gX, gw1, gb1, gw2,
           gb2, sf, si):
    """Samples [a, b): forward, loss and backward, gradients added into row ``q`` of the g* buffers
    (each laid out as its parameter); returns the sum of the (weighted) squared errors. ``sf`` and
    ``si`` are this chunk's float32 and int64 scratch (:func:`_split`); compiled without numba's
    reference counting, which otherwise costs an atomic add per array use in the inner loop."""
    n_in = w1.shape[1]
    hidden = w1.shape[0]
    n_out = w2.shape[0]
    feats, pre, hid, draw, val, deriv, fxy, scratch, lvl, g, gl, dfe = _split(sf, n_in, hidden, n_out, C)
    dh = pre[hidden:2 * hidden]
    L = blend.shape[0]
    blks = si[0:8 * L].reshape((L, 2, 4))
    poss = si[8 * L:16 * L].reshape((L, 2, 4))
    sse = 0.0
    for n in range(a, b):
        _features(fmt, quantized, signed, wrap, n, uv, P, X, M, slots, blend, C, plo, phi, utab, uslope,
                  w3, w3s, feats, val, deriv, blks, poss, fxy, scratch, lvl)
        # ---- the MLP, the loss and its gradient; inner loops run over contiguous rows, in the
        # order of a dot product's terms, so LLVM vectorizes them without reassociating sums
        for h in range(hidden):
            pre[h] = 0.0
        for k in range(n_in):
            fk = feats[k]
            for h in range(hidden):
                pre[h] += fk * w1t[k, h]
        for h in range(hidden):
            pre[h] += b1[h]
            hid[h] = pre[h] if pre[h] > 0 else _F32(0.0)
        wn = weight[n] if weight.shape[0] > 0 else _F32(1.0)
        for o in range(n_out):
            acc = _F32(0.0)
            for h in range(hidden):
                acc += hid[h] * w2[o, h]
            acc += b2[o]
            d = (acc * out_scale[o] + out_bias[o]) - target[n, o]
            sse += wn * d * d
            draw[o] = loss_scale * _F32(2.0) * wn * d * out_scale[o]
        _dense_backward(draw, hid, w2, gw2, gb2, q, dh)
        for h in range(hidden):
            if pre[h] <= 0:
                dh[h] = 0.0
        _dense_backward(dh, feats, w1, gw1, gb1, q, dfe)
        # ---- back through the trilinear taps into the parameters
        for i in range(L):
            for lv in range(2):
                j = 2 * i + lv
                if slots[j, 0] != TRAINED:
                    continue
                tb = blend[i]
                for c in range(C):
                    gc = dfe[C * i + c]
                    if slots[2 * i + 1, 0] != 0:
                        gc = gc * tb if lv == 1 else gc - gc * tb
                    gl[c] = gc
                fx = fxy[i, lv, 0]
                fy = fxy[i, lv, 1]
                po = slots[j, 2]
                xo = slots[j, 3]
                plane = slots[j, 5]
                for t in range(4):
                    wy = fy if t >= 2 else _F32(1.0) - fy
                    wx = fx if t % 2 == 1 else _F32(1.0) - fx
                    for c in range(C):
                        g[c] = gl[c] * wy * wx
                    _texel_backward(fmt, signed, C, po, xo, plane, blks[i, lv, t], poss[i, lv, t], g, deriv, i, lv, t, gP, gX, q)
    return sse


@nb.njit(parallel=True, cache=CACHE)
def _step_parallel(fmt, quantized, signed, wrap, n_chunks, uv, target, weight, P, X, M, slots, blend, C,
                   plo, phi, utab, uslope, w3, w3s, w1, b1, w2, b2, out_scale, out_bias, loss_scale, gP, gX, gw1, gb1,
                   gw2, gb2):
    N = uv.shape[0]
    sse = np.zeros(n_chunks, np.float64)
    w1t = np.ascontiguousarray(w1.T)
    for q in nb.prange(n_chunks):
        a = N * q // n_chunks
        b = N * (q + 1) // n_chunks
        sf = np.zeros(scratch_size(w1.shape[1], w1.shape[0], w2.shape[0], C), np.float32)
        si = np.zeros(16 * blend.shape[0], np.int64)
        sse[q] = _chunk(fmt, quantized, signed, wrap, q, a, b, uv, target, weight, P, X, M, slots, blend, C,
                        plo, phi, utab, uslope, w3, w3s, w1, w1t, b1, w2, b2, out_scale, out_bias, loss_scale,
                        gP, gX, gw1, gb1, gw2, gb2, sf, si)
    return sse


@nb.njit(cache=CACHE)
def _step_serial(fmt, quantized, signed, wrap, n_chunks, uv, target, weight, P, X, M, slots, blend, C,
                 plo, phi, utab, uslope, w3, w3s, w1, b1, w2, b2, out_scale, out_bias, loss_scale, gP, gX, gw1, gb1,
                 gw2, gb2):
    sse = np.zeros(1, np.float64)
    sf = np.zeros(scratch_size(w1.shape[1], w1.shape[0], w2.shape[0], C), np.float32)
    si = np.zeros(16 * blend.shape[0], np.int64)
    sse[0] = _chunk(fmt, quantized, signed, wrap, 0, 0, uv.shape[0], uv, target, weight, P, X, M, slots, blend, C,
                    plo, phi, utab, uslope, w3, w3s, w1, np.ascontiguousarray(w1.T), b1, w2, b2, out_scale, out_bias,
                    loss_scale, gP, gX, gw1, gb1, gw2, gb2, sf, si)
    return sse


def uncached(call):
    """Run ``call``; if numba cannot write its cache (a full or read-only cache folder), compile
    every kernel here without caching and run it again: a slower start, never a failed training."""
    return without_cache(call, globals())


def step(fmt, quantized, signed, wrap, n_chunks, *args):
    """One training step's forward and backward over all samples, in ``n_chunks`` ranges (run in
    parallel when there are several), each into its own row (axis 0) of the g* buffers; returns the
    per-chunk sums of the squared errors (the caller adds the rows in chunk order)."""
    run = _step_parallel if n_chunks > 1 else _step_serial
    return uncached(lambda: run(fmt, quantized, signed, wrap, n_chunks, *args))


@nb.njit(cache=CACHE, _nrt=False)
def _features_all(fmt, quantized, signed, wrap, uv, P, X, M, slots, blend, C, plo, phi, utab, uslope, w3, w3s,
                  out, sf, si):
    feats, pre, hid, draw, val, deriv, fxy, scratch, lvl, g, gl, dfe = _split(sf, out.shape[1], 1, 1, C)
    L = blend.shape[0]
    blks = si[0:8 * L].reshape((L, 2, 4))
    poss = si[8 * L:16 * L].reshape((L, 2, 4))
    for n in range(uv.shape[0]):
        _features(fmt, quantized, signed, wrap, n, uv, P, X, M, slots, blend, C, plo, phi, utab, uslope,
                  w3, w3s, feats, val, deriv, blks, poss, fxy, scratch, lvl)
        for k in range(out.shape[1]):
            out[n, k] = feats[k]


def features(fmt, quantized, signed, wrap, uv, P, X, M, slots, blend, C, plo, phi, utab, uslope, w3, w3s):
    """The features (N, layers C) the step feeds the MLP (for tests against the torch path)."""
    out = np.zeros((uv.shape[0], len(blend) * C), np.float32)
    _features_all(fmt, quantized, signed, wrap, uv, P, X, M, slots, blend, C, plo, phi, utab, uslope, w3, w3s,
                  out, np.zeros(scratch_size(out.shape[1], 1, 1, C), np.float32), np.zeros(16 * len(blend), np.int64))
    return out


# ---- the training targets (targets.py): the reference's bicubic lookup

@nb.njit(inline="always", cache=CACHE)
def _keys(f, a, w):
    """keys_weights: cubic-convolution weights of the taps at -1, 0, 1, 2 for fraction ``f`` into ``w``."""
    f2 = f * f
    f3 = f2 * f
    w[0] = a * (f3 - _F32(2.0) * f2 + f)
    w[1] = (a + _F32(2.0)) * f3 - (a + _F32(3.0)) * f2 + _F32(1.0)
    w[2] = -(a + _F32(2.0)) * f3 + (_F32(2.0) * a + _F32(3.0)) * f2 - a * f
    w[3] = a * (f2 - f3)


@nb.njit(cache=CACHE)
def bicubic_into(tex, uv, wrap, t, out):
    """out = lerp(out, bicubic(tex, uv), t) when ``t`` >= 0, else out = bicubic(tex, uv)."""
    c, h, w = tex.shape
    a = _F32(KEYS_A)
    wx = np.zeros(4, np.float32)
    wy = np.zeros(4, np.float32)
    xs = np.zeros(4, np.int64)
    ys = np.zeros(4, np.int64)
    for n in range(uv.shape[0]):
        x = uv[n, 0] * _F32(w) - _F32(0.5)
        y = uv[n, 1] * _F32(h) - _F32(0.5)
        x0 = np.floor(x)
        y0 = np.floor(y)
        _keys(x - x0, a, wx)
        _keys(y - y0, a, wy)
        for k in range(4):
            xi = int(x0) - 1 + k
            yi = int(y0) - 1 + k
            xs[k] = _address(xi, w, wrap & 3)
            ys[k] = _address(yi, h, (wrap >> 2) & 3)
        for ch in range(c):
            acc = _F32(0.0)
            for ky in range(4):
                row = _F32(0.0)
                for kx in range(4):
                    row += tex[ch, ys[ky], xs[kx]] * wx[kx]
                acc += row * wy[ky]
            if t >= 0:
                out[n, ch] = out[n, ch] + _F32(t) * (acc - out[n, ch])
            else:
                out[n, ch] = acc
