"""``material.json``: everything a consumer needs to decode one exported material.

The contract is this module's records and schemas/material.schema.json, which says what each key
means; tests check that the two agree and that every file bcfpipe writes passes the schema. The
only writer is :func:`bcfpipe.export.writer.export`; every reader goes through :func:`read`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from bcfpipe import __version__
from bcfpipe.formats.atomic import atomic_write
from bcfpipe.formats.vocabulary import Source, Wrap, wrap_axes
from bcfpipe.formats.record import FormatError, Record, optional, read as read_record

FORMAT = "bcfpipe-material"
FORMAT_VERSION = 8  # 3: classic textures and each output's source (issue 31); 4: the mip-split layout ("split");
# 5: a layer's "blocks" (a T_0 of principal components in any BC7 mode, issue 29); 6: more than four layers
# (a T_0 of two or three layers of components, issue 52: T0.dds, T0b.dds, T0c.dds, then T1..T3); 7: addressing
# per axis (sampling.wrap_s / wrap_t: repeat, clamp or mirror, as a UsdUVTexture's wrapS / wrapT; issue 57),
# written only where the axes differ or one mirrors; 8: a classic normal stored as slopes (outputs' "encoding":
# "slope", issue 57), written only with one; versions 2-7 read as before. A material is written as the lowest version its contents need, byte for byte as before:
# four layers none of which is in any mode, as version 3 (with a split, 4); four layers, one of them in any
# mode, as version 5; so readers of those versions read what they read before.
NO_SPLIT_VERSION = 3
SPLIT_VERSION = 4
ANY_MODE_VERSION = 5
MANY_LAYERS_VERSION = 6
PER_AXIS_VERSION = 7
SLOPE = "slope"  # Output.encoding of a normal stored as slopes: (s_x, s_y, 1) normalised is the normal
PROFILE_LAYERS = 4  # T_0..T_3: a material with more layers is written as FORMAT_VERSION
ANY_BC7_MODE = "any BC7 mode"  # Layer.blocks of a layer encoded once by a full BC7 encoder
FILE = "material.json"
WEIGHTS = "weights.bin"
ONNX = "decoder.onnx"
ONNX_INPUT = "features"  # the decoder's input and output names (material.json ``onnx``)
ONNX_OUTPUT = "channels"


def layer_name(i: int, t0_layers: int = 1) -> str:
    """Name of the model's feature layer i when T_0 has ``t0_layers`` layers: T_0's are T0, T0b,
    T0c, then the profile's T1..T3; with one T_0 layer, layer i is Ti. The MLP input order and the
    DDS files use it; material.json's ``layers[i].file`` is what a reader goes by."""
    if i < t0_layers:
        return "T0" if i == 0 else f"T0{chr(ord('a') + i)}"
    return f"T{i - t0_layers + 1}"


def layer_file(i: int, t0_layers: int = 1) -> str:
    """File name of the model's feature layer i (`layer_name`)."""
    return f"{layer_name(i, t0_layers)}.dds"


def classic_file(i: int) -> str:
    """File name of classic texture C_i."""
    return f"C{i}.dds"


@dataclass(frozen=True)
class Layer(Record):
    """One feature texture: a mipmapped BC6H or BC7 DDS of ``resolution``², sampled at s +
    ``lod_bias``; its first ``channels`` channels are features (3 for BC6H, 4 for BC7), the next
    ones in the MLP's input after the previous layers'. T_0..T_3, or with a T_0 of several layers
    of principal components (version 6) T0, T0b(, T0c), T1..T3 (`layer_name`)."""

    file: str
    resolution: int
    mip_count: int
    lod_bias: float
    channels: int = 3
    # ANY_BC7_MODE: this layer's blocks may use every BC7 mode (encoded once, not trained: a T_0 of
    # principal components); absent: every block is in the format record's block_mode
    blocks: str | None = optional()


@dataclass(frozen=True)
class BC6H(Record):
    """How the feature textures are block-compressed, when they are BC6H."""

    dxgi_format: int
    signed: bool
    block_mode: str


@dataclass(frozen=True)
class BC7(Record):
    """How the feature textures are block-compressed, when they are BC7 (``--features bc7``):
    UNORM, every block in ``block_mode``; a texel's value is its 8-bit value / 255."""

    dxgi_format: int
    block_mode: str


@dataclass(frozen=True)
class Sampling(Record):
    """How a decoder samples the feature layers and classic textures (hardware trilinear
    filtering), with an addressing per axis (S along u, T along v). Written as ``addressing`` when
    both axes repeat or both clamp (the one key readers before version 7 know), else as ``wrap_s``
    and ``wrap_t`` (version 7); `Sampling.of` picks, `axes` reads either."""

    addressing: str | None = optional()
    filter: str = "trilinear (LINEAR_MIPMAP_LINEAR), lod clamped to [0, mip_count-1]"
    uv: str = "u along width, v along height; v = 0 is the first stored row (for USD st use v = 1 - t)"
    lod: str = "s_i = s + lod_bias_i, with s = log2 of the pixel footprint in reference texels"
    wrap_s: str | None = optional()
    wrap_t: str | None = optional()

    _ORDER = ("addressing", "wrap_s", "wrap_t")

    def __post_init__(self) -> None:
        if (self.addressing is None) == (self.wrap_s is None or self.wrap_t is None):
            raise FormatError("material.json: sampling needs either 'addressing' or both 'wrap_s' and 'wrap_t'")
        try:
            wrap_axes(self.addressing if self.addressing is not None else (self.wrap_s, self.wrap_t))
        except ValueError as exc:
            raise FormatError(f"material.json: sampling: {exc}") from None

    @classmethod
    def of(cls, wrap) -> "Sampling":
        """The record of an addressing (one mode, or an (S, T) pair), in the lowest version that holds it."""
        s, t = wrap_axes(wrap)
        if s == t and s != Wrap.MIRROR:
            return cls(str(s))
        return cls(wrap_s=str(s), wrap_t=str(t))

    @property
    def axes(self) -> tuple[str, str]:
        """(S, T) addressing, whichever way it is written."""
        s, t = wrap_axes(self.addressing if self.addressing is not None else (self.wrap_s, self.wrap_t))
        return str(s), str(t)

    @property
    def per_axis(self) -> bool:
        """Whether it is written per axis (material.json version 7)."""
        return self.addressing is None


@dataclass(frozen=True)
class Reference(Record):
    """The source texture set's size; s = 0 is its mip 0."""

    width: int
    height: int
    mip_count: int


@dataclass(frozen=True)
class Mlp(Record):
    """The decoder: ``n_in`` features -> ``n_hidden`` ReLU units -> ``n_out`` outputs, then
    ``out_scale`` * y + ``out_bias`` per output."""

    weights: str
    offset: int
    size_bytes: int
    n_in: int
    n_hidden: int
    n_out: int
    activation: str
    precision: str
    record: str
    input_order: tuple[str, ...]
    out_scale: tuple[float, ...]
    out_bias: tuple[float, ...]


@dataclass(frozen=True)
class Output(Record):
    """One decoded channel and the UsdPreviewSurface input it feeds; ``reconstructed`` outputs
    (normal z) are computed by the decoder's post-processing, not by the MLP."""

    name: str
    semantic: str
    component: str
    kind: str
    usd_target: str | None
    range: tuple[float, float]
    source_channel: int | None
    source_format: str | None
    reconstructed: bool
    value_scale: float = 1.0
    value_bias: float = 0.0
    log_gain: float | None = optional()  # HDR channels only: the decoder's log-domain gain (BCFW v2)
    # None: the MLP's (Source.MLP); Source.CLASSIC: a classic texture's; Source.SPLIT: the classic
    # texture's for s <= split - 1, the MLP's for s >= split, linear in s between (MaterialFile.split)
    source: str | None = optional()
    texture: int | None = optional()  # classic and split outputs: index into MaterialFile.classic
    texel_channel: int | None = optional()  # classic outputs: the texture's channel (0 = r)
    texel_scale: float | None = optional()  # classic outputs: value = texel * texel_scale + texel_bias
    texel_bias: float | None = optional()
    # SLOPE: a classic normal stored as slopes (issue 57): x's and y's texel * texel_scale + texel_bias are
    # s_x = x / z and s_y = y / z; the normal is (s_x, s_y, 1) normalised (z = 1 / sqrt(1 + s_x² + s_y²))
    encoding: str | None = optional()


@dataclass(frozen=True)
class ClassicTexture(Record):
    """A classic BC texture that outputs read directly (a layout's classic group, issue 31): a DDS
    (DX10 header) of ``width`` × ``height`` with ``mip_count`` mips (every mip down to 1×1, or in a
    mip-split layout those that serve s < split), sampled like the feature layers (trilinear, the
    material's addressing) at s + ``lod_bias``, the lod clamped to its mips; texels are UNORM in [0, 1],
    or a BC6H_UF16 texture's half floats (an HDR colour's linear values)."""

    file: str
    dxgi_format: int
    format: str
    width: int
    height: int
    mip_count: int
    lod_bias: float
    channels: int
    # per texel channel, the output it stores (an index into outputs),
    # when a channel is stored in more than one slot: a colour whose source repeats a channel, kept in
    # the slots a UsdUVTexture's rgb reads (issue 57); None when every channel is stored once
    slots: tuple[int, ...] | None = optional()


@dataclass(frozen=True)
class Onnx(Record):
    """The decoder as an ONNX model: features (N, n_in) -> channels (N, outputs)."""

    file: str
    input: str
    output: str
    opset: int


@dataclass(frozen=True)
class Training(Record):
    """How the material was trained (informative; it holds no times: the same inputs give the same file)."""

    profile_resolutions: tuple[int, ...]
    preset: str
    seed: int
    device: str


@dataclass(frozen=True)
class MaterialFile(Record):
    """The material.json of one exported material folder."""

    layers: tuple[Layer, ...]  # empty when no output comes from the MLP
    sampling: Sampling
    reference: Reference
    outputs: tuple[Output, ...]
    training: Training
    mlp: Mlp | None = optional()  # None when no output comes from the MLP
    onnx: Onnx | None = optional()
    bc6h: BC6H | None = optional()  # exactly one of bc6h and bc7 when there are layers
    bc7: BC7 | None = optional()
    classic: tuple[ClassicTexture, ...] = ()
    # A mip-split layout: the first reference mip (s) the MLP serves; its outputs are Source.SPLIT
    split: int | None = optional()
    sha256: dict[str, str] | None = optional()
    format: str = FORMAT
    format_version: int = FORMAT_VERSION
    bcfpipe_version: str = field(default_factory=lambda: _version())

    _ORDER = ("format", "format_version", "bcfpipe_version", "layers", "bc6h", "bc7", "sampling", "reference", "mlp",
              "outputs", "onnx", "training")

    def __post_init__(self) -> None:
        # the version this record is written as (FORMAT_VERSION's note)
        any_mode = any(layer.blocks is not None for layer in self.layers)
        slope = [o for o in self.outputs if o.encoding is not None]
        object.__setattr__(self, "format_version", FORMAT_VERSION if slope else
                           PER_AXIS_VERSION if self.sampling.per_axis else
                           MANY_LAYERS_VERSION if len(self.layers) > PROFILE_LAYERS else
                           ANY_MODE_VERSION if any_mode else SPLIT_VERSION if self.split is not None else
                           NO_SPLIT_VERSION)
        neural = any(o.source != Source.CLASSIC for o in self.outputs)
        if neural and (self.bc6h is None) == (self.bc7 is None):
            raise FormatError("material.json needs exactly one of 'bc6h' and 'bc7' (the feature format)")
        if neural and (self.mlp is None or self.onnx is None or not self.layers):
            raise FormatError("material.json: outputs from the MLP need 'layers', 'mlp' and 'onnx'")
        if not neural and (self.layers or self.mlp or self.onnx or self.bc6h or self.bc7):
            raise FormatError("material.json: no output comes from the MLP, yet it has feature layers or an MLP")
        for o in self.outputs:
            if o.source in (Source.CLASSIC, Source.SPLIT) and (o.texture is None
                                                               or not 0 <= o.texture < len(self.classic)):
                raise FormatError(f"material.json: output {o.name} names no classic texture")
        if any(o.encoding != SLOPE or o.kind != "normal" or o.source not in (Source.CLASSIC, Source.SPLIT)
               for o in slope):
            raise FormatError("material.json: an output's 'encoding' is 'slope', on a classic or split normal only")
        splits = any(o.source == Source.SPLIT for o in self.outputs)
        if splits != (self.split is not None) or (self.split is not None and self.split < 1):
            raise FormatError("material.json: 'split' (a reference mip >= 1) goes with outputs whose source is "
                              "'split', and only with them")

    @property
    def neural(self) -> bool:
        """Whether any output comes from the MLP (a layout may ship classic textures only)."""
        return self.mlp is not None

    @property
    def mixed(self) -> bool:
        """Whether some outputs come from classic textures."""
        return any(o.source in (Source.CLASSIC, Source.SPLIT) for o in self.outputs)

    @property
    def features(self) -> str:
        """The feature format: "bc6h" or "bc7"."""
        return "bc7" if self.bc7 is not None else "bc6h"

    @property
    def signed(self) -> bool:
        return self.bc6h is not None and self.bc6h.signed

    @property
    def wrap(self) -> tuple[str, str]:
        """(S, T) addressing of every layer and classic texture."""
        return self.sampling.axes

    @property
    def lod_biases(self) -> tuple[float, ...]:
        return tuple(layer.lod_bias for layer in self.layers)

    @property
    def mip_counts(self) -> tuple[int, ...]:
        return tuple(layer.mip_count for layer in self.layers)

    @property
    def mlp_outputs(self) -> tuple[Output, ...]:
        """The outputs the decoder (MLP and its post-processing) produces, in its output order."""
        return tuple(o for o in self.outputs if o.source != Source.CLASSIC)

    @property
    def kinds(self) -> tuple[str, ...]:
        """Kinds of the MLP's outputs (reconstructed outputs excluded)."""
        return tuple(o.kind for o in self.mlp_outputs if not o.reconstructed)

    @property
    def normal_index(self) -> int:
        """Index of normal x among the MLP's outputs, -1 without a normal map."""
        return next((i for i, k in enumerate(self.kinds) if k == "normal"), -1)

    @property
    def files(self) -> list[str]:
        """Every file of the material besides material.json, in digest order."""
        neural = [layer.file for layer in self.layers] + ([self.mlp.weights, self.onnx.file] if self.mlp else [])
        return neural + [c.file for c in self.classic]


def _version() -> str:
    return __version__


def read(folder: str | os.PathLike) -> MaterialFile:
    """``folder/material.json``; a missing, foreign or malformed file raises FormatError."""
    # v2 (all from the MLP) reads as v3; v3, a material without a split, stays v3 as written
    return read_record(MaterialFile, Path(folder) / FILE, FORMAT, FORMAT_VERSION, compatible=(2, 3, 4, 5, 6, 7),
                       upgrade=lambda data: dict(data, format_version=NO_SPLIT_VERSION))


def write(folder: str | os.PathLike, desc: MaterialFile) -> Path:
    """``folder/material.json``, as the version its contents need (FORMAT_VERSION's note)."""
    path = Path(folder) / FILE
    atomic_write(path, desc.dumps().encode())
    return path
