"""Differentiable torch emulation of BC6H mode-10 (mode bits ``11110``) decoding.

Implements the "Trainable BC6 decompression" of Weinreich et al. (EG 2024, §4.2,
eqs. 6-8) so that it is *bit-exact* with the hardware / spec decoder
(:func:`bcfpipe.bc6h.decode.decode`) at quantized parameters, and differentiable
almost everywhere in the continuous block parameters.

Per texel and channel the spec computes (integers throughout)::

    U = unquantize(e)                        # 6-bit endpoint -> 16-bit domain
    V = (Ua*(64 - w) + Ub*w + 32) >> 6       # w = WEIGHTS3[index] / 64ths
    F = (V*31) >> 6                          # unsigned; signed: trunc(V*31/32)
    value = half_from_bits(F)                # sign-magnitude for signed

with, for the unsigned format, ``U(0) = 0``, ``U(63) = 0xFFFF`` and
``U(e) = ((e << 16) + 0x8000) >> 6 = 1024 e + 512`` otherwise; for the signed
format (endpoints sign-extended to [-32, 31]) ``U(e) = sign(e) * U+(|e|)`` with
``U+(0) = 0``, ``U+(|e| >= 31) = 0x7FFF`` and ``U+ = ((|e| << 15) + 0x4000) >> 5
= 1024 |e| + 512`` otherwise.

Reconciling with the paper:

* Eq. 6, ``(a 2^16 e + 2^15) / 2^b`` with ``a = 31/64`` (unsigned) folds the final
  ``*31 >> 6`` scale into the unquantization and drops the floors and the two
  special cases.  It gives ``496 e + 512`` whereas the spec, after the finishing
  scale, gives ``(1024 e + 512) * 31/64 = 496 e + 248`` (and 0 / 31743 at the
  ends).  We therefore keep the spec's two stages separate: ``U`` is the
  piecewise-linear interpolant of the exact integer table ``U(k)`` (so the
  special cases are honoured and ``U`` is continuous in ``e``), and the scale
  ``31/64`` (``31/32`` signed) is applied after interpolation, as in the spec.
* Eq. 7 interpolates with ``2^q x``; we use the spec's weights instead (below).
* Eq. 8, ``w = 2^(h-14) (y/1024 - h)``, ``h = max(floor((y-1)/1024) - 1, 0)``, is
  exactly the IEEE half bit-cast for every integer ``y`` in [0, 31743] -- normal
  numbers *and* subnormals (``y < 1024`` gives ``h = 0`` and ``w = y 2^-24``)
  (verified in the tests).  Between integers the paper's ``h`` jumps just below
  ``y = 1024 E + 1``; we use ``h = max(floor(y/1024) - 1, 0)`` instead, which gives
  the same value at every integer and is the continuous, monotone,
  piecewise-linear interpolant of the bit-cast (linear on each exponent's
  ``[1024 E, 1024 (E+1)]``).  For the signed format we apply it to ``|F|`` and restore the sign,
  written as ``2^(h-14) (F/1024 - sign(F) h)`` so the derivative stays
  ``2^(h-24)`` at ``F = 0`` too.

All floors / truncations are straight-through: the forward value is the exact
integer the spec computes, the backward pass treats the rounding as identity.
All intermediate integers are < 2^24 and hence exact in float32.

Continuous index -> weight mapping (the spec's 3-bit weights are
``W3 = {0, 9, 18, 27, 37, 46, 55, 64}``, *not* ``64 k / 7``)::

    phi(x) = W3[k] + (7x - k) (W3[k+1] - W3[k]),   k = min(floor(7x), 6),  x in [0, 1]

i.e. the monotone piecewise-linear map with ``phi(k/7) = W3[k]``; slopes are
63 or 70 (64ths per unit x).  Quantization of x is ``index = round(7x)``, which is
also the nearest weight.  Values of ``x`` within 1e-4 of a knot ``k/7`` are snapped
(straight-through) so that ``x = k/7`` in floating point decodes exactly.

Parameter tensors (see :mod:`bcfpipe.bc6h.mode10` for the integer conventions):
``endpoints`` float (n, 4, 3) in the 6-bit domain -- [0, 63] unsigned, [-32, 31]
signed -- ordered (e0, e1) subset 0, (e2, e3) subset 1; ``x`` float (n, 16) in
[0, 1]; ``partition_mask`` (n, 16) bool/float, True for texels of subset 1.
Inputs are clamped to these ranges (gradient zero outside, passed at the bounds).

:func:`decode_blocks` runs all of this as one autograd node (``_DecodeBlocks``): the
forward values are bit-identical to the composition of torch ops above (still
available as ``decode_blocks(..., fused=False)`` / :func:`decode_blocks_composed`),
the backward is the gradient autograd computes through that composition, written
out by hand (see the comment above ``_DecodeBlocks``).
"""

from __future__ import annotations

import numpy as np
import torch

from . import mode10
from .tables import PARTITIONS2, WEIGHTS3

__all__ = [
    "decode_blocks",
    "decode_blocks_composed",
    "decode_texels",
    "index_weight",
    "unquantize",
    "half_from_bits",
    "partition_mask",
    "from_params",
    "from_blocks",
    "to_params",
    "to_blocks",
]

_SNAP_EPS = 1e-4


def _ste(x: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """Forward ``q``, backward identity w.r.t. ``x``."""
    return x + (q - x).detach()


def _floor_ste(x: torch.Tensor) -> torch.Tensor:
    return _ste(x, torch.floor(x))


def _compute_dtype(t: torch.Tensor) -> torch.dtype:
    return torch.float64 if t.dtype == torch.float64 else torch.float32


_TABLES: dict[tuple, torch.Tensor] = {}


def _table(name: str, like: torch.Tensor) -> torch.Tensor:
    """Constant table ``name`` on ``like``'s device and dtype (cached)."""
    key = (name, like.device, like.dtype)
    tab = _TABLES.get(key)
    if tab is None:
        base = name[:-5] if name.endswith("_diff") else name
        if base == "w3":
            vals = np.asarray(WEIGHTS3, dtype=np.float64)
        else:  # "u_unsigned" / "u_signed": unquantized value of every 6-bit endpoint
            vals = mode10.unquantize_table(base == "u_signed")[1].astype(np.float64)
        if name.endswith("_diff"):  # slope of segment k: table[k + 1] - table[k] (exact integers)
            vals = np.append(np.diff(vals), 0.0)
        tab = torch.tensor(vals, dtype=like.dtype, device=like.device)
        _TABLES[key] = tab
    return tab


def index_weight(x: torch.Tensor, quantized: bool = False) -> torch.Tensor:
    """Continuous index x in [0, 1] -> interpolation weight in [0, 64] (64ths), see module doc."""
    t = 7.0 * x.clamp(0.0, 1.0)
    k = torch.round(t)
    if quantized:
        t = _ste(t, k)
    else:
        t = torch.where((t - k).abs() < 7.0 * _SNAP_EPS, _ste(t, k), t)
    k0 = torch.floor(t.detach()).clamp(0, 6).long()
    w3 = _table("w3", t)
    lo = w3[k0]
    return lo + (t - k0.to(t.dtype)) * (w3[k0 + 1] - lo)


def unquantize(e: torch.Tensor, signed: bool = False, quantized: bool = False) -> torch.Tensor:
    """6-bit endpoint (continuous) -> 16-bit interpolation domain.

    Piecewise-linear interpolant of the spec's integer table (exact at integers,
    special cases included).  ``quantized`` rounds ``e`` (straight-through) first.
    """
    lo, hi = (-32.0, 31.0) if signed else (0.0, 63.0)
    e = e.clamp(lo, hi)
    if quantized:
        e = _ste(e, torch.round(e))
    table = _table("u_signed" if signed else "u_unsigned", e)
    pos = e - lo  # 0..63
    k0 = torch.floor(pos.detach()).clamp(0, 62).long()
    a = table[k0]
    return a + (pos - k0.to(e.dtype)) * (table[k0 + 1] - a)


def half_from_bits(y: torch.Tensor) -> torch.Tensor:
    """Paper eq. 8: value of the half whose bits are the integer ``y`` (|y| <= 31743).

    Exact bit-cast for integer ``y``; continuous and piecewise linear in between
    (see the module doc for the one change to the paper's ``h``).  Negative ``y``
    means sign-magnitude with the sign bit set (signed BC6H), i.e. ``-half(|y|)``.
    """
    ay = y.detach().abs()
    h = torch.clamp(torch.floor(ay / 1024.0) - 1.0, min=0.0)
    s = torch.sign(y.detach())
    return torch.exp2(h - 14.0) * (y / 1024.0 - s * h)


def _check_and_convert(endpoints, x, partition_mask):
    if endpoints.ndim != 3 or endpoints.shape[1:] != (4, 3):
        raise ValueError(f"endpoints must have shape (n, 4, 3), got {tuple(endpoints.shape)}")
    n = endpoints.shape[0]
    if x.shape != (n, 16) or partition_mask.shape != (n, 16):
        raise ValueError("x and partition_mask must have shape (n, 16)")
    dtype = _compute_dtype(endpoints)
    endpoints = endpoints.to(dtype)
    x = x.to(device=endpoints.device, dtype=dtype)
    mask = partition_mask.to(device=endpoints.device)
    mask = (mask > 0.5) if mask.dtype != torch.bool else mask
    return endpoints, x, mask


def decode_blocks(
    endpoints: torch.Tensor,
    x: torch.Tensor,
    partition_mask: torch.Tensor,
    signed: bool = False,
    quantized: bool = False,
    fused: bool = True,
) -> torch.Tensor:
    """Emulated BC6H mode-10 decode of n blocks -> (n, 16, 3) texel values.

    ``endpoints`` (n, 4, 3), ``x`` (n, 16), ``partition_mask`` (n, 16) (True/1 =
    subset 1).  ``quantized=True`` rounds endpoints and indices straight-through
    first (quantization-aware forward); with ``quantized=False`` the parameters are
    used as they are, but every integer step of the decoder is still applied
    (straight-through), so integer endpoints and ``x = k/7`` reproduce the spec
    decoder bit-exactly either way.  Output dtype is float32 (float64 if the
    endpoints are float64) on the endpoints' device.

    ``fused=True`` (default) runs the single autograd node :class:`_DecodeBlocks`;
    ``fused=False`` the composition of elementwise torch ops
    (:func:`decode_blocks_composed`).  Both give bit-identical values and the same
    gradients (up to float rounding of the backward arithmetic); the fused one is
    several times faster and saves far less for backward, but is differentiable
    only once (no double backward).  Its result is a (n, 16, 3) view of a
    channel-planar (3, n, 16) tensor (not contiguous).
    """
    endpoints, x, mask = _check_and_convert(endpoints, x, partition_mask)
    if not fused:
        return _decode_composed(endpoints, x, mask, signed, quantized)
    if torch.is_grad_enabled() and (endpoints.requires_grad or x.requires_grad):
        return _DecodeBlocks.apply(endpoints, x, mask, bool(signed), bool(quantized))
    return _fused_forward(endpoints, x, mask, bool(signed), bool(quantized), False, False)[0]


def decode_blocks_composed(
    endpoints: torch.Tensor,
    x: torch.Tensor,
    partition_mask: torch.Tensor,
    signed: bool = False,
    quantized: bool = False,
) -> torch.Tensor:
    """:func:`decode_blocks` as a composition of elementwise torch ops (the reference
    implementation: autograd differentiates it; kept for tests and benchmarks)."""
    return decode_blocks(endpoints, x, partition_mask, signed, quantized, fused=False)


def _interpolate_finish(ua: torch.Tensor, ub: torch.Tensor, w: torch.Tensor, signed: bool) -> torch.Tensor:
    """Spec interpolation of unquantized endpoints with weight ``w`` (64ths), the finishing scale
    and the half bit-cast (module doc, lines 2-4 of the per-texel formula)."""
    v = _floor_ste((ua * (64.0 - w) + ub * w + 32.0) / 64.0)
    if signed:
        s = v * (31.0 / 32.0)
        f = _ste(s, torch.trunc(s))
    else:
        f = _floor_ste(v * (31.0 / 64.0))
    return half_from_bits(f)


def _decode_composed(endpoints, x, mask, signed, quantized):
    mask = mask.unsqueeze(-1)  # (n, 16, 1)
    u = unquantize(endpoints, signed=signed, quantized=quantized)  # (n, 4, 3)
    ua = torch.where(mask, u[:, None, 2], u[:, None, 0])  # (n, 16, 3)
    ub = torch.where(mask, u[:, None, 3], u[:, None, 1])
    w = index_weight(x, quantized=quantized).unsqueeze(-1)  # (n, 16, 1)
    return _interpolate_finish(ua, ub, w, signed)


def decode_texels(ea: torch.Tensor, eb: torch.Tensor, x: torch.Tensor, signed: bool = False,
                  quantized: bool = False) -> torch.Tensor:
    """Single texels from their subset's endpoints ``ea``, ``eb`` (M, 3) and continuous index
    ``x`` (M,): :func:`decode_blocks`'s arithmetic per texel (the trainer's sparse taps)."""
    ua = unquantize(ea, signed=signed, quantized=quantized)
    ub = unquantize(eb, signed=signed, quantized=quantized)
    return _interpolate_finish(ua, ub, index_weight(x, quantized=quantized).unsqueeze(1), signed)


# ---------------------------------------------------------------------------
# fused decode: one autograd node
# ---------------------------------------------------------------------------
#
# The forward repeats the composed version's float operations on the same values
# (in place, without a graph), so it is bit-identical, with rewrites that are exact
# for every finite input:
#
# * ``torch.where(mask, u2, u0) * (64 - w)`` (where is slow on CPU: not vectorised,
#   and with the (n, 16, 3) layout its broadcast inner loop is 3 long) ->
#   ``u0 * W0 + u2 * W2`` with ``W0 = (1 - m)(64 - w)``, ``W2 = m (64 - w)``: one
#   product is the one the composed version rounds, the other is +-0, and adding
#   +-0 is exact (the sign of a zero is lost in the ``+ 32`` that follows anyway).
#   Likewise ``ub * w``.  (An FMA in addcmul is harmless: it adds to a +-0 or a 0.)
# * ``_floor_ste(p) = p + (floor(p) - p)`` -> ``floor(p)``: ``floor(p) - p`` is
#   exact (Sterbenz) unless -1 < p < 0, where the sum still rounds to -1; p is never
#   -0.  ``_ste(s, trunc(s))`` -> ``trunc(s) + 0.0`` (the ``+ 0.0`` turns the -0 of
#   trunc(-0.5) into the +0 the STE gives).
# * ``half_from_bits(f)`` of the integer ``f`` (|f| <= 31743) -> the IEEE half
#   bit-cast of ``|f|`` (eq. 8 *is* that bit-cast, see the tests), with the sign
#   copied from ``f``.
# * ``where(|t - k| < eps, t + (k - t), t)`` -> ``t + (k - t) * [|k - t| < eps]``
#   (t is not 0 where the snap is off, so adding +-0 changes nothing).
#
# The texel-sized work is done channel-planar, (3, n, 16), so that the per-texel
# weight (n, 16) broadcasts over a contiguous inner dimension.
#
# Backward: with ``p = (ua (64 - w) + ub w + 32) / 64`` and the straight-through
# steps as identity, d out / d p = c * exp2(h - 14) / 1024 (c = 31/64, 31/32
# signed) with h = max(floor(|f| / 1024) - 1, 0) = max(E, 1) - 1 for the half
# exponent field E of the output; exp2(max(E, 1) - 15) is the half with bits
# max(|f| & 0x7C00, 0x0400).  Saved: those int16 bits (3, n, 16), w and dw/dx (n, 16),
# ub - ua per subset (3, n, 2), du/de (n, 4, 3) and the mask.


def _lookup(name: str, k: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(table[k], table[k + 1] - table[k]) for integer-valued float ``k`` (index_select with
    int32 indices: cheaper than advanced indexing, which needs int64)."""
    ki = k.to(torch.int32).reshape(-1)
    lo = _table(name, k).index_select(0, ki).view(k.shape)
    return lo, _table(name + "_diff", k).index_select(0, ki).view(k.shape)


def _eq(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a == b`` as 0.0 / 1.0 in a's dtype (bool results are slow to make and to use on CPU)."""
    return torch.eq(a, b, out=torch.empty_like(a))


def _unquantize_fwd(e: torch.Tensor, signed: bool, quantized: bool, need_grad: bool):
    """(unquantize(e), d unquantize / d e or None), no graph; bit-identical to :func:`unquantize`."""
    lo, hi = (-32.0, 31.0) if signed else (0.0, 63.0)
    pos = e.clamp(lo, hi)
    inside = _eq(pos, e) if need_grad else None  # clamp passes the gradient on [lo, hi]
    if quantized:
        pos.add_(torch.round(pos).sub_(pos))  # _ste(e, round(e))
    if lo:
        pos.sub_(lo)
    k0 = torch.floor(pos).clamp_(0, 62)
    u, slope = _lookup("u_signed" if signed else "u_unsigned", k0)
    u.add_(pos.sub_(k0).mul_(slope))  # a + (pos - k0) * (table[k0 + 1] - a)
    return u, (slope.mul_(inside) if need_grad else None)


def _index_weight_fwd(x: torch.Tensor, quantized: bool, need_grad: bool):
    """(index_weight(x), d index_weight / d x or None), no graph; bit-identical."""
    t = x.clamp(0.0, 1.0)
    inside = _eq(t, x) if need_grad else None
    t.mul_(7.0)
    d = torch.round(t).sub_(t)  # k - t
    if quantized:
        t.add_(d)
    else:  # where(|t - k| < eps, t + (k - t), t), as t + d * snap (t != 0 where snap is False)
        t.add_(d.mul_(torch.lt(d.abs(), 7.0 * _SNAP_EPS, out=torch.empty_like(d))))
    k0 = torch.floor(t).clamp_(0, 6)
    w, slope = _lookup("w3", k0)
    w.add_(t.sub_(k0).mul_(slope))
    return w, (slope.mul_(inside).mul_(7.0) if need_grad else None)


def _texel_weights(w: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(4, n, 16): the weight of endpoint j in texel t, ``(1-m)(64-w), (1-m) w, m (64-w), m w``
    (each exactly 0, 64 - w or w)."""
    mf = mask.to(w.dtype)
    nm = torch.sub(1.0, mf)
    om = torch.sub(64.0, w)
    wts = torch.empty((4,) + w.shape, dtype=w.dtype, device=w.device)
    torch.mul(nm, om, out=wts[0])
    torch.mul(nm, w, out=wts[1])
    torch.mul(mf, om, out=wts[2])
    torch.mul(mf, w, out=wts[3])
    return wts


def _fused_forward(endpoints, x, mask, signed, quantized, need_e, need_x):
    """Decoded texels (n, 16, 3) and what the backward needs (None if it needs nothing)."""
    u, dude = _unquantize_fwd(endpoints, signed, quantized, need_e)  # (n, 4, 3)
    w, dwdx = _index_weight_fwd(x, quantized, need_x)  # (n, 16)
    wts = _texel_weights(w, mask)
    up = u.permute(2, 0, 1).contiguous()  # (3, n, 4)
    # ua (64 - w) = u0 wts0 + u2 wts2 and ub w = u1 wts1 + u3 wts3, exactly: one term is the
    # product the composed version rounds, the other is +-0
    f = torch.mul(up[..., 0:1], wts[0]).addcmul_(up[..., 2:3], wts[2])  # (3, n, 16)
    f.add_(torch.mul(up[..., 1:2], wts[1]).addcmul_(up[..., 3:4], wts[3]))
    f.add_(32.0).div_(64.0).floor_()  # V
    del wts
    if signed:
        f.mul_(31.0 / 32.0).trunc_().add_(0.0)  # F
    else:
        f.mul_(31.0 / 64.0).floor_()
    bits = f.to(torch.int16)
    if signed:
        bits.abs_()
    out = bits.view(torch.float16).to(endpoints.dtype)  # half_from_bits(|F|)
    if signed:
        out.copysign_(f)
    del f
    saved = None
    if need_e or need_x:
        du = up[..., 1::2] - up[..., 0::2]  # (3, n, 2): ub - ua of subsets 0 and 1
        saved = (bits, w, dwdx, mask, du, dude)
    return out.permute(1, 2, 0), saved  # (n, 16, 3) view of the planar result


class _DecodeBlocks(torch.autograd.Function):
    """Fused :func:`decode_blocks` (see the comment above); inputs already converted."""

    @staticmethod
    def forward(ctx, endpoints, x, mask, signed, quantized):
        out, saved = _fused_forward(endpoints, x, mask, signed, quantized, *ctx.needs_input_grad[:2])
        if saved is not None:
            ctx.save_for_backward(*saved)
            ctx.signed = signed
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad):
        bits, w, dwdx, mask, du, dude = ctx.saved_tensors
        need_e, need_x = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        # d out / d p = c 2^-10 exp2(max(E, 1) - 15); gp = grad exp2(max(E, 1) - 15), the constant
        # c 2^-10 / 64 is applied to the (smaller) results
        k = (31.0 / 32.0 if ctx.signed else 31.0 / 64.0) * 2.0**-16
        gp = torch.bitwise_and(bits, 0x7C00).clamp_min_(0x400).view(torch.float16).to(w.dtype)
        gp.mul_(grad.permute(2, 0, 1))  # (3, n, 16)
        ge = gx = None
        if need_x:  # d p / d w = (ub - ua) / 64
            mf = mask.to(w.dtype)
            d = torch.mul(du[..., 0:1], torch.sub(1.0, mf)).addcmul_(du[..., 1:2], mf)
            gx = d.mul_(gp).sum(0).mul_(dwdx).mul_(k)
        if need_e:  # d p / d ua = (64 - w) / 64, d p / d ub = w / 64, summed per subset
            gu = torch.bmm(_texel_weights(w, mask).permute(1, 0, 2), gp.permute(1, 2, 0))  # (n, 4, 3)
            ge = gu.mul_(dude).mul_(k)
        return ge, gx, None, None, None


# ---------------------------------------------------------------------------
# numpy block parameters <-> torch tensors
# ---------------------------------------------------------------------------


def partition_mask(partition, device=None) -> torch.Tensor:
    """bool (n, 16): subset-1 membership of each texel for partition ids (n,)."""
    p = partition.detach().cpu().numpy() if isinstance(partition, torch.Tensor) else np.asarray(partition)
    return torch.as_tensor(PARTITIONS2[p.astype(np.int64)].astype(bool), device=device)


def from_params(endpoints, indices, partition, device=None, dtype=torch.float32):
    """Integer block parameters (numpy, see :mod:`mode10`) -> torch tensors.

    Returns ``(endpoints float (n,4,3), x = indices/7 (n,16), mask bool (n,16),
    partition long (n,))``; feeding them to :func:`decode_blocks` reproduces
    the decoded blocks exactly.
    """
    e = torch.as_tensor(np.asarray(endpoints, dtype=np.float64), dtype=dtype, device=device)
    x = torch.as_tensor(np.asarray(indices, dtype=np.float64) / 7.0, dtype=dtype, device=device)
    part = np.asarray(partition, dtype=np.int64)
    return e, x, partition_mask(part, device), torch.as_tensor(part, device=device)


def from_blocks(blocks, signed: bool = False, device=None, dtype=torch.float32):
    """Mode-10 BC6H blocks uint8 (n, 16) -> ``from_params(*mode10.unpack(blocks))``."""
    return from_params(*mode10.unpack(blocks, signed=signed), device=device, dtype=dtype)


def to_params(endpoints: torch.Tensor, x: torch.Tensor, partition, signed: bool = False):
    """Quantize continuous tensors -> integer numpy params ``(endpoints, indices, partition)``.

    Endpoints are rounded and clamped to the format's range; ``index = round(7x)``.
    """
    lo, hi = (-32, 31) if signed else (0, 63)
    e = torch.round(endpoints.detach().double()).clamp(lo, hi).cpu().numpy().astype(np.int64)
    idx = torch.round(7.0 * x.detach().double().clamp(0.0, 1.0)).cpu().numpy().astype(np.int64)
    p = partition.detach().cpu().numpy() if isinstance(partition, torch.Tensor) else np.asarray(partition)
    return e, idx, p.astype(np.int64)


def to_blocks(endpoints: torch.Tensor, x: torch.Tensor, partition, signed: bool = False) -> np.ndarray:
    """Quantize and pack: continuous tensors -> uint8 (n, 16) mode-10 blocks."""
    return mode10.pack(*to_params(endpoints, x, partition, signed=signed), signed=signed)
