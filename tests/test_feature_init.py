"""The PCA start (bcfpipe.feature_init): the initial model is the reference's linear projection."""
from __future__ import annotations

import numpy as np
import torch

from bcfpipe.model import neural as M
from bcfpipe.config import ModelConfig
from bcfpipe.model.features import Layers
from bcfpipe.train.feature_init import pca_init
from bcfpipe.texset.reference import ReferencePyramid, sample_reference
from bcfpipe.texset.texture_set import build_mip_chain
from bcfpipe.formats.vocabulary import FeatureFormat


def _psnr(pred, target):
    return float(-10 * torch.log10(torch.mean((pred.detach() - target) ** 2)))


def test_pca_start_reproduces_a_low_rank_texture_set():
    """Six channels that are affine functions of three smooth fields have rank 3: the PCA start
    (T_0 holding components 0-2) must reproduce them at the lods T_0 covers far better than the
    random start, before any training step."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:64, 0:64] / 64.0
    fields = np.stack([np.sin(2 * np.pi * xx), np.cos(2 * np.pi * yy), np.sin(2 * np.pi * (xx + yy))], -1)
    mix = rng.uniform(-0.2, 0.2, (3, 6))
    data = (0.5 + fields @ mix).astype(np.float32)
    pyr = ReferencePyramid.from_mips(build_mip_chain(data))
    mc = ModelConfig(features=FeatureFormat.BC6H, resolutions=(32, 16, 8, 4))
    biases = M.lod_biases(mc.resolutions, 64, 64)
    gen = torch.Generator().manual_seed(0)
    free = M.init_free(mc, gen, "cpu")
    mlp = M.init_mlp(12, 16, 6, gen, "cpu", torch.as_tensor(data.reshape(-1, 6).mean(0)))
    uv = torch.rand(4096, 2, generator=gen)
    level = M.free_level_fn(Layers.of(free), mc)
    before = {s: _psnr(M.forward(level, mlp, mc, biases, uv, s), sample_reference(pyr, uv, s)) for s in (0.0, 1.0, 3.0)}
    with torch.no_grad():
        assert pca_init(mc, pyr.mips, biases, free, mlp) == 6
        after = {s: _psnr(M.forward(level, mlp, mc, biases, uv, s), sample_reference(pyr, uv, s)) for s in before}
    for s in before:
        assert after[s] > before[s] + 10, (before, after)
        assert after[s] > 35, after  # limited by the feature domain's half-float steps only
