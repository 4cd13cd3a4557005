"""Texture sampling exactly as GPU hardware filters (OpenGL 4.5 §8.14, D3D11 3.5.8).

Conventions shared by training, ONNX cross-checks and the GLSL runtime:
- uv in [0, 1) spans the texture; texel i of a level with w texels has its centre at (i + 0.5) / w.
  v = 0 is the first row in memory (the top row of the source image file, the DDS's first row).
- Bilinear within a level, linear between the two nearest levels (LINEAR_MIPMAP_LINEAR).
- ``lod`` is clamped to [0, last level]; lod <= 0 samples level 0 bilinearly (magnification).
- Addressing is per axis (S along u, T along v): ``repeat`` (GL_REPEAT), ``clamp``
  (GL_CLAMP_TO_EDGE) or ``mirror`` (GL_MIRRORED_REPEAT); ``wrap`` is one mode for both axes or an
  (S, T) pair (`wrap_axes`). uv is range-reduced first, exactly as glsl/bcf_decode.glsl does
  (:func:`reduce_uv`), so far-away uvs address the same texels with the same weights as uvs in [0, 1).
Tensors are (C, H, W) per level; sample points are (N, 2).
"""
from __future__ import annotations

from typing import Callable, Sequence

import torch

from bcfpipe.formats.addressing import address
from bcfpipe.formats.vocabulary import Wrap, wrap_axes

WRAP_MODES = (Wrap.REPEAT, Wrap.CLAMP, Wrap.MIRROR)


def reduce_coord(x: torch.Tensor, mode: str) -> torch.Tensor:
    """One coordinate range-reduced for ``mode``: x - floor(x) for repeat, x - 2 floor(x / 2) for
    mirror (both exact in fp32), x clamped to [-1, 2] for clamp-to-edge."""
    if mode == Wrap.REPEAT:
        return x - torch.floor(x)
    if mode == Wrap.MIRROR:
        return x - 2.0 * torch.floor(x * 0.5)
    return x.clamp(-1.0, 2.0)


def reduce_uv(uv: torch.Tensor, wrap) -> torch.Tensor:
    """uv range-reduced per axis (`reduce_coord`): the same texels and weights, with coordinates
    small enough that ``uv * w`` keeps its sub-texel bits."""
    s, t = wrap_axes(wrap)
    return torch.stack([reduce_coord(uv[..., 0], s), reduce_coord(uv[..., 1], t)], dim=-1)


TexelFn = Callable[[torch.Tensor], torch.Tensor]  # flat texel ids (M,) -> values (M, C)


def sample_bilinear(tex: torch.Tensor, uv: torch.Tensor, wrap=Wrap.REPEAT) -> torch.Tensor:
    """Bilinear sample of one level ``tex`` (C, H, W) at ``uv`` (N, 2) -> (N, C)."""
    c, h, w = tex.shape
    flat = tex.reshape(c, h * w).t()  # (H*W, C)
    return sample_bilinear_fn(lambda ids: flat[ids], h, w, uv, wrap)


def sample_bilinear_fn(texels: TexelFn, h: int, w: int, uv: torch.Tensor, wrap=Wrap.REPEAT) -> torch.Tensor:
    """Bilinear sample of an h x w level whose texels are produced on demand by ``texels``
    (row-major flat ids -> values). Training uses this to decode only the 4 taps of each sample
    instead of a whole level, so a step costs O(batch) rather than O(level size)."""
    ws, wt = wrap_axes(wrap)
    uv = reduce_uv(uv, (ws, wt))
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0f, y0f = torch.floor(x), torch.floor(y)
    fx, fy = (x - x0f).unsqueeze(1), (y - y0f).unsqueeze(1)
    x0, y0 = x0f.long(), y0f.long()
    xa, xb = address(x0, w, ws), address(x0 + 1, w, ws)
    ya, yb = address(y0, h, wt), address(y0 + 1, h, wt)
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
                     wrap=Wrap.REPEAT) -> torch.Tensor:
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
