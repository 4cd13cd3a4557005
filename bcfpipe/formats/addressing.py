"""Texel addressing per axis, as GL_REPEAT, GL_CLAMP_TO_EDGE and GL_MIRRORED_REPEAT address: which
texel of n an index names (`address`, for numpy arrays and torch tensors alike: the samplers of
training, scan, layout and verify share it), how a coordinate is range-reduced as the decoder does
(`reduce_coord`, numpy; bcfpipe.model.sampling has torch's), and each mode's code and GL enum. The
fused kernels and bcf_decode.glsl address alike."""
from __future__ import annotations

import numpy as np

from bcfpipe.formats.vocabulary import Wrap, wrap_axes


def address(i, n: int, mode: str):
    """Texels ``i`` (an integer numpy array or torch tensor) of ``n`` along an axis addressed with
    ``mode``: i mod n for repeat (Python's modulo, as both libraries' ``%``), i clamped to [0, n - 1]
    for clamp, and for mirror i mod 2n reflected (period 2n: texel -1 is texel 0, texel n is n - 1)."""
    if mode == Wrap.REPEAT:
        return i % n
    if mode == Wrap.MIRROR:
        j = i % (2 * n)
        return j + (j >= n) * (2 * n - 1 - 2 * j)
    return i.clip(0, n - 1)


def reduce_coord(x, mode: str):
    """A coordinate range-reduced for ``mode`` as the decoder does (bcfReduceUv): x - floor(x) for
    repeat, x - 2 floor(x / 2) for mirror, x clamped to [-1, 2] for clamp."""
    if mode == Wrap.REPEAT:
        return x - np.floor(x)
    if mode == Wrap.MIRROR:
        return x - 2.0 * np.floor(x * 0.5)
    return np.clip(x, -1.0, 2.0)


# Each mode's code where a shader or kernel takes an int: bcf_decode.glsl's BCF_WRAP_*, the fused
# kernels' (bcfpipe.train.fused.common).
WRAP_CODES = {Wrap.REPEAT: 0, Wrap.CLAMP: 1, Wrap.MIRROR: 2}


def wrap_codes(wrap) -> tuple[int, int]:
    """(S, T) codes of an addressing (one mode or a pair): the decoder's ``uWrap`` uniform."""
    s, t = wrap_axes(wrap)
    return WRAP_CODES[s], WRAP_CODES[t]


def gl_wrap_modes(wrap, GL) -> tuple[int, int]:
    """(GL_TEXTURE_WRAP_S, GL_TEXTURE_WRAP_T) values of an addressing, with ``GL`` PyOpenGL's module."""
    modes = {Wrap.REPEAT: GL.GL_REPEAT, Wrap.CLAMP: GL.GL_CLAMP_TO_EDGE, Wrap.MIRROR: GL.GL_MIRRORED_REPEAT}
    s, t = wrap_axes(wrap)
    return modes[s], modes[t]
