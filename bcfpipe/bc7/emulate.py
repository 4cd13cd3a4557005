"""Differentiable torch emulation of the BC7 blocks bcfpipe writes (modes 6 and 7,
:mod:`bcfpipe.bc7.modes`), bit-exact with :mod:`bcfpipe.bc7.decode` at quantized parameters.

Per texel and channel the spec computes, in integers (:mod:`bcfpipe.bc7.mode6`, :mod:`.mode7`)::

    value = ((64 - w) e_a + w e_b + 32) >> 6,   w = WEIGHTS[index],   read as value / 255

with (e_a, e_b) the endpoints of the texel's subset (0 and 1, or 2 and 3 in subset 1 of a mode-7
block) and the 4-bit (mode 6, L = 15) or 2-bit (mode 7, L = 3) weight table. Both tables are
``WEIGHTS[k] = floor((64 k + (L - 1) / 2) / L)``.

Trainable parameters are ``endpoints`` (n, 4, 4) continuous in the 8-bit domain [0, 255] and
``x`` (n, 16) continuous in [0, 1] (index / L). A block's shape (``mask``, True for texels of
subset 1) and mode (``levels``, L per block) stay as the encoder chose them. The index maps to its
weight through the monotone piecewise-linear ``phi`` with ``phi(k / L) = WEIGHTS[k]``; values of x
within 1e-4 of a knot are snapped, so x = k / L decodes exactly. The final shift is a floor,
straight-through (forward the spec's integer, backward identity); every intermediate is an integer
below 2^15, exact in float32.

Quantization-aware decoding (``quantized=True``) rounds x to the nearest of the L + 1 indices and
each endpoint to :func:`quantize_endpoints`'s choice (mode 6: 7 bits plus a p-bit; mode 7: 5 bits
plus a p-bit, widened to 8; the four channels of an endpoint share the p-bit), both
straight-through: the forward value is then exactly what the exported block decodes to.
"""
from __future__ import annotations

import torch

__all__ = ["decode_blocks", "decode_blocks_composed", "decode_texels", "quantize_endpoints", "weight_of",
           "MODE6_LEVELS", "MODE7_LEVELS", "levels_of"]

MODE6_LEVELS = 15.0  # index steps: x = index / 15
MODE7_LEVELS = 3.0
_SNAP = 1e-4


def _straight_through(value: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    return x + (value - x).detach()


def levels_of(partition, device=None) -> torch.Tensor:
    """(n,) float32 L per block: 15 for mode 6 (partition < 0), 3 for mode 7."""
    p = torch.as_tensor(partition, device=device)
    return torch.where(p < 0, MODE6_LEVELS, MODE7_LEVELS).to(torch.float32)


def _table_weight(k: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
    """WEIGHTS[k] for integer-valued k in [0, L] as floor((64 k + (L - 1) / 2) / L) (equal to both
    spec tables for every k, tested), so no gather is needed."""
    return torch.floor((64.0 * k + (L - 1.0) * 0.5) / L)


def _segment(t: torch.Tensor, L: torch.Tensor):
    near = torch.round(t)
    snapped = (t - near).abs() < _SNAP * L
    k = torch.minimum(torch.floor(torch.where(snapped, near, t).detach()), L - 1.0)
    return near, snapped, k


def weight_of(x: torch.Tensor, L: torch.Tensor | float = MODE6_LEVELS) -> torch.Tensor:
    """Continuous index x in [0, 1] -> interpolation weight in 64ths (piecewise linear through the
    weight table of L + 1 entries; ``L`` broadcasts against x)."""
    L = torch.as_tensor(L, dtype=x.dtype, device=x.device)
    t = x.clamp(0.0, 1.0) * L
    near, snapped, k = _segment(t, L)
    t = torch.where(snapped, _straight_through(near, t), t)
    lo, hi = _table_weight(k, L), _table_weight(k + 1.0, L)
    return lo + (t - k) * (hi - lo)


def _nearest_on_grid(v: torch.Tensor, p: float, seven: torch.Tensor) -> torch.Tensor:
    """Per channel, the nearest endpoint value with p-bit p: mode 6 2c + p (c in 0..127); mode 7
    the widened 6-bit value (v6 << 2) | (v6 >> 4) with v6 = 2c + p (c in 0..31), ties to the smaller."""
    q6 = torch.clamp(2.0 * torch.floor((v - p) / 2.0 + 0.5) + p, p, 254.0 + p)
    c0 = torch.clamp(torch.round((v * (63.0 / 255.0) - p) / 2.0), 0.0, 31.0)
    best = best_d = None
    for dc in (-1.0, 0.0, 1.0):
        v6 = 2.0 * torch.clamp(c0 + dc, 0.0, 31.0) + p
        cand = 4.0 * v6 + torch.floor(v6 / 16.0)
        d = (cand - v).abs()
        if best is None:
            best, best_d = cand, d
        else:
            take = (d < best_d) | ((d == best_d) & (cand < best))
            best, best_d = torch.where(take, cand, best), torch.where(take, d, best_d)
    return torch.where(seven, best, q6)


def quantize_endpoints(e: torch.Tensor, seven: torch.Tensor | bool = False) -> torch.Tensor:
    """Nearest representable endpoint values (..., 4), straight-through: per endpoint, the p-bit
    whose grid lies nearer (ties to p = 0). ``seven`` (broadcast against e[..., :1]): mode-7 endpoints."""
    v = e.clamp(0.0, 255.0)
    vd = v.detach()
    seven = torch.as_tensor(seven, device=e.device)
    q0, q1 = _nearest_on_grid(vd, 0.0, seven), _nearest_on_grid(vd, 1.0, seven)
    err0 = ((q0 - vd) ** 2).sum(-1, keepdim=True)
    err1 = ((q1 - vd) ** 2).sum(-1, keepdim=True)
    return _straight_through(torch.where(err1 < err0, q1, q0), v)


def _prepare(ea: torch.Tensor, eb: torch.Tensor, x: torch.Tensor, L: torch.Tensor, quantized: bool):
    """ea, eb (..., 4); x and L (...)."""
    if quantized:
        seven = (L == MODE7_LEVELS).unsqueeze(-1)
        ea, eb = quantize_endpoints(ea, seven), quantize_endpoints(eb, seven)
        x = _straight_through(torch.round(x.clamp(0.0, 1.0) * L) / L, x)
    else:
        ea, eb = ea.clamp(0.0, 255.0), eb.clamp(0.0, 255.0)
    return ea, eb, weight_of(x, L).unsqueeze(-1)


def _interpolate(ea: torch.Tensor, eb: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    v = (w * (eb - ea) + (64.0 * ea + 32.0)) / 64.0  # = ((64 - w) ea + w eb + 32) / 64, exact at integers
    return _straight_through(torch.floor(v), v) / 255.0


def decode_texels(ea: torch.Tensor, eb: torch.Tensor, x: torch.Tensor, L: torch.Tensor | float = MODE6_LEVELS,
                  quantized: bool = False) -> torch.Tensor:
    """Texel values in [0, 1] (M, 4) from the endpoints ``ea``, ``eb`` (M, 4) of each texel's
    subset, continuous indices (M,) and each texel's block's L (M,) or one L."""
    L = torch.as_tensor(L, dtype=x.dtype, device=x.device).expand_as(x)
    return _interpolate(*_prepare(ea, eb, x, L, quantized))


def _per_texel(endpoints: torch.Tensor, mask: torch.Tensor | None):
    """(ea, eb) (n, 16, 4): each texel's subset's endpoints."""
    e = endpoints.reshape(endpoints.shape[0], -1, 4)
    if mask is None or e.shape[1] == 2:
        return e[:, None, 0].expand(-1, 16, -1), e[:, None, 1].expand(-1, 16, -1)
    m = mask.unsqueeze(-1)
    return torch.where(m, e[:, None, 2], e[:, None, 0]), torch.where(m, e[:, None, 3], e[:, None, 1])


def decode_blocks_composed(endpoints: torch.Tensor, x: torch.Tensor, mask: torch.Tensor | None = None,
                           levels: torch.Tensor | None = None, quantized: bool = False) -> torch.Tensor:
    """:func:`decode_blocks` as a composition of torch ops (the reference the fused node is tested against)."""
    L = _levels(levels, x)
    ea, eb = _per_texel(endpoints, mask)
    return _interpolate(*_prepare(ea, eb, x, L.expand_as(x), quantized))


def _levels(levels, x):
    if levels is None:
        return torch.full((x.shape[0], 1), MODE6_LEVELS, dtype=x.dtype, device=x.device)
    return levels.reshape(-1, 1).to(x.dtype)


class _DecodeBlocks(torch.autograd.Function):
    """:func:`decode_blocks_composed` as one autograd node: the same forward values, and the
    gradient autograd computes through the composition written out (the floor and the roundings
    pass gradients unchanged; the clamps pass them inside their range, bounds included):

        dv/d e_a = (64 - w) / (64 * 255),   dv/d e_b = w / (64 * 255),
        dv/d x  = (e_b - e_a) / (64 * 255) * phi'(x),   phi' = L (W[k + 1] - W[k]) on segment k,

    each endpoint gathering the texels of its subset.
    """

    @staticmethod
    def forward(ctx, endpoints, x, mask, L, quantized: bool):
        with torch.no_grad():
            e = endpoints.clamp(0.0, 255.0)
            if quantized:
                e = quantize_endpoints(e, (L == MODE7_LEVELS).unsqueeze(-1))
                xs = torch.round(x.clamp(0.0, 1.0) * L) / L
            else:
                xs = x
            t = xs.clamp(0.0, 1.0) * L
            near, snapped, k = _segment(t, L)
            t = torch.where(snapped, near, t)
            lo, hi = _table_weight(k, L), _table_weight(k + 1.0, L)
            w = (lo + (t - k) * (hi - lo)).unsqueeze(-1)  # (n, 16, 1)
            ea, eb = _per_texel(e, mask)
            out = (w * (eb - ea)).add_(64.0 * ea + 32.0).div_(64.0).floor_().div_(255.0)
        ctx.save_for_backward(endpoints, x, e, w, (hi - lo) * L, mask)
        ctx.quantized = quantized
        return out

    @staticmethod
    def backward(ctx, g):
        endpoints, x, e, w, slope, mask = ctx.saved_tensors
        s = 1.0 / (64.0 * 255.0)
        ga, gb = g * (64.0 - w), g * w  # (n, 16, 4)
        if e.shape[1] == 4:
            m = mask.unsqueeze(-1).to(g.dtype)
            g_e = torch.stack([(ga * (1.0 - m)).sum(1), (gb * (1.0 - m)).sum(1), (ga * m).sum(1), (gb * m).sum(1)], 1)
        else:
            g_e = torch.stack([ga.sum(1), gb.sum(1)], 1)
        g_e = g_e * s * ((endpoints >= 0.0) & (endpoints <= 255.0)).to(g.dtype)
        ea, eb = _per_texel(e, mask)
        g_x = (g * (eb - ea)).sum(-1) * s * slope
        if not ctx.quantized:  # the rounding's straight-through passes x's gradient at any x
            g_x = g_x * ((x >= 0.0) & (x <= 1.0)).to(g.dtype)
        return g_e, g_x, None, None, None


def decode_blocks(endpoints: torch.Tensor, x: torch.Tensor, mask: torch.Tensor | None = None,
                  levels: torch.Tensor | None = None, quantized: bool = False) -> torch.Tensor:
    """(n, 4, 4) or mode-6-only (n, 2, 4) endpoints, (n, 16) indices, subset-1 ``mask`` (n, 16)
    and ``levels`` (n,) (default: every block mode 6) -> (n, 16, 4) texel values in [0, 1]; one
    autograd node (:class:`_DecodeBlocks`), forward bit-identical to :func:`decode_blocks_composed`."""
    if mask is None:
        mask = torch.zeros(x.shape, dtype=torch.bool, device=x.device)
    return _DecodeBlocks.apply(endpoints, x, mask, _levels(levels, x), quantized)
