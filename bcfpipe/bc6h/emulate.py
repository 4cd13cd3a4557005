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
"""

from __future__ import annotations

import numpy as np
import torch

from . import mode10
from .tables import PARTITIONS2, WEIGHTS3

__all__ = [
    "decode_blocks",
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
        if name == "w3":
            vals = np.asarray(WEIGHTS3, dtype=np.float64)
        else:  # "u_unsigned" / "u_signed": unquantized value of every 6-bit endpoint
            vals = mode10.unquantize_table(name == "u_signed")[1].astype(np.float64)
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


def decode_blocks(
    endpoints: torch.Tensor,
    x: torch.Tensor,
    partition_mask: torch.Tensor,
    signed: bool = False,
    quantized: bool = False,
) -> torch.Tensor:
    """Emulated BC6H mode-10 decode of n blocks -> (n, 16, 3) texel values.

    ``endpoints`` (n, 4, 3), ``x`` (n, 16), ``partition_mask`` (n, 16) (True/1 =
    subset 1).  ``quantized=True`` rounds endpoints and indices straight-through
    first (quantization-aware forward); with ``quantized=False`` the parameters are
    used as they are, but every integer step of the decoder is still applied
    (straight-through), so integer endpoints and ``x = k/7`` reproduce the spec
    decoder bit-exactly either way.  Output dtype is float32 (float64 if the
    endpoints are float64) on the endpoints' device.
    """
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
    mask = mask.unsqueeze(-1)  # (n, 16, 1)

    u = unquantize(endpoints, signed=signed, quantized=quantized)  # (n, 4, 3)
    ua = torch.where(mask, u[:, None, 2], u[:, None, 0])  # (n, 16, 3)
    ub = torch.where(mask, u[:, None, 3], u[:, None, 1])
    w = index_weight(x, quantized=quantized).unsqueeze(-1)  # (n, 16, 1)
    v = _floor_ste((ua * (64.0 - w) + ub * w + 32.0) / 64.0)
    if signed:
        s = v * (31.0 / 32.0)
        f = _ste(s, torch.trunc(s))
    else:
        f = _floor_ste(v * (31.0 / 64.0))
    return half_from_bits(f)


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
