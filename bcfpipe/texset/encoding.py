"""The output encoding of an HDR channel: relative precision across its whole range.

A float colour channel whose values are non-negative and exceed 1 (emission, HDR light) is not
learnt linearly: an error of 1 % of a 0..3,000 range is 30 units, which wipes out every texel
below 30. Such a channel is learnt in a log domain with gain ``g`` (per channel, fp16):

    v_n = (v - lo) / (hi - lo)                        the linear normalisation every channel has
    t   = log2(1 + v_n (2^g - 1)) / g                 what the MLP learns, in [0, 1]
    v_n = (2^(g t) - 1) / (2^g - 1)                   what every decoder computes after the clamp

with ``2^g = 1 + hi - lo`` (rounded to fp16), so t is log1p of the source value over log1p of the
peak: equal steps of t are equal ratios of v above 1, and steps of about one unit below it. The
decoders (torch, ONNX, GLSL) apply the second line after clamping t to [0, 1], so their output is
the linear v_n as before and material.json's value_scale / value_bias (and the USD layer's scale
and bias) are unchanged in meaning. ``g = 0`` is the linear encoding: every LDR channel, normals,
signed data, and scalar data such as displacement, whose errors matter in absolute units.
The gain travels in the decoder's weight record (BCFW version 2, bcfpipe.model.decoder).
"""
from __future__ import annotations

import numpy as np

__all__ = ["log_gain_for", "encode", "decode", "encode_levels", "decode_levels", "gains"]


def log_gain_for(kind: str, is_float: bool, lo: float, hi: float) -> float:
    """The gain for a channel of ``kind`` whose source values span [lo, hi]: 0 (linear) unless it
    is a non-negative float colour channel beyond 1."""
    if kind != "color" or not is_float or lo < 0.0 or hi <= 1.0:
        return 0.0
    return float(np.float16(np.log2(1.0 + (hi - min(lo, 0.0)))))


def encode(v: np.ndarray, g: float) -> np.ndarray:
    """Linear normalised values in [0, 1] -> the learnt domain (identity for g = 0)."""
    if g <= 0.0:
        return v
    v = np.asarray(v, np.float64)
    return (np.log2(1.0 + np.clip(v, 0.0, None) * (np.exp2(g) - 1.0)) / g).astype(np.float32)


def decode(t: np.ndarray, g: float) -> np.ndarray:
    """The learnt domain -> linear normalised values (identity for g = 0); float32 as the decoders."""
    if g <= 0.0:
        return t
    t = np.asarray(t, np.float32)
    return ((np.exp2(np.float32(g) * t) - np.float32(1)) * np.float32(1.0 / (np.exp2(np.float64(g)) - 1.0))
            ).astype(np.float32)


def gains(channels) -> np.ndarray:
    """Per model channel, its gain (``Channel.log_gain``), float32."""
    return np.array([getattr(c, "log_gain", 0.0) for c in channels], np.float32)


def _map_levels(levels, g: np.ndarray, fn) -> list[np.ndarray]:
    if not np.any(g > 0):
        return list(levels)
    out = []
    for m in levels:
        m = np.array(m, np.float32)
        for c in np.nonzero(g > 0)[0]:
            m[..., c] = fn(m[..., c], float(g[c]))
        out.append(m)
    return out


def encode_levels(levels, g: np.ndarray) -> list[np.ndarray]:
    """Each (H, W, c) level with every channel in its learnt domain. Mips are filtered in the linear
    domain first (as a GPU filters texels), then encoded."""
    return _map_levels(levels, g, encode)


def decode_levels(levels, g: np.ndarray) -> list[np.ndarray]:
    """Inverse of `encode_levels`."""
    return _map_levels(levels, g, decode)
