"""The neural material G(u, v, s) = f_eta(T_0(u, v, s_0), ..., T_3(u, v, s_3))  (paper eq. 2).

Pure functions over tensors. A material's state is a dict of tensors:

- ``free``     phase 1: per layer, per mip, a (C, H, W) tensor of free texel parameters in the
               format's endpoint domain (C = 3 for BC6H, 4 for BC7); for BC6H texel value =
               unquantize -> finish -> half cast of it, so warm features live in exactly the value
               domain BC6H can represent; for BC7 value = p / 255.
- ``blocks``   phases 2-4: per layer, per mip, a `bcfpipe.model.features.BlockParams`: continuous
               ``endpoints`` and indices ``x`` in [0, 1] (and BC6H's fixed partition ``mask``).

Both are `bcfpipe.model.features.Layers`, which hold a fixed T_0 (`FixedLevel`s) apart from the
trained layers; the level and tap functions pick each layer's decode once, from that structure.
- ``mlp``      w1, b1, w2, b2 of the decoder, plus fixed out_scale / out_bias.

Each layer i is sampled at lod s_i = s + b_i, where s is in the reference's mip units and
b_i (``lod_biases``) starts from log2(max(w_i / W, h_i / H)) for a w_i x h_i layer and a W x H
reference, the layer's texel density.
"""
from __future__ import annotations

import math
from typing import Callable, Sequence

import torch

from bcfpipe.config import ModelConfig, mip_count
from bcfpipe.model.decoder import mlp_raw
from bcfpipe.model.features import BlockParams, FixedLevel, Layers, codec_of
from bcfpipe.model.sampling import level_weights, sample_bilinear, sample_bilinear_fn, sample_trilinear

LevelFn = Callable[[int, int], torch.Tensor]  # (layer, mip) -> (3, H, W) texel values
TapFn = Callable[[int, int], Callable[[torch.Tensor], torch.Tensor]]  # (layer, mip) -> texel ids -> (M, 3)


def lod_biases(resolutions: Sequence[int], ref_width: int, ref_height: int) -> tuple[float, ...]:
    """Per-layer lod bias b_i: layer T_i is sampled at s + b_i, with s in reference mip units.

    The natural bias log2(max(w_i / W, h_i / H)) matches T_i's texel density to the reference's.
    With it every layer of a Table-1 profile reaches its last (4x4) mip at the same s, two lods
    before the reference's 1x1 mip, so over those last lods nothing in the model changes while the
    target still does (a 6 dB dip at that s on the teapot). Layer i is therefore shifted a further
    min(i, gap) mips coarser, gap being the lods left past the 4x4 mips: T_0 keeps its density for
    detail, T_3 ends at the reference's last mip. Measured on a 512² teapot crop, all-mip PSNR
    32.3 -> 34.0 dB at the same size (docs/benchmarks.md, "lod biases").
    """
    natural = [math.log2(max(r / ref_width, r / ref_height)) for r in resolutions]
    s_max = math.log2(max(ref_width, ref_height))
    last = max(mip_count(r) - 1 - b for r, b in zip(resolutions, natural))
    gap = max(0, int(math.floor(s_max - last)))
    return tuple(b - min(i, gap) for i, b in enumerate(natural))


def layer_lod_biases(cfg: ModelConfig, ref_width: int, ref_height: int) -> tuple[float, ...]:
    """Each model layer's lod bias: its profile layer's (:func:`lod_biases`), so every T_0 layer
    has T_0's (ModelConfig.profile_slots)."""
    profile = lod_biases(cfg.resolutions, ref_width, ref_height)
    return tuple(profile[j] for j in cfg.profile_slots)


def blocks_to_image(texels: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """(n, 16, C) block texels in row-major block order -> (C, H, W)."""
    by, bx, c = height // 4, width // 4, texels.shape[-1]
    return texels.reshape(by, bx, 4, 4, c).permute(4, 0, 2, 1, 3).reshape(c, height, width)


def init_free(cfg: ModelConfig, gen: torch.Generator, device: torch.device) -> list[list[torch.Tensor]]:
    """Phase-1 parameters: uniform in the format's start range (BC6H: endpoints that decode to about
    [0.03, 1.7] unsigned or [-1, 1] signed; BC7: [0.25, 0.75]), where the MLP's inputs are well scaled."""
    codec = codec_of(cfg)
    lo, hi = codec.init_range(cfg)
    layers = []
    for res, n in zip(cfg.layer_resolutions, cfg.mip_counts):
        mips = []
        for k in range(n):
            r = res >> k
            t = torch.rand((codec.channels, r, r), generator=gen) * (hi - lo) + lo
            mips.append(t.to(device).requires_grad_(True))
        layers.append(mips)
    return layers


def init_mlp(n_in: int, hidden: int, n_out: int, gen: torch.Generator, device: torch.device,
             out_bias: torch.Tensor) -> dict[str, torch.Tensor]:
    """He-uniform first layer, small second layer; out_scale 1 and out_bias = channel means."""
    b1 = 1.0 / math.sqrt(n_in)
    b2 = 1.0 / math.sqrt(hidden)
    p = {
        "w1": (torch.rand((hidden, n_in), generator=gen) * 2 - 1) * math.sqrt(6.0 / n_in),
        "b1": (torch.rand((hidden,), generator=gen) * 2 - 1) * b1,
        "w2": (torch.rand((n_out, hidden), generator=gen) * 2 - 1) * b2 * 0.1,
        "b2": torch.zeros(n_out),
    }
    p = {k: v.to(device).requires_grad_(True) for k, v in p.items()}
    p["out_scale"] = torch.ones(n_out, device=device)
    p["out_bias"] = out_bias.to(device=device, dtype=torch.float32)
    return p


def free_tap_fn(free: Layers[torch.Tensor], cfg: ModelConfig) -> TapFn:
    codec = codec_of(cfg)
    lo, hi = codec.param_range(cfg)

    def trained(p: torch.Tensor, i: int, k: int):
        flat = p.reshape(p.shape[0], -1)
        return lambda ids: codec.value(flat[:, ids].t().clamp(lo, hi), cfg)
    return free.lookup(_fixed_taps, trained)


def _fixed_taps(lv: FixedLevel):
    flat = lv.values.reshape(lv.values.shape[0], -1)
    return lambda ids: flat[:, ids].t() / 255.0


def block_tap_fn(blocks: Layers[BlockParams], cfg: ModelConfig,
                 quantized: Callable[[], bool] = lambda: False) -> TapFn:
    """Texel values straight from block parameters: texel (y, x) lives in block
    (y // 4) * (w // 4) + x // 4 at position (y % 4) * 4 + x % 4. ``quantized()`` is asked per
    call, so a schedule can switch quantization-aware decoding on mid-phase."""
    codec = codec_of(cfg)

    def trained(b: BlockParams, i: int, k: int):
        r = max(4, cfg.layer_resolutions[i] >> k)

        def texels(ids: torch.Tensor) -> torch.Tensor:
            y, xx = ids // r, ids % r
            blk = (y // 4) * (r // 4) + xx // 4
            pos = (y % 4) * 4 + xx % 4
            return codec.texels(b, blk, pos, cfg, quantized())
        return texels
    return blocks.lookup(_fixed_taps, trained)


def free_level_fn(free: Layers[torch.Tensor], cfg: ModelConfig) -> LevelFn:
    codec = codec_of(cfg)
    lo, hi = codec.param_range(cfg)
    return free.lookup(fixed_value, lambda p, i, k: codec.value(p.clamp(lo, hi), cfg))


def fixed_value(lv: FixedLevel) -> torch.Tensor:
    """A fixed level's (C, H, W) texel values: its UNORM8 values / 255, as the BC7 codec decodes."""
    return lv.values / 255.0


def block_level_fn(blocks: Layers[BlockParams], cfg: ModelConfig,
                   quantized: bool | Callable[[], bool] = False) -> LevelFn:
    q = quantized if callable(quantized) else (lambda: quantized)
    codec = codec_of(cfg)

    def trained(b: BlockParams, i: int, k: int) -> torch.Tensor:
        r = max(4, cfg.layer_resolutions[i] >> k)
        return blocks_to_image(codec.decode_blocks(b, cfg, q()), r, r)
    return blocks.lookup(fixed_value, trained)


def cached_level_fn(levels: list[list[torch.Tensor]]) -> LevelFn:
    return lambda i, k: levels[i][k]


def sample_features_taps(tap_fn: TapFn, sizes: Sequence[Sequence[int]], biases: Sequence[float],
                         uv: torch.Tensor, s: float, wrap: str) -> torch.Tensor:
    """As :func:`sample_features` for one batch lod ``s``, decoding only the texels sampled."""
    out = []
    for i, (lvl_sizes, b) in enumerate(zip(sizes, biases)):
        lo, hi, t = level_weights(s + b, len(lvl_sizes))
        r = lvl_sizes[lo]
        a = sample_bilinear_fn(tap_fn(i, lo), r, r, uv, wrap)
        if hi != lo and t > 0:
            r = lvl_sizes[hi]
            a = a + (sample_bilinear_fn(tap_fn(i, hi), r, r, uv, wrap) - a) * t
        out.append(a)
    return torch.cat(out, 1)


def level_sizes(cfg: ModelConfig) -> list[list[int]]:
    return [[max(4, r >> k) for k in range(n)] for r, n in zip(cfg.layer_resolutions, cfg.mip_counts)]


def sample_features(level_fn: LevelFn, mip_counts: Sequence[int], biases: Sequence[float],
                    uv: torch.Tensor, s: float | torch.Tensor, wrap: str) -> torch.Tensor:
    """Concatenated trilinear samples of all layers -> (N, C * n_layers).

    With a float ``s`` only the two levels each layer needs are decoded; with a per-point tensor
    every level is decoded once and sampled (evaluation).
    """
    out = []
    for i, (n, b) in enumerate(zip(mip_counts, biases)):
        if isinstance(s, torch.Tensor):
            out.append(sample_trilinear([level_fn(i, k) for k in range(n)], uv, s + b, wrap))
            continue
        lo, hi, t = level_weights(s + b, n)
        a = sample_bilinear(level_fn(i, lo), uv, wrap)
        if hi != lo and t > 0:
            a = a + (sample_bilinear(level_fn(i, hi), uv, wrap) - a) * t
        out.append(a)
    return torch.cat(out, 1)


def forward(level_fn: LevelFn, mlp: dict[str, torch.Tensor], cfg: ModelConfig, biases: Sequence[float],
            uv: torch.Tensor, s: float | torch.Tensor, tap_fn: TapFn | None = None) -> torch.Tensor:
    """Model output before clamping/normal-z (what the loss compares to the reference).

    With ``tap_fn`` (training, float ``s``) features are decoded per sampled texel; the result is
    identical to decoding whole levels with ``level_fn``."""
    if tap_fn is not None and not isinstance(s, torch.Tensor):
        feats = sample_features_taps(tap_fn, level_sizes(cfg), biases, uv, s, cfg.wrap)
    else:
        feats = sample_features(level_fn, cfg.mip_counts, biases, uv, s, cfg.wrap)
    return mlp_raw(mlp, feats) * mlp["out_scale"] + mlp["out_bias"]
