"""Texel addressing per axis on the CPU, in numpy (or on plain ints): which texel of n an index
names under repeat, clamp-to-edge or mirror, as GL_REPEAT, GL_CLAMP_TO_EDGE and GL_MIRRORED_REPEAT
do. The torch samplers (bcfpipe.model.sampling.address), the fused kernels and the GLSL decoder's
samplers address alike; scan, layout and verify use this one."""
from __future__ import annotations

import numpy as np

from bcfpipe.formats.vocabulary import Wrap, wrap_axes


def address(i, n: int, mode: str):
    """Texel ``i`` (an int or an integer array) of ``n`` along an axis addressed with ``mode``:
    i mod n for repeat, i clamped to [0, n - 1] for clamp, and for mirror i mod 2n reflected
    (texel -1 is texel 0, texel n is texel n - 1)."""
    if mode == Wrap.REPEAT:
        return np.mod(i, n)
    if mode == Wrap.MIRROR:
        j = np.mod(i, 2 * n)
        return np.where(j < n, j, 2 * n - 1 - j)
    return np.clip(i, 0, n - 1)


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
