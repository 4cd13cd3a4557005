"""Reference material sampling for training (paper §5.1).

The reference texture set is sampled at continuous (u, v, s): bicubic filtering in the two mips
nearest to the scale s, linearly interpolated by frac(s) -- a "tri-cubic" lookup that a neural
material learns to emulate.

Conventions:

* uv in [0, 1)^2, u along the width (columns), v along the height (rows, row 0 = first stored
  row). Texel i of a level of size w has its centre at u = (i + 0.5) / w.
* s is in reference-mip units: s = 0 is level 0, s = 1 level 1 (half size), ...; levels used are
  floor(s) and floor(s) + 1, both clamped to [0, last level]; s < 0 behaves as 0, s >= last level
  returns the last level (the 1x1 mean).
* Bicubic = Keys cubic convolution with a = -0.5 (Catmull-Rom), the common "bicubic": it
  interpolates (returns texel values exactly at texel centres), is C1 and reproduces linear ramps,
  and its weights sum to 1. It can overshoot slightly near edges, like any sharp bicubic.
* Addressing, per axis (S, T): 'repeat' wraps indices (tiling materials), 'clamp' clamps them to
  the edge, 'mirror' reflects them (bcfpipe.formats.addressing.address, as the feature layers').
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from bcfpipe.formats.vocabulary import Wrap, wrap_axes
from bcfpipe.formats.addressing import address
from bcfpipe.texset import hostmem
from bcfpipe.texset.texture_set import TextureSet, build_mip_chain

__all__ = ["level_split", "bicubic_sample", "ReferencePyramid", "CentreTargets", "keys_weights", "sample_reference", "random_batch", "WRAP_MODES"]

WRAP_MODES = (Wrap.REPEAT, Wrap.CLAMP, Wrap.MIRROR)
KEYS_A = -0.5
# CentreTargets(interleave=True) keeps a level texel by texel when its two images fit in this much
# (a 2048² level of 8 channels does; at 8K the two largest levels stay planar: no 4 GiB copy)
INTERLEAVE_MAX_BYTES = 256 << 20
# A texel-centre target looked up per batch costs about this many precomputed ones (the native lookup,
# 2048² x 11 channels, one thread: 0.22 us per texel precomputed; 0.45-0.49 us more per draw at
# levels 0 and 1 looked up, 0.21 at level 2)
LAZY_COST = 2.0


@dataclass(frozen=True)
class ReferencePyramid:
    """A reference mip chain as torch tensors of shape (c, H_k, W_k) on one device."""

    mips: tuple[torch.Tensor, ...]

    def __post_init__(self) -> None:
        if not self.mips:
            raise ValueError("a reference pyramid needs at least one mip")
        c = self.mips[0].shape[0]
        for k, m in enumerate(self.mips):
            if m.ndim != 3 or m.shape[0] != c:
                raise ValueError(f"mip {k} has shape {tuple(m.shape)}, expected ({c}, H, W)")
        object.__setattr__(self, "mips", tuple(self.mips))

    @classmethod
    def from_mips(cls, mips: Sequence[np.ndarray], device: torch.device | str = "cpu",
                  dtype: torch.dtype = torch.float32) -> "ReferencePyramid":
        """From (H, W, c) numpy mips (as `build_mip_chain` returns)."""
        return cls(tuple(torch.as_tensor(np.ascontiguousarray(np.moveaxis(m, -1, 0)), dtype=dtype).to(device)
                         for m in mips))

    @classmethod
    def from_texture_set(cls, ts: TextureSet, device: torch.device | str = "cpu",
                         dtype: torch.dtype = torch.float32) -> "ReferencePyramid":
        """Build the box mip chain of `ts` (see `build_mip_chain`) and move it to `device`."""
        return cls.from_mips(build_mip_chain(ts.data), device, dtype)

    @property
    def num_levels(self) -> int:
        return len(self.mips)

    @property
    def num_channels(self) -> int:
        return self.mips[0].shape[0]

    @property
    def device(self) -> torch.device:
        return self.mips[0].device


def keys_weights(f: torch.Tensor, a: float = KEYS_A) -> torch.Tensor:
    """Cubic-convolution weights of the 4 taps at offsets -1, 0, 1, 2 for fraction f: (..., 4)."""
    f2, f3 = f * f, f * f * f
    w0 = a * (f3 - 2 * f2 + f)
    w1 = (a + 2) * f3 - (a + 3) * f2 + 1
    w2 = -(a + 2) * f3 + (2 * a + 3) * f2 - a * f
    w3 = a * (f2 - f3)
    return torch.stack((w0, w1, w2, w3), dim=-1)


def bicubic_sample(tex: torch.Tensor, uv: torch.Tensor, wrap: str) -> torch.Tensor:
    """Catmull-Rom sample of one level (c, H, W) at uv (N, 2): (N, c), one gather of 16 taps."""
    c, h, w = tex.shape
    size = torch.tensor([w, h], device=uv.device)
    x = uv * size.to(uv.dtype) - 0.5  # texel-centre coordinates (N, 2)
    x0 = torch.floor(x)
    wts = keys_weights(x - x0).to(tex.dtype)  # (N, 2, 4): taps at -1, 0, 1, 2 per axis
    idx = x0.long().unsqueeze(-1) + torch.arange(-1, 3, device=uv.device)  # (N, 2, 4)
    idx = torch.stack([address(idx[:, a], n, mode) for a, (n, mode) in enumerate(zip((w, h), wrap_axes(wrap)))], 1)
    flat = (idx[:, 1, :, None] * w + idx[:, 0, None, :]).reshape(-1)  # (N*16,) row-major taps
    weights = (wts[:, 1, :, None] * wts[:, 0, None, :]).reshape(-1, 16)  # (N, 16)
    taps = tex.reshape(c, h * w).index_select(1, flat).reshape(c, -1, 16)  # (c, N, 16)
    return torch.einsum("cnk,nk->nc", taps, weights)


def level_split(s: float, levels: int) -> tuple[int, int, float]:
    s = max(float(s), 0.0)
    base = math.floor(s)
    l0, l1 = min(base, levels - 1), min(base + 1, levels - 1)
    return l0, l1, (s - base if l0 != l1 else 0.0)


def sample_reference(pyr: ReferencePyramid, uv: torch.Tensor, s: float | torch.Tensor,
                     wrap: str = Wrap.REPEAT) -> torch.Tensor:
    """Trilinear-of-bicubic reference lookup at uv (N, 2) and scale s: returns (N, c).

    `s` is one scalar per batch (the paper's setting: a float or 0-d tensor) or a per-point
    (N,) tensor. See the module docstring for the uv / s / kernel / addressing conventions.
    """
    wrap = wrap_axes(wrap)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise ValueError(f"uv must have shape (N, 2), got {tuple(uv.shape)}")
    ref_dtype = pyr.mips[0].dtype
    uv = uv.to(device=pyr.device, dtype=ref_dtype if ref_dtype.is_floating_point else torch.float32)
    n, levels = uv.shape[0], pyr.num_levels

    if not torch.is_tensor(s) or s.ndim == 0:
        l0, l1, t = level_split(float(s), levels)
        out = bicubic_sample(pyr.mips[l0], uv, wrap)
        if t > 0.0:
            out = torch.lerp(out, bicubic_sample(pyr.mips[l1], uv, wrap), t)
        return out

    if s.shape != (n,):
        raise ValueError(f"per-point s must have shape ({n},), got {tuple(s.shape)}")
    s = s.to(device=uv.device, dtype=uv.dtype).clamp_min(0.0)
    base = torch.floor(s)
    l0 = base.long().clamp_max(levels - 1)
    l1 = (base.long() + 1).clamp_max(levels - 1)
    t = torch.where(l0 == l1, torch.zeros_like(s), s - base)
    out = torch.zeros(n, pyr.num_channels, device=uv.device, dtype=uv.dtype)
    for k in torch.unique(torch.cat((l0, l1))).tolist():
        wk = (1.0 - t) * (l0 == k) + t * (l1 == k)
        sel = torch.nonzero(wk > 0).squeeze(-1)
        if sel.numel():
            out.index_add_(0, sel, bicubic_sample(pyr.mips[k], uv[sel], wrap) * wk[sel, None])
    return out


def random_batch(n: int, generator: torch.Generator | None, device: torch.device | str,
                 s_max: float) -> tuple[torch.Tensor, float]:
    """A training batch: uv (n, 2) uniform in [0, 1)^2 and one scale s uniform in [0, s_max].

    Random numbers are drawn on the generator's device (CPU for None) and moved to `device`, so a
    CPU generator reproduces the same batches on any device.
    """
    if n < 1:
        raise ValueError(f"batch size must be >= 1, got {n}")
    if not s_max >= 0:
        raise ValueError(f"s_max must be >= 0, got {s_max}")
    gdev = generator.device if generator is not None else torch.device("cpu")
    uv = torch.rand((n, 2), generator=generator, device=gdev).to(device)
    s = float(torch.rand((), generator=generator, device=gdev)) * float(s_max)
    return uv, s


def texel_centres(h: int, w: int, ids: torch.Tensor) -> torch.Tensor:
    """uv (N, 2) of the centres of flat row-major texel ids of an h x w level."""
    return torch.stack((((ids % w).to(torch.float32) + 0.5) / w, ((ids // w).to(torch.float32) + 0.5) / h), 1)


class CentreTargets:
    """The reference at the texel centres of its large mips, precomputed (issue #9, "a faster step").

    At the centre of a texel of mip k, bicubic filtering of mip k returns the texel itself
    (Catmull-Rom interpolates), so the training target F(u, v, s) for k = floor(s) is
    lerp(mip_k[texel], B_k+1[texel], frac(s)), where B_k+1 is mip k+1's bicubic at mip k's texel
    centres: one image per large mip, computed once. A step whose uv are texel centres of mip k
    then gathers 2 values per channel instead of 32. Mips smaller than ``min_texels`` are not
    precomputed: there a batch covers the level densely and continuous uv stay cheap. ``bicubic``
    (tex, uv, wrap) -> (N, c) computes B_k+1 (default: this module's; the fused kernel's native
    one, bcfpipe.train.fused.targets.bicubic, sums the same taps in another order, ~10x faster).

    ``interleave``: keep a level's two images texel by texel instead, ``texels[k]`` (h w, 2 c) =
    [mip_k | B_k+1] per texel (``up[k]`` then None), for levels whose copy fits
    :data:`INTERLEAVE_MAX_BYTES`. A drawn texel's 2 c values then share one or two cache lines
    instead of 2 c planes; at a 2048² level that halves the batch's time (the fused kernel's
    centre batches). The cost is one more copy of each such mip.

    ``draws``: how many texels a training will draw at each level (expected), when known. A level
    drawn less than 1 / `LAZY_COST` of its texels is not precomputed: each batch's B_k+1 is looked
    up at its own texel centres (`up_at`), the same values where ``bicubic`` looks each point up on
    its own (the native lookup). The layout's probe at draft draws 16 % of a 2048² level 0's texels.
    """

    def __init__(self, pyr: ReferencePyramid, wrap: str, min_texels: int, chunk: int = 1 << 18,
                 covered: Sequence[np.ndarray] | None = None, bicubic=None, interleave: bool = False,
                 draws: Sequence[float] | None = None):
        self.pyr, self.wrap, self.min_texels, self.bicubic = pyr, wrap, min_texels, bicubic
        self.lazy: list[bool] = []
        # with a coverage mask chain (bcfpipe.scan.coverage), steps draw only texels the scene reads
        self.allowed = ([torch.as_tensor(np.flatnonzero(m), device=pyr.mips[0].device) for m in covered]
                        if covered is not None else None)
        self.up: list[torch.Tensor | None] = []
        self.texels: list[torch.Tensor | None] = []
        for k, m in enumerate(pyr.mips):
            c, h, w = m.shape
            self.texels.append(None)
            lazy = draws is not None and h * w >= min_texels and k + 1 < pyr.num_levels and draws[k] * LAZY_COST < h * w
            self.lazy.append(lazy)
            if h * w < min_texels or k + 1 >= pyr.num_levels or lazy:
                self.up.append(None)
                continue
            nxt = pyr.mips[k + 1]
            rows = interleave and 2 * c * h * w * m.element_size() <= INTERLEAVE_MAX_BYTES
            up = hostmem.empty((h * w, 2 * c) if rows else (c, h * w), nxt.dtype, m.device)
            if rows:
                up[:, :c] = m.reshape(c, -1).t()
            for a in range(0, h * w, chunk):  # in chunks: no 2x peak at 8K
                ids = torch.arange(a, min(a + chunk, h * w), device=m.device)
                b = (bicubic or bicubic_sample)(nxt, texel_centres(h, w, ids).to(nxt.dtype), wrap)
                if rows:
                    up[a:a + len(ids), c:] = b
                else:
                    up[:, a:a + len(ids)] = b.t()
            self.up.append(None if rows else up)
            self.texels[k] = up if rows else None

    def covers(self, s: float) -> bool:
        """Whether a batch at scale ``s`` is drawn at texel centres (precomputed or looked up per batch)."""
        l0, _, _ = level_split(s, self.pyr.num_levels)
        return self.up[l0] is not None or self.texels[l0] is not None or self.lazy[l0]

    def up_at(self, k: int, ids: torch.Tensor) -> torch.Tensor:
        """B_k+1 at the centres of level ``k``'s texels ``ids``: (n, c), as the precompute makes it."""
        _, h, w = self.pyr.mips[k].shape
        nxt = self.pyr.mips[k + 1]
        return (self.bicubic or bicubic_sample)(nxt, texel_centres(h, w, ids).to(nxt.dtype), self.wrap)

    def draw(self, n: int, s: float, gen: torch.Generator | None) -> tuple[int, float, torch.Tensor]:
        """(mip floor(s), the blend t towards the next, ``n`` uniformly random texel ids of it)."""
        l0, _, t = level_split(s, self.pyr.num_levels)
        m = self.pyr.mips[l0]
        c, h, w = m.shape
        gdev = gen.device if gen is not None else torch.device("cpu")
        allowed = self.allowed[l0] if self.allowed is not None and len(self.allowed[l0]) else None
        ids = torch.randint(0, h * w if allowed is None else len(allowed), (n,), generator=gen, device=gdev)
        return l0, t, (ids.to(m.device) if allowed is None else allowed[ids.to(m.device)])

    def batch(self, n: int, s: float, gen: torch.Generator | None) -> tuple[torch.Tensor, torch.Tensor]:
        """``n`` uniformly random texel centres of mip floor(s) and their targets at ``s``:
        (uv (n, 2), target (n, c)), equal to sample_reference(pyr, uv, s)."""
        l0, t, ids = self.draw(n, s, gen)
        m, up, rows = self.pyr.mips[l0], self.up[l0], self.texels[l0]
        c, h, w = m.shape
        if rows is not None:
            both = rows.index_select(0, ids)
            return texel_centres(h, w, ids), torch.lerp(both[:, :c], both[:, c:], t) if t > 0.0 else both[:, :c]
        target = m.reshape(c, -1).index_select(1, ids)
        if t > 0.0:
            b = self.up_at(l0, ids).t().contiguous() if up is None else up.reshape(c, -1).index_select(1, ids)
            target = torch.lerp(target, b, t)
        return texel_centres(h, w, ids), target.t()
