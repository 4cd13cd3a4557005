"""The feature textures' block formats behind one interface, for the trainer and the export.

A `FeatureCodec` says, for one format, how a layer's free (phase 1) parameters map to texel values,
how warm features become trainable block parameters, how those decode (per sampled texel or per
level, optionally quantization-aware), how they round to the exact blocks that are written, and how
those blocks are packed into a DDS. Two formats:

* `bc6h`: BC6H mode 11110 (the paper's), 3 channels, parameters in the 6-bit endpoint domain
  (bcfpipe.bc6h);
* `bc7`: BC7 mode 6, 4 channels in the same bytes, parameters in the 8-bit endpoint domain
  (bcfpipe.bc7; issue 29). A layer encoded once and not trained (`FixedLevel`: a T_0 of principal
  components, any BC7 mode) holds its blocks as written and decodes them itself; `Layers` keeps such
  layers apart from the trained ones.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Generic, Iterator, Mapping, Sequence, TypeVar

import numpy as np
import torch

from bcfpipe.bc6h import emulate
from bcfpipe.bc6h import mode10
from bcfpipe.bc6h import quick
from bcfpipe.bc6h.encode import encode_params
from bcfpipe.bc7 import decode_to_u8
from bcfpipe.bc7 import emulate as bc7_emulate
from bcfpipe.bc7 import mode6
from bcfpipe.bc7.encode import encode_params as bc7_encode_params
from bcfpipe.config import ModelConfig
from bcfpipe.formats import dds
from bcfpipe.formats.vocabulary import FeatureFormat

__all__ = ["FeatureCodec", "BlockParams", "QuantizedLevel", "FixedLevel", "Layers", "codec_of", "endpoint_value",
           "endpoint_range"]


@dataclass
class BlockParams:
    """One mip of one layer as trainable blocks (paper §4.2): ``endpoints`` and ``x`` (indices
    scaled to [0, 1]) are learnt. BC6H: endpoints (n, 4, 3), two subsets, ``mask`` (n, 16) says
    which texels use the second and ``partition`` (n,) is the shape the encoding chose. BC7 mode 6:
    endpoints (n, 2, 4), one subset, no mask or partition."""

    endpoints: torch.Tensor
    x: torch.Tensor
    mask: torch.Tensor | None = None
    partition: np.ndarray | None = None


@dataclass(frozen=True)
class QuantizedLevel:
    """One mip of one layer as the exact block parameters that are written."""

    endpoints: np.ndarray
    indices: np.ndarray
    partition: np.ndarray | None
    size: int


@dataclass(frozen=True)
class FixedLevel:
    """One mip of one layer written as it was encoded once, never trained: ``blocks`` (n, 16) uint8
    as written (BC7, any mode) and ``values`` (C, size, size) float32, their decoded UNORM8 values
    (0..255), which training samples without a gradient (issue 29: a T_0 of principal components)."""

    blocks: np.ndarray
    values: torch.Tensor
    size: int

    def texels(self, device) -> torch.Tensor:
        """Every texel (n, 16, C) of its blocks in [0, 1], bit-exact as written (bcfpipe.bc7's decode)."""
        return torch.as_tensor(decode_to_u8(self.blocks).astype(np.float32) / np.float32(255.0), device=device)


L = TypeVar("L")
R = TypeVar("R")
LevelOf = Callable[[L, int, int], R]  # (level, layer, mip) -> R


@dataclass
class Layers(Generic[L]):
    """A material's feature layers, per layer, per mip, with the layers encoded once and never
    trained (``fixed``: a T_0 of principal components) kept apart from those that training moves
    (``trained``: free tensors, then `BlockParams`, then `QuantizedLevel`s). A layer's kind is
    settled where the structure is built; the phases, the fused step and the export read the two
    parts, and no level is asked what it is."""

    fixed: dict[int, list[FixedLevel]]
    trained: dict[int, list[L]]

    @classmethod
    def of(cls, layers: Sequence[list[L]], fixed: Mapping[int, list[FixedLevel]] | None = None) -> Layers[L]:
        """Layer i from ``fixed`` where that has it, else ``layers[i]`` (its list, not a copy)."""
        fixed = dict(fixed or {})
        return cls(fixed, {i: mips for i, mips in enumerate(layers) if i not in fixed})

    def __len__(self) -> int:
        return len(self.fixed) + len(self.trained)

    def __getitem__(self, i: int) -> list:
        return self.fixed[i] if i in self.fixed else self.trained[i]

    def __iter__(self) -> Iterator[list]:
        return (self[i] for i in range(len(self)))

    def trained_levels(self) -> list[L]:
        """The trained levels, layer by layer: what the optimizer moves."""
        return [lv for mips in self.trained.values() for lv in mips]

    def map(self, fn: LevelOf) -> Layers:
        """The trained levels through ``fn(level, layer, mip)``, in layer order; the fixed ones kept."""
        return Layers(self.fixed, {i: [fn(lv, i, k) for k, lv in enumerate(mips)] for i, mips in self.trained.items()})

    def lookup(self, fixed: Callable[[FixedLevel], R], trained: LevelOf) -> Callable[[int, int], R]:
        """(layer, mip) -> ``fixed(level)`` or ``trained(level, layer, mip)``, the function picked
        per layer here, once. The level is read at each call: one replaced in its layer's list (the
        fused step rehomes them) is the one seen."""
        def on_fixed(lv: FixedLevel, i: int, k: int) -> R:
            return fixed(lv)
        table = [(self.fixed[i], on_fixed) if i in self.fixed else (self.trained[i], trained) for i in range(len(self))]

        def at(i: int, k: int) -> R:
            mips, fn = table[i]
            return fn(mips[k], i, k)
        return at

    def each(self, fixed: Callable[[FixedLevel], R], trained: LevelOf) -> list[list[R]]:
        """Every level through its kind's function, as lists per layer, per mip."""
        at = self.lookup(fixed, trained)
        return [[at(i, k) for k in range(len(mips))] for i, mips in enumerate(self)]


class FeatureCodec:
    """One feature format (see the module docstring); stateless, one instance per format."""

    format: FeatureFormat
    channels: int
    lr_scale: dict[str, float]  # per phase: feature learning rates are stated for BC6H's 6-bit endpoint units

    def param_range(self, mc: ModelConfig) -> tuple[float, float]:
        raise NotImplementedError

    def init_range(self, mc: ModelConfig) -> tuple[float, float]:
        raise NotImplementedError

    def value(self, p: torch.Tensor, mc: ModelConfig) -> torch.Tensor:
        """Texel values of free parameters ``p`` (already clamped to :meth:`param_range`)."""
        raise NotImplementedError

    def encode(self, texels: np.ndarray, mc: ModelConfig, device, lib=None) -> BlockParams:
        """Warm texel values (H, W, channels) -> trainable blocks (requires_grad). ``lib``: the
        fused kernel's compiled library (bcfpipe.train.fused.native.load()), whose encoder a
        format may use where the caller has it."""
        raise NotImplementedError

    def texels(self, b: BlockParams, blk: torch.Tensor, pos: torch.Tensor, mc: ModelConfig,
               quantized: bool) -> torch.Tensor:
        """Values (M, channels) of texel ``pos`` of blocks ``blk``."""
        raise NotImplementedError

    def decode_blocks(self, b: BlockParams, mc: ModelConfig, quantized: bool) -> torch.Tensor:
        """Every texel (n, 16, channels) of a level."""
        raise NotImplementedError

    def quantize(self, b: BlockParams, mc: ModelConfig, size: int) -> QuantizedLevel:
        raise NotImplementedError

    def exact(self, q: QuantizedLevel, mc: ModelConfig, device) -> torch.Tensor:
        """Bit-exact decoded texels (n, 16, channels) of quantized parameters."""
        raise NotImplementedError

    def pack(self, q: QuantizedLevel, mc: ModelConfig) -> np.ndarray:
        """(n, 16) uint8 blocks of a quantized level, as written to the DDS file."""
        raise NotImplementedError

    def dxgi_format(self, mc: ModelConfig) -> int:
        raise NotImplementedError


# Phase 2's first encode picks each block's partition and a start that training then moves, so the
# encoder's refinement (its defaults: four shapes refined, two rounds, a window of 4 codes) buys
# nothing there: one shape, one round, a window of 1 trained teapot 1k `standard` to 37.61 dB (37.55
# refined), `draft` 31.20 (31.24), brick `draft` 28.80 (28.82), in a third of the encode's time
# (4.6 s against 12.9 s at 1k). BC7 likewise takes one round of its four: 37.86 (37.90) and 33.21
# (33.11), 5.5 s against 13.2 s (docs/benchmarks.md, "The first encode").
_BC6H_START = dict(refine_top=1, keep=1, rounds=1, window=1)
_BC7_START_ROUNDS = 1
_BC6H_NATIVE = True  # the one-shape start compiled (bc6h/quick.cpp) where a C++ compiler builds it


def _bc6h_start(texels, signed: bool, lib):
    """The first encode's parameters: the compiled one-shape path (bc6h/quick.cpp) in ``lib``, the
    fused kernel's library, where the caller has it; else the torch encoder with the same settings
    (the same blocks but for a few in a thousand, where float sums taken in another order tip a
    choice)."""
    if lib is not None and _BC6H_NATIVE and _BC6H_START["refine_top"] == 1:
        return quick.encode_params(texels, signed, lib, rounds=_BC6H_START["rounds"], window=_BC6H_START["window"])

    return encode_params(texels, signed=signed, **_BC6H_START)


def endpoint_value(p: torch.Tensor, signed: bool = False) -> torch.Tensor:
    """Smooth texel value of a constant BC6H block with endpoint ``p`` (continuous 6-bit domain)."""
    u = emulate.unquantize(p, signed=signed)
    return emulate.half_from_bits(u * (31.0 / 32.0 if signed else 31.0 / 64.0))


def endpoint_range(signed: bool, max_feature: float | None = None) -> tuple[float, float]:
    """Endpoint bounds used in training: the format's range, narrowed so decoded features stay
    within +-``max_feature``. Large features make no better MLP inputs but make the 6-bit log-like
    endpoint steps coarse in absolute terms and magnify hardware filtering error at decode time."""
    lo, hi = (-32.0, 31.0) if signed else (0.0, 63.0)
    if max_feature is None:
        return lo, hi
    e = torch.arange(0.0, hi + 1)
    top = float(e[endpoint_value(e, signed) <= max_feature].max())
    return (-top, top) if signed else (0.0, top)


class _BC6H(FeatureCodec):
    format = FeatureFormat.BC6H
    channels = 3
    lr_scale = {"warmup": 1.0, "constrained": 1.0}

    def param_range(self, mc):
        return endpoint_range(mc.signed, mc.max_feature)

    def init_range(self, mc):
        return (-15.0, 15.0) if mc.signed else (20.0, 32.0)

    def value(self, p, mc):
        return endpoint_value(p, mc.signed)

    def encode(self, texels, mc, device, lib=None):
        e, idx, part = _bc6h_start(texels, mc.signed, lib)
        return BlockParams(torch.as_tensor(e, dtype=torch.float32, device=device).requires_grad_(True),
                           (torch.as_tensor(idx, dtype=torch.float32, device=device) / 7.0).requires_grad_(True),
                           emulate.partition_mask(part, device=device), np.asarray(part))

    def texels(self, b, blk, pos, mc, quantized):
        e = b.endpoints[blk]  # (M, 4, 3)
        m = b.mask[blk, pos].unsqueeze(1)
        ea = torch.where(m, e[:, 2], e[:, 0])
        eb = torch.where(m, e[:, 3], e[:, 1])
        return emulate.decode_texels(ea, eb, b.x[blk, pos], mc.signed, quantized)

    def decode_blocks(self, b, mc, quantized):
        return emulate.decode_blocks(b.endpoints, b.x, b.mask, signed=mc.signed, quantized=quantized)

    def quantize(self, b, mc, size):
        e, idx, part = emulate.to_params(b.endpoints, b.x, b.partition, signed=mc.signed)
        return QuantizedLevel(e, idx, part, size)

    def exact(self, q, mc, device):
        e, x, mask, _ = emulate.from_params(q.endpoints, q.indices, q.partition, device=device)
        return emulate.decode_blocks(e, x, mask, signed=mc.signed, quantized=True)

    def pack(self, q, mc):
        return mode10.pack(q.endpoints, q.indices, q.partition, signed=mc.signed)

    def dxgi_format(self, mc):
        return dds.DXGI_FORMAT_BC6H_SF16 if mc.signed else dds.DXGI_FORMAT_BC6H_UF16


class _BC7(FeatureCodec):
    format = FeatureFormat.BC7
    channels = 4
    # Feature learning rates in 8-bit endpoint units, relative to the presets' (stated for BC6H's 6-bit,
    # log-like endpoints). Measured on the teapot (0.5k, draft; all-mip PSNR, mips 0-1), warm-up x
    # constrained: 32 x 32: 29.45 (25.9, 26.2); 128 x 8: 30.45; 512 x 8: 30.40; 1024 x 4: 30.98;
    # 4096 x 4: 31.04; 1024 x 2: 31.23; 1024 x 1: 31.28 (28.9, 29.5); BC6H: 29.83 (27.5, 28.0).
    # The warm-up wants large steps, the constrained phase small ones. With x1024 many warm features
    # end at the ends of [0, 1] (the clamp): the large rate partly works by saturating them.
    lr_scale = {"warmup": 1024.0, "constrained": 1.0}

    def param_range(self, mc):
        return 0.0, 255.0

    def init_range(self, mc):
        # features in [0.43, 0.57]; measured on the brick (tiny, draft, rates x32 x32): [0, 1] 27.6 dB,
        # [0.25, 0.75] 28.0, this 28.1
        return 110.0, 146.0

    def value(self, p, mc):
        return p / 255.0

    def encode(self, texels, mc, device, lib=None):
        h, w, c = texels.shape
        blocks = texels.reshape(h // 4, 4, w // 4, 4, c).transpose(0, 2, 1, 3, 4).reshape(-1, 16, c)
        e, idx = bc7_encode_params(blocks, rounds=_BC7_START_ROUNDS)
        return BlockParams(torch.as_tensor(e, dtype=torch.float32, device=device).requires_grad_(True),
                           (torch.as_tensor(idx, dtype=torch.float32, device=device) / 15.0).requires_grad_(True))

    def texels(self, b, blk, pos, mc, quantized):
        e = b.endpoints[blk]  # (M, 2, 4)
        return bc7_emulate.decode_texels(e[:, 0], e[:, 1], b.x[blk, pos], quantized)

    def decode_blocks(self, b, mc, quantized):
        return bc7_emulate.decode_blocks(b.endpoints, b.x, quantized)

    def quantize(self, b, mc, size):
        """The values quantization-aware decoding uses (the same float32 arithmetic), as integers."""
        with torch.no_grad():
            e = bc7_emulate.quantize_endpoints(b.endpoints.detach()).cpu().numpy().astype(np.uint8)
            idx = torch.round(b.x.detach().clamp(0.0, 1.0) * bc7_emulate.LEVELS).cpu().numpy().astype(np.uint8)
        return QuantizedLevel(e, idx, None, size)

    def exact(self, q, mc, device):
        u8 = mode6.interpolate(q.endpoints, q.indices)
        return torch.as_tensor(u8.astype(np.float32) / np.float32(255.0), device=device)

    def pack(self, q, mc):
        return mode6.pack(q.endpoints, q.indices)

    def dxgi_format(self, mc):
        return dds.DXGI_FORMAT_BC7_UNORM


_CODECS = {FeatureFormat.BC6H: _BC6H(), FeatureFormat.BC7: _BC7()}


def codec_of(mc: ModelConfig) -> FeatureCodec:
    return _CODECS[FeatureFormat(mc.features)]
