"""A T_0 that holds the texture set's principal components, BC7-encoded once in every mode and
never trained (``--t0 pca``, the default with ``--features bc7``; issue 29).

The oracle of benchmarks/bound_t0.py says what one BC7 texture at T_0 can hold: the set's four
leading principal components, encoded by a full BC7 encoder (Intel's ISPC, every mode), keep more of
the closest mips than trained mode-6 features do (brick, mip 1: 31.4 dB against 28.0). Trained
features lose that: free features from noise are not block-friendly (their ISPC encode costs 3 dB at
mip 1), and mode 6, the one mode the trainer emulates, holds one line per block.

So T_0 is encoded first and kept: each of its mips holds the components at the lod the sampler
reads it at (:func:`bcfpipe.train.feature_init.pca_init`, the T_0 layers only), ISPC encodes them (the
settings of the classic BC7 textures, `bcfpipe.texset.baselines.BC7_SETTINGS`), and training
samples the exact decoded values (`FixedLevel`) from its first step. T_1..T_3 and the MLP train as
the paper's do (random start, warm-up, mode-6 constrained phase, fine-tune), around it; the MLP
starts as the components' linear decoder. Measured in docs/benchmarks.md ("A fixed T_0 of
principal components").
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from bcfpipe.bc7 import decode_to_u8
from bcfpipe.config import ModelConfig
from bcfpipe.errors import InputError
from bcfpipe.model import neural as M
from bcfpipe.model.features import FixedLevel, codec_of
from bcfpipe.train.feature_init import pca_init

__all__ = ["pca_t0", "encoded_levels", "t0_layers_problem"]


def pca_t0(mc: ModelConfig, ref_mips, biases, free: list[list[torch.Tensor]],
           mlp: dict[str, torch.Tensor], on_layer: Callable[[int, int], None] = lambda done, n: None,
           profile: str = "basic") -> dict[int, list[FixedLevel]]:
    """T_0's layers (the model's first ``mc.t0_layers``; layer j holds components 4j..4j+3) as
    `FixedLevel`s (components, ISPC's BC7 blocks, their decoded values), by layer; sets ``mlp`` to
    the components' linear decoder (in place). Their ``free`` layers are overwritten on the way.
    A set whose components do not reach a layer is refused (`t0_layers_problem`). ``on_layer``
    hears (layers encoded, layers) before the first layer's encode and after each (seconds apiece
    at 1k). ``profile``: the ISPC BC7 profile of the encode (`TrainConfig.t0_bc7`)."""
    problem = t0_layers_problem(mc.t0_layers, ref_mips[0].shape[0])
    if problem:
        raise InputError(problem)
    layers = tuple(range(mc.t0_layers))
    pca_init(mc, ref_mips, biases, free, mlp, layers=layers)
    codec = codec_of(mc)
    lo, hi = codec.param_range(mc)
    with torch.no_grad():  # a later layer's channels past the set's components: constant, not the random start
        for i in layers[1:]:
            for p in free[i]:
                p[max(0, ref_mips[0].shape[0] - codec.channels * i):] = (lo + hi) / 2
    out = {}
    on_layer(0, len(layers))
    for i in layers:
        with torch.no_grad():
            levels = [codec.value(p.detach().clamp(lo, hi), mc).permute(1, 2, 0).cpu().numpy() for p in free[i]]
        out[i] = encoded_levels(levels, free[i][0].device, profile)
        on_layer(i + 1, len(layers))
    return out


def t0_layers_problem(t0_layers: int, channels: int) -> str | None:
    """Why a set of ``channels`` channels cannot fill ``t0_layers`` layers of principal components
    (None when it can): layer j holds components 4j..4j+3, so each layer needs at least one of its
    own; a layer of nothing but the constant start would cost its bytes for no feature."""
    need = 4 * (t0_layers - 1) + 1
    if channels < need:
        return (f"a T_0 of {t0_layers} layers needs at least {need} channels (one principal component in its "
                f"last layer); this set has {channels}")
    return None


def encoded_levels(levels, device="cpu", profile: str = "basic") -> list[FixedLevel]:
    """(H, W, 4) [0, 1] levels encoded once by ISPC (every BC7 mode, or `BC7_PROFILES` ``profile``'s),
    as `FixedLevel`s whose values are bcfpipe's decode of the blocks."""
    from bcfpipe.texset.baselines import bc7_mips  # lazy: start-up

    shipped: list = []
    bc7_mips(levels, shipped, profile)
    out = []
    for blocks, w, h in shipped:
        b = np.ascontiguousarray(np.asarray(blocks, np.uint8).reshape(-1, 16))
        u8 = torch.as_tensor(decode_to_u8(b).astype(np.float32))
        out.append(FixedLevel(b, M.blocks_to_image(u8, w, h).contiguous().to(device), w))
    return out
