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

from .mode6 import WEIGHTS4

__all__ = ["decode_blocks", "decode_texels", "quantize_endpoints", "weight_of", "LEVELS"]

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
    k = torch.clamp(torch.floor(t.detach()), max=LEVELS - 1).long()
    w = torch.as_tensor(WEIGHTS4, dtype=x.dtype, device=x.device)
    lo, hi = w[k], w[k + 1]
    return lo + (t - k.to(x.dtype)) * (hi - lo)


def quantize_endpoints(e: torch.Tensor) -> torch.Tensor:
    """Nearest mode-6 endpoint values (..., 4), straight-through; equals the numpy encoder's choice."""
    v = e.clamp(0.0, 255.0)
    q = []
    for p in (0.0, 1.0):
        q.append(torch.clamp(2.0 * torch.floor((v.detach() - p) / 2.0 + 0.5) + p, p, 254.0 + p))
    err0 = ((q[0] - v.detach()) ** 2).sum(-1, keepdim=True)
    err1 = ((q[1] - v.detach()) ** 2).sum(-1, keepdim=True)
    return _straight_through(torch.where(err1 < err0, q[1], q[0]), v)


def decode_texels(ea: torch.Tensor, eb: torch.Tensor, x: torch.Tensor, quantized: bool = False) -> torch.Tensor:
    """Texel values in [0, 1] (M, 4) from endpoints ``ea``, ``eb`` (M, 4) and continuous indices (M,)."""
    if quantized:
        ea, eb = quantize_endpoints(ea), quantize_endpoints(eb)
        x = _straight_through(torch.round(x.clamp(0.0, 1.0) * LEVELS) / LEVELS, x)
    else:
        ea, eb = ea.clamp(0.0, 255.0), eb.clamp(0.0, 255.0)
    w = weight_of(x).unsqueeze(-1)
    v = ((64.0 - w) * ea + w * eb + 32.0) / 64.0
    return _straight_through(torch.floor(v), v) / 255.0


def decode_blocks(endpoints: torch.Tensor, x: torch.Tensor, quantized: bool = False) -> torch.Tensor:
    """(n, 2, 4) endpoints and (n, 16) indices -> (n, 16, 4) texel values in [0, 1]."""
    ea = endpoints[:, None, 0].expand(-1, 16, -1)
    eb = endpoints[:, None, 1].expand(-1, 16, -1)
    return decode_texels(ea, eb, x, quantized)
