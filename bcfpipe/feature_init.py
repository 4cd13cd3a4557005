"""Initial features and decoder from a PCA of the reference (issue #9, "initialisation").

Random features make the warm-up spend its steps discovering what a linear projection already
knows. Here layer T_i starts as principal components 3i..3i+2 of the texture set, each mip k
holding the components of the reference at the lod where the sampler reads it (s = k - b_i),
resized to the mip's size, and the MLP starts as the matching linear decoder: one ReLU unit
passes each used feature through (features are positive, so ReLU is the identity there) and
W2 maps them back onto the channels. The other hidden units keep their random first layer and
start with zero output weights, so the start is exactly the projection; layers past the texture
set's channel count keep the random start.

The component values are mapped affinely onto a feature range [F_LO, F_HI] that BC6H's
unsigned half domain resolves evenly enough, then onto the free parameters' 6-bit endpoint
domain through the inverse of :func:`bcfpipe.model.endpoint_value`.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from . import model as M
from .config import LAYER_CHANNELS, ModelConfig

F_LO, F_HI = 0.25, 1.7  # feature range of the initial components (decoded BC6H values)
_SAMPLE_TEXELS = 1 << 16  # texels of the mip the PCA is computed on (about 256²)


def principal_axes(mips: Sequence[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean (c,) and principal axes (c, c), rows by decreasing variance, of the reference's
    channels, computed on the first mip with at most ``_SAMPLE_TEXELS`` texels."""
    m = next((m for m in mips if m.shape[1] * m.shape[2] <= _SAMPLE_TEXELS), mips[-1])
    x = m.reshape(m.shape[0], -1).t().double()
    mean = x.mean(0)
    _, _, vt = torch.linalg.svd(x - mean, full_matrices=False)
    return mean.float(), vt.float()


def _inverse_endpoint_value(f: torch.Tensor, signed: bool) -> torch.Tensor:
    """Continuous endpoint p with endpoint_value(p) = f, by interpolation in a dense table."""
    p = torch.linspace(0.0, 40.0, 40 * 256 + 1)
    v = M.endpoint_value(p, signed)
    keep = torch.cat([torch.tensor([True]), v[1:] > v[:-1]])
    p, v = p[keep].numpy(), v[keep].numpy()
    return torch.as_tensor(np.interp(f.cpu().numpy(), v, p), dtype=torch.float32, device=f.device)


def _reference_at(mips: Sequence[torch.Tensor], lod: float, size: int) -> torch.Tensor:
    """The reference at integer ``lod`` (clamped to the chain), resized to size x size: (c, r, r)."""
    k = min(max(int(round(lod)), 0), len(mips) - 1)
    m = mips[k]
    if m.shape[1:] == (size, size):
        return m
    mode = "area" if m.shape[1] > size else "bilinear"
    kw = {} if mode == "area" else {"align_corners": False}
    return F.interpolate(m[None], size=(size, size), mode=mode, **kw)[0]


def pca_init(cfg: ModelConfig, mips: Sequence[torch.Tensor], biases: Sequence[float],
             free: list[list[torch.Tensor]], mlp: dict[str, torch.Tensor], layers: int = 4) -> int:
    """Overwrite ``free`` (phase-1 parameters) and ``mlp`` in place with the PCA start.

    ``mips`` are the reference's (c, H, W) levels. Returns the number of components used
    (min(c, 3 * layers)). Unsigned features only; signed models keep the random start."""
    if cfg.signed:
        return 0
    c = mips[0].shape[0]
    mean, axes = principal_axes(mips)
    n_comp = min(c, LAYER_CHANNELS * min(layers, len(free)))
    coarse = mips[min(len(mips) - 1, max(0, int(math.log2(max(1, mips[0].shape[1] // 256)))))]
    proj = (coarse.reshape(c, -1).t() - mean) @ axes[:n_comp].t()
    lo = torch.quantile(proj[:: max(1, proj.shape[0] // 65536)], 0.001, dim=0)
    hi = torch.quantile(proj[:: max(1, proj.shape[0] // 65536)], 0.999, dim=0)
    span = torch.where(hi - lo > 1e-6, hi - lo, torch.ones_like(hi))
    scale = (F_HI - F_LO) / span  # feature per unit of component
    with torch.no_grad():
        for i, layer in enumerate(free):
            comps = list(range(LAYER_CHANNELS * i, min(n_comp, LAYER_CHANNELS * (i + 1))))
            if not comps:
                continue
            for k, p in enumerate(layer):
                r = p.shape[-1]
                ref = _reference_at(mips, k - biases[i], r).to(p.device)
                comp = torch.einsum("chw,jc->jhw", ref - mean.to(p.device)[:, None, None], axes[comps].to(p.device))
                f = (F_LO + (comp - lo[comps, None, None].to(p.device)) * scale[comps, None, None].to(p.device))
                p[: len(comps)] = _inverse_endpoint_value(f.clamp(F_LO * 0.5, F_HI * 1.1), False)
        # decoder: hidden unit j passes feature j (positive) through; W2 undoes the projection
        dev = mlp["w1"].device
        used = [3 * i + j for i in range(len(free)) for j in range(LAYER_CHANNELS)
                if 3 * i + j < n_comp]
        w2 = torch.zeros_like(mlp["w2"])  # the other units start silent; their W2 learns first
        b2 = torch.zeros_like(mlp["b2"])
        for h, col in enumerate(used):
            mlp["w1"][h].zero_()
            mlp["w1"][h, col] = 1.0
            mlp["b1"][h] = 0.0
            # channel value = mean + sum_j comp_j * axis_j, comp_j = lo_j + (f_j - F_LO) / scale_j
            w2[:, h] = axes[col].to(dev) / scale[col].to(dev)
            b2 += axes[col].to(dev) * (lo[col].to(dev) - F_LO / scale[col].to(dev))
        mlp["w2"].copy_(w2)
        mlp["b2"].copy_(b2 + mean.to(dev) - mlp["out_bias"])
    return n_comp
