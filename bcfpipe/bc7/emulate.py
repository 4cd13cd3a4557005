"""Differentiable torch emulation of BC7 mode-6 decoding, bit-exact with :mod:`bcfpipe.bc7.decode`
at quantized parameters.

Per texel and channel the spec computes, in integers (:mod:`bcfpipe.bc7.mode6`)::

    value = ((64 - w) e0 + w e1 + 32) >> 6,   w = WEIGHTS4[index],   read as value / 255

Trainable parameters are ``endpoints`` (n, 2, 4) continuous in the 8-bit domain [0, 255] and
``x`` (n, 16) continuous in [0, 1] (index / 15). The index maps to its weight through the monotone
piecewise-linear ``phi`` with ``phi(k / 15) = WEIGHTS4[k]``; values of x within 1e-4 of a knot are
snapped, so x = k / 15 decodes exactly. The final shift is a floor, straight-through (forward the
spec's integer, backward identity); every intermediate is an integer below 2^15, exact in float32.

Quantization-aware decoding (``quantized=True``) rounds x to the nearest of the 16 indices and each
endpoint to :func:`bcfpipe.bc7.encode.quantize_endpoints`'s choice (the p-bit whose 7-bit grid lies
nearer; the four channels share it), both straight-through: the forward value is then exactly what
the exported block decodes to.
"""
from __future__ import annotations

import torch


__all__ = ["decode_blocks", "decode_blocks_composed", "decode_texels", "quantize_endpoints", "weight_of", "LEVELS"]

LEVELS = 15  # index steps: x = index / 15
_SNAP = 1e-4


def _straight_through(value: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    return x + (value - x).detach()


def weight_of(x: torch.Tensor) -> torch.Tensor:
    """Continuous index x in [0, 1] -> interpolation weight in 64ths (piecewise linear through WEIGHTS4)."""
    x = x.clamp(0.0, 1.0)
    t = x * LEVELS
    near = torch.round(t)
    t = torch.where((t - near).abs() < _SNAP * LEVELS, _straight_through(near, t), t)
    k = torch.clamp(torch.floor(t.detach()), max=LEVELS - 1)
    lo, hi = _table_weight(k), _table_weight(k + 1)
    return lo + (t - k) * (hi - lo)


def _table_weight(k: torch.Tensor) -> torch.Tensor:
    """WEIGHTS4[k] for integer-valued k in [0, 15], as floor((64 k + 7) / 15) (equal for every k,
    tested), so no gather is needed."""
    return torch.floor((64.0 * k + 7.0) / 15.0)


def quantize_endpoints(e: torch.Tensor) -> torch.Tensor:
    """Nearest mode-6 endpoint values (..., 4), straight-through; equals the numpy encoder's choice."""
    v = e.clamp(0.0, 255.0)
    q = []
    for p in (0.0, 1.0):
        q.append(torch.clamp(2.0 * torch.floor((v.detach() - p) / 2.0 + 0.5) + p, p, 254.0 + p))
    err0 = ((q[0] - v.detach()) ** 2).sum(-1, keepdim=True)
    err1 = ((q[1] - v.detach()) ** 2).sum(-1, keepdim=True)
    return _straight_through(torch.where(err1 < err0, q[1], q[0]), v)


def _prepare(ea: torch.Tensor, eb: torch.Tensor, x: torch.Tensor, quantized: bool):
    if quantized:
        ea, eb = quantize_endpoints(ea), quantize_endpoints(eb)
        x = _straight_through(torch.round(x.clamp(0.0, 1.0) * LEVELS) / LEVELS, x)
    else:
        ea, eb = ea.clamp(0.0, 255.0), eb.clamp(0.0, 255.0)
    return ea, eb, weight_of(x).unsqueeze(-1)


def _interpolate(ea: torch.Tensor, eb: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    v = (w * (eb - ea) + (64.0 * ea + 32.0)) / 64.0  # = ((64 - w) ea + w eb + 32) / 64, exact at integers
    return _straight_through(torch.floor(v), v) / 255.0


def decode_texels(ea: torch.Tensor, eb: torch.Tensor, x: torch.Tensor, quantized: bool = False) -> torch.Tensor:
    """Texel values in [0, 1] (M, 4) from endpoints ``ea``, ``eb`` (M, 4) and continuous indices (M,)."""
    return _interpolate(*_prepare(ea, eb, x, quantized))


def decode_blocks_composed(endpoints: torch.Tensor, x: torch.Tensor, quantized: bool = False) -> torch.Tensor:
    """:func:`decode_blocks` as a composition of torch ops (the reference the fused node is tested against)."""
    ea, eb, w = _prepare(endpoints[:, 0], endpoints[:, 1], x, quantized)
    return _interpolate(ea[:, None], eb[:, None], w)


class _DecodeBlocks(torch.autograd.Function):
    """:func:`decode_blocks_composed` as one autograd node: the same forward values, and the
    gradient autograd computes through the composition written out (the floor and the roundings
    pass gradients unchanged; the clamps pass them inside their range, bounds included):

        dv/d e0 = (64 - w) / (64 * 255),   dv/d e1 = w / (64 * 255),
        dv/d x  = (e1 - e0) / (64 * 255) * phi'(x),   phi' = 15 (W[k + 1] - W[k]) on segment k.
    """

    @staticmethod
    def forward(ctx, endpoints, x, quantized: bool):
        with torch.no_grad():
            e = endpoints.clamp(0.0, 255.0)
            if quantized:
                e = quantize_endpoints(e)
                xs = torch.round(x.clamp(0.0, 1.0) * LEVELS) / LEVELS
            else:
                xs = x
            t = xs.clamp(0.0, 1.0) * LEVELS
            near = torch.round(t)
            t = torch.where((t - near).abs() < _SNAP * LEVELS, near, t)
            k = torch.clamp(torch.floor(t), max=LEVELS - 1)
            lo, hi = _table_weight(k), _table_weight(k + 1)
            w = (lo + (t - k) * (hi - lo)).unsqueeze(-1)  # (n, 16, 1)
            ea = e[:, None, 0]
            out = (w * (e[:, None, 1] - ea)).add_(64.0 * ea + 32.0).div_(64.0).floor_().div_(255.0)
        ctx.save_for_backward(endpoints, x, e, w, hi - lo)
        ctx.quantized = quantized
        return out

    @staticmethod
    def backward(ctx, g):
        endpoints, x, e, w, step = ctx.saved_tensors
        s = 1.0 / (64.0 * 255.0)
        gw = (g * w).sum(1)
        g_e = torch.stack([64.0 * g.sum(1) - gw, gw], 1) * s
        g_e = g_e * ((endpoints >= 0.0) & (endpoints <= 255.0)).to(g.dtype)
        diff = (e[:, 1] - e[:, 0])[:, None, :]  # (n, 1, 4)
        g_x = (g * diff).sum(-1) * s * step * LEVELS
        if not ctx.quantized:  # the rounding's straight-through passes x's gradient at any x
            g_x = g_x * ((x >= 0.0) & (x <= 1.0)).to(g.dtype)
        return g_e, g_x, None


def decode_blocks(endpoints: torch.Tensor, x: torch.Tensor, quantized: bool = False) -> torch.Tensor:
    """(n, 2, 4) endpoints and (n, 16) indices -> (n, 16, 4) texel values in [0, 1]; one autograd
    node (:class:`_DecodeBlocks`), forward bit-identical to :func:`decode_blocks_composed`."""
    return _DecodeBlocks.apply(endpoints, x, quantized)
