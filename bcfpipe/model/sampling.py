"""Texture sampling exactly as GPU hardware filters (OpenGL 4.5 §8.14, D3D11 3.5.8).

Conventions shared by training, ONNX cross-checks and the GLSL runtime:
- uv in [0, 1) spans the texture; texel i of a level with w texels has its centre at (i + 0.5) / w.
  v = 0 is the first row in memory (the top row of the source image file, the DDS's first row).
- Bilinear within a level, linear between the two nearest levels (LINEAR_MIPMAP_LINEAR).
- ``lod`` is clamped to [0, last level]; lod <= 0 samples level 0 bilinearly (magnification).
- Addressing is ``repeat`` (GL_REPEAT) or ``clamp`` (GL_CLAMP_TO_EDGE). uv is range-reduced first,
  exactly as glsl/bcf_decode.glsl does (:func:`reduce_uv`), so far-away uvs address the same texels
  with the same weights as uvs in [0, 1).
Tensors are (C, H, W) per level; sample points are (N, 2).
"""
from __future__ import annotations

from typing import Callable, Sequence

import torch

from bcfpipe.formats.vocabulary import Wrap

WRAP_MODES = (Wrap.REPEAT, Wrap.CLAMP)


def _address(i: torch.Tensor, n: int, wrap: str) -> torch.Tensor:
    return torch.remainder(i, n) if wrap == Wrap.REPEAT else i.clamp(0, n - 1)


def reduce_uv(uv: torch.Tensor, wrap: str) -> torch.Tensor:
    """uv - floor(uv) for repeat (exact in fp32), uv clamped to [-1, 2] for clamp-to-edge: the same
    texels and weights, with coordinates small enough that ``uv * w`` keeps its sub-texel bits."""
    return uv - torch.floor(uv) if wrap == Wrap.REPEAT else uv.clamp(-1.0, 2.0)


TexelFn = Callable[[torch.Tensor], torch.Tensor]  # flat texel ids (M,) -> values (M, C)


def sample_bilinear(tex: torch.Tensor, uv: torch.Tensor, wrap: str = Wrap.REPEAT) -> torch.Tensor:
    """Bilinear sample of one level ``tex`` (C, H, W) at ``uv`` (N, 2) -> (N, C)."""
    c, h, w = tex.shape
    flat = tex.reshape(c, h * w).t()  # (H*W, C)
    return sample_bilinear_fn(lambda ids: flat[ids], h, w, uv, wrap)


def sample_bilinear_fn(texels: TexelFn, h: int, w: int, uv: torch.Tensor, wrap: str = Wrap.REPEAT) -> torch.Tensor:
    """Bilinear sample of an h x w level whose texels are produced on demand by ``texels``
    (row-major flat ids -> values). Training uses this to decode only the 4 taps of each sample
    instead of a whole level, so a step costs O(batch) rather than O(level size)."""
    uv = reduce_uv(uv, wrap)
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0f, y0f = torch.floor(x), torch.floor(y)
    fx, fy = (x - x0f).unsqueeze(1), (y - y0f).unsqueeze(1)
    x0, y0 = x0f.long(), y0f.long()
    xa, xb = _address(x0, w, wrap), _address(x0 + 1, w, wrap)
    ya, yb = _address(y0, h, wrap), _address(y0 + 1, h, wrap)
    n = uv.shape[0]
    ids = torch.cat([ya * w + xa, ya * w + xb, yb * w + xa, yb * w + xb])
    t00, t01, t10, t11 = texels(ids).split(n)
    top = t00 + (t01 - t00) * fx
    bot = t10 + (t11 - t10) * fx
    return top + (bot - top) * fy


def level_weights(lod: torch.Tensor | float, n_levels: int) -> tuple[torch.Tensor | int, torch.Tensor | int, torch.Tensor | float]:
    """(lower level, upper level, blend) for a trilinear fetch at ``lod`` over ``n_levels`` levels."""
    if isinstance(lod, torch.Tensor):
        l = lod.clamp(0, n_levels - 1)
        lo = torch.floor(l).long().clamp(max=n_levels - 1)
        return lo, (lo + 1).clamp(max=n_levels - 1), l - lo
    l = min(max(float(lod), 0.0), n_levels - 1)
    lo = min(int(l), n_levels - 1)
    return lo, min(lo + 1, n_levels - 1), l - lo


def sample_trilinear(levels: Sequence[torch.Tensor], uv: torch.Tensor, lod: torch.Tensor | float,
                     wrap: str = Wrap.REPEAT) -> torch.Tensor:
    """Trilinear sample of a mip pyramid ``levels`` [(C, H_k, W_k)] -> (N, C).

    ``lod`` is a float (one lod for the whole batch, as in training: only two levels are touched)
    or a tensor (N,) of per-point lods (evaluation, verification).
    """
    lo, hi, t = level_weights(lod, len(levels))
    if not isinstance(lod, torch.Tensor):
        a = sample_bilinear(levels[lo], uv, wrap)
        if hi == lo or t == 0.0:
            return a
        return a + (sample_bilinear(levels[hi], uv, wrap) - a) * t
    out = uv.new_zeros(uv.shape[0], levels[0].shape[0])
    t = t.unsqueeze(1)
    for k, tex in enumerate(levels):
        w = torch.where(lo.unsqueeze(1) == k, 1 - t, 0) + torch.where((hi.unsqueeze(1) == k) & (hi != lo).unsqueeze(1), t, 0)
        sel = (w[:, 0] > 0).nonzero().squeeze(1)
        if sel.numel():
            out = out.index_add(0, sel, sample_bilinear(tex, uv[sel], wrap) * w[sel])
    return out
