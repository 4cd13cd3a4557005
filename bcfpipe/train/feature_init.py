"""Initial features and decoder from a PCA of the reference (issue #9, "initialisation"); opt-in.

Random features make the warm-up spend its steps discovering what a linear projection already
knows. ``pca_init`` starts T_0 with principal components 0-2 of the texture set and T_1 with
components 3-5; mip k of layer i holds the reference at the lod the sampler reads it at,
s = k - b_i, resized to the mip's size. The decoder starts as the matching linear map: each used
feature gets one ReLU unit that passes it through (features are positive, so ReLU is the
identity there) and a W2 column that maps it back onto the channels. The other hidden units keep
their random first layer and start with zero output weights, so the start is exactly the
projection; T_2, T_3 and layer channels without a component keep the random start.

Measured on the teapot and brick sets (docs/benchmarks.md, "Fine mips"): +1.5 to 2 dB at mips
0-2, but 1 to 10 dB lower at the coarse mips and about 1 dB lower over all mips on the teapot,
so the presets keep the paper's random start and ``--init pca`` is a choice for close-ups.
A two-band variant (coarse layers holding the components, fine layers the residual) and a PCA
start without warm-up measured worse on every mip and were dropped.

Component values are mapped affinely onto the format's feature range per (layer, component),
then onto the free parameters' domain: for BC6H ([0.25, 1.7]) the 6-bit endpoint domain through the
inverse of :func:`bcfpipe.model.features.endpoint_value`; for BC7 ([0.02, 0.98]) the 8-bit one. A BC7 layer
holds four components, so T_0 starts as the oracle of benchmarks/bound_t0.py ("4 PCs, BC7").
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from bcfpipe.config import ModelConfig
from bcfpipe.formats.vocabulary import FeatureFormat
from bcfpipe.model.features import codec_of, endpoint_value

# feature range of the initial components, per format (decoded values)
FEATURE_RANGE = {FeatureFormat.BC6H: (0.25, 1.7), FeatureFormat.BC7: (0.02, 0.98)}
_SAMPLE_TEXELS = 1 << 16  # texels of the mip the PCA is computed on (about 256²)
LAYERS = (0, 1)  # the layers holding components 0-2 and 3-5


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
    v = endpoint_value(p, signed)
    keep = torch.cat([torch.tensor([True]), v[1:] > v[:-1]])
    p, v = p[keep].numpy(), v[keep].numpy()
    return torch.as_tensor(np.interp(f.cpu().numpy(), v, p), dtype=torch.float32, device=f.device)


def _resize(img: torch.Tensor, size: int) -> torch.Tensor:
    """(c, h, w) -> (c, size, size): box-average down, bilinear (texel-centre aligned) up."""
    if img.shape[1:] == (size, size):
        return img
    if img.shape[1] >= size and img.shape[2] >= size:
        return F.interpolate(img[None], size=(size, size), mode="area")[0]
    return F.interpolate(img[None], size=(size, size), mode="bilinear", align_corners=False)[0]


def _components(mips, lod: float, size: int, mean, axes) -> torch.Tensor:
    """Principal components (n, size, size) of the reference at integer ``lod`` (clamped)."""
    k = min(max(int(round(lod)), 0), len(mips) - 1)
    ref = _resize(mips[k], size)
    return torch.einsum("chw,jc->jhw", ref - mean[:, None, None], axes)


def pca_init(cfg: ModelConfig, mips: Sequence[torch.Tensor], biases: Sequence[float],
             free: list[list[torch.Tensor]], mlp: dict[str, torch.Tensor], layers: Sequence[int] = LAYERS) -> int:
    """Overwrite ``free`` (phase-1 parameters) and ``mlp`` in place with the PCA start.

    ``mips`` are the reference's (c, H, W) levels on the parameters' device. Returns the number
    of components used (at most those ``layers``' channels): 2 layers for --init pca, a fixed T_0's one to
    three (bcfpipe.train.fixed_t0). ``layers``: which layers hold them, the first
    the leading ones. Unsigned features only; signed models keep the random start."""
    if cfg.signed or len(free) < 4:
        return 0
    per_layer = codec_of(cfg).channels
    bc7 = FeatureFormat(cfg.features) == FeatureFormat.BC7
    F_LO, F_HI = FEATURE_RANGE[FeatureFormat(cfg.features)]
    dev = free[0][0].device
    mips = [m.to(dev) for m in mips]
    c = mips[0].shape[0]
    mean, axes = principal_axes(mips)
    mean, axes = mean.to(dev), axes.to(dev)
    n_comp = min(c, len(layers) * per_layer, axes.shape[0])  # a set of fewer texels than channels has fewer axes
    content: dict[int, list[torch.Tensor]] = {}  # layer -> per-mip component images
    comps_of: dict[int, list[int]] = {}
    for g, i in enumerate(layers):
        comps = list(range(per_layer * g, min(n_comp, per_layer * (g + 1))))
        if comps:
            content[i] = [_components(mips, k - biases[i], p.shape[-1], mean, axes[comps]) for k, p in enumerate(free[i])]
            comps_of[i] = comps

    w1, b1 = mlp["w1"], mlp["b1"]
    w2 = torch.zeros_like(mlp["w2"])  # units other than the pass-throughs start silent
    b2 = torch.zeros_like(mlp["b2"])
    unit = 0
    with torch.no_grad():
        for i in sorted(content):
            top = content[i][0].reshape(len(comps_of[i]), -1)
            sub = top[:, :: max(1, top.shape[1] // 65536)]
            lo = torch.quantile(sub, cfg.pca_clip, dim=1)
            hi = torch.quantile(sub, 1 - cfg.pca_clip, dim=1)
            scale = (F_HI - F_LO) / torch.where(hi - lo > 1e-6, hi - lo, torch.ones_like(hi))
            for k, p in enumerate(free[i]):
                f = F_LO + (content[i][k] - lo[:, None, None]) * scale[:, None, None]
                if bc7:
                    p[: len(comps_of[i])] = f.clamp(0.0, 1.0) * 255.0
                else:
                    p[: len(comps_of[i])] = _inverse_endpoint_value(f.clamp(F_LO * 0.5, F_HI * 1.1), False)
            for j, comp in enumerate(comps_of[i]):
                if unit >= w1.shape[0]:
                    break
                col = per_layer * i + j
                w1[unit].zero_()
                w1[unit, col] = 1.0
                b1[unit] = 0.0
                # channel value = mean + sum comp * axis, comp = lo + (f - F_LO) / scale
                w2[:, unit] = axes[comp] / scale[j]
                b2 += axes[comp] * (lo[j] - F_LO / scale[j])
                unit += 1
        mlp["w2"].copy_(w2)
        mlp["b2"].copy_(b2 + mean - mlp["out_bias"])
    return n_comp
