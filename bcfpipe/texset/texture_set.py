"""Texture sets: the reference data a neural material learns.

A material's textures (albedo, normal, ARM, displacement, ...) are described by `TextureSpec`s
(``semantic=path:channels``), loaded with OpenImageIO into one `TextureSet` (an (H, W, c) float32
array plus a `Channel` per column), and turned into a mip chain with `build_mip_chain`.

Conventions (documented here once, relied on by the sampler, trainer and metrics):

* Values are the *stored* values, as a shader's texture fetch from a non-sRGB (UNORM / float)
  texture format would return them: 8/16-bit integers are mapped to [0, 1] with no sRGB
  linearisation and no colour management (a tag such as PQ / BT.2020 on a PNG is ignored), so the
  model reproduces exactly what the original texture would have fed the shader. Float files (EXR,
  half) are passed through unclamped.
* Value ranges (HDR, negative values): a channel from a float file whose values leave the
  nominal [0, 1] is stored normalised, ``t = (v - lo) / (hi - lo)`` with ``lo = min(0, min v)``
  and ``hi = max(1, max v)``, and its `Channel` keeps ``value_scale = hi - lo`` and
  ``value_bias = lo``: the decoder reproduces t, and ``v = t * value_scale + value_bias``
  (material.json ``outputs[].value_scale/value_bias``; the USD layer folds them into each
  target's scale and bias). Quality figures are therefore relative to the channel's own range:
  an HDR channel's PSNR uses the peak ``hi - lo``. A non-negative float colour channel beyond 1
  is, in addition, learnt in a log domain (``Channel.log_gain``, bcfpipe.texset.encoding) that the
  decoders undo, so it keeps relative precision; ``data`` still holds the linear t. Values beyond fp16's +-65504 cannot be stored by
  any consumer of half-float data and are clamped to it, with a warning.
* Non-finite texels (NaN, +-Inf) are refused (`NonFiniteError`, naming the file, channel and
  count, as maketx --checknan does) unless ``fix_nonfinite``: then NaN becomes 0 and +-Inf the
  channel's largest / smallest finite value, with a warning.
* Alpha is read unassociated (straight), as stored: OpenImageIO premultiplies colour by alpha by
  default, which would corrupt e.g. a PNG whose alpha channel carries opacity or roughness.
* Normals (semantic ``normal``) keep x, y only, mapped ``v * 2 - 1`` to [-1, 1]; z is
  reconstructed at decode time.
* Grey files feed r, g and b from their single channel; ``a`` of a file without alpha is an error.
  CMYK JPEGs are converted to RGB by OpenImageIO (naive ``(1-C)(1-K)``, embedded ICC profile
  ignored), so colours are plausible but not colour-managed.
* All sources are resampled to one common size (see `common_resolution`) with OpenImageIO's
  ``blackman-harris`` filter, once per file. That filter is positive everywhere, so resampling never
  overshoots the stored range (no ringing, unlike lanczos3); integer files are clipped to [0, 1]
  afterwards to remove float rounding (1.0000001).
* uv / image layout: row 0 is the first row stored in the file; arrays are (rows, cols, channels).
"""
from __future__ import annotations


import logging
import os
import re
from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np

from bcfpipe.errors import InputError
from bcfpipe.formats import images
from bcfpipe.formats.images import channel_index as source_channel_index
from bcfpipe.formats.images import MissingChannel
from bcfpipe.scan.sources import common_resolution
from bcfpipe.texset.encoding import log_gain_for

__all__ = [
    "Semantic", "SEMANTICS", "ALIASES", "semantic_info", "TextureError", "TextureSpec", "Channel",
    "TextureSet", "load_texture_set", "common_resolution", "build_mip_chain", "RESAMPLE_FILTER",
]

RESAMPLE_FILTER = "blackman-harris"


class TextureError(InputError):
    """A texture file is missing, unreadable, or lacks a requested channel."""


class NonFiniteError(TextureError):
    """A texture holds NaN or Inf texels (exit code 2; ``--fix-nonfinite`` replaces them)."""


FP16_MAX = 65504.0
log = logging.getLogger("bcfpipe.texset")


# --------------------------------------------------------------------------------------------
# semantic registry


@dataclass(frozen=True)
class Semantic:
    """One kind of material channel group: its name, value kind, channel count and USD input."""

    name: str
    kind: str  # 'color' | 'normal' | 'scalar'
    channels: int | None  # None: any count (generic)
    usd_input: str | None  # UsdPreviewSurface input name; None for generic data
    default_channels: str

    @property
    def value_range(self) -> tuple[float, float]:
        """Nominal value range of this semantic's channels in a `TextureSet`."""
        return (-1.0, 1.0) if self.kind == "normal" else (0.0, 1.0)


SEMANTICS: Mapping[str, Semantic] = {
    s.name: s
    for s in (
        Semantic("albedo", "color", 3, "diffuseColor", "rgb"),
        Semantic("normal", "normal", 2, "normal", "xy"),
        Semantic("occlusion", "scalar", 1, "occlusion", "r"),
        Semantic("roughness", "scalar", 1, "roughness", "r"),
        Semantic("metallic", "scalar", 1, "metallic", "r"),
        Semantic("displacement", "scalar", 1, "displacement", "r"),
        Semantic("opacity", "scalar", 1, "opacity", "r"),
        Semantic("emissiveColor", "color", 3, "emissiveColor", "rgb"),
        Semantic("generic", "scalar", None, None, "r"),
    )
}

#: other spellings accepted by `semantic_info` / `TextureSpec.parse` (keys compared lower-case).
ALIASES: Mapping[str, str] = {
    "diffusecolor": "albedo", "basecolor": "albedo", "diffuse": "albedo",
    "ao": "occlusion", "metalness": "metallic", "height": "displacement",
    "emissive": "emissiveColor", "emission": "emissiveColor",
}

_CANONICAL = {name.lower(): name for name in SEMANTICS}


def semantic_info(name: str) -> Semantic:
    """The registry entry for a semantic name or alias (case-insensitive)."""
    key = name.strip().lower()
    canon = _CANONICAL.get(key) or ALIASES.get(key)
    if canon is None:
        raise ValueError(f"unknown texture semantic {name!r}; known: {', '.join(SEMANTICS)}")
    return SEMANTICS[canon]


# --------------------------------------------------------------------------------------------
# specs and channels

# channel letters: r/x=0, g/y=1, b/z=2, a/w=3 (logical RGBA slots of the file)
_SLOT = {"r": 0, "g": 1, "b": 2, "a": 3, "x": 0, "y": 1, "z": 2, "w": 3}
_CHANNELS_RE = re.compile(r"^[rgbaxyzw]+$")


@dataclass(frozen=True)
class TextureSpec:
    """One source texture: which semantic it feeds, from which file, through which channels."""

    semantic: str
    path: str
    channels: str

    def __post_init__(self) -> None:
        sem = semantic_info(self.semantic)
        object.__setattr__(self, "semantic", sem.name)
        object.__setattr__(self, "path", os.fspath(self.path))
        ch = self.channels.lower()
        if not _CHANNELS_RE.match(ch):
            raise ValueError(f"{self.semantic}: bad channel selection {self.channels!r} (use letters from rgba or xyzw)")
        if sem.channels is not None and len(ch) != sem.channels:
            raise ValueError(f"{sem.name} needs {sem.channels} channel(s), got {self.channels!r} ({len(ch)})")
        object.__setattr__(self, "channels", ch)

    @classmethod
    def parse(cls, text: str, base_dir: str | os.PathLike | None = None) -> "TextureSpec":
        """Parse ``semantic=path[:channels]``, e.g. ``roughness=arm.jpg:g`` or ``normal=n.png:xy``.

        The ``:channels`` suffix is only taken when it is made of channel letters, so paths with
        colons (``C:\\tex.png``) still work. Default channels come from the semantic (colour: rgb,
        normal: xy, scalar: r). A relative path is joined to `base_dir` when given.
        """
        sem_name, sep, rest = text.partition("=")
        if not sep or not sem_name.strip() or not rest.strip():
            raise ValueError(f"bad texture spec {text!r}: expected semantic=path[:channels]")
        sem = semantic_info(sem_name)
        path, channels = rest.strip(), sem.default_channels
        head, colon, tail = path.rpartition(":")
        if colon and head and _CHANNELS_RE.match(tail.lower()):
            path, channels = head, tail
        elif colon and head and tail.isalpha() and len(tail) <= 4 and not os.path.exists(path):
            raise ValueError(f"bad channel selection {tail!r} in {text!r}: channels are letters of "
                             f"r, g, b, a (x, y, z, w), e.g. {sem.name}=file.png:{sem.default_channels}")
        if base_dir is not None and not os.path.isabs(path):
            path = os.path.join(os.fspath(base_dir), path)
        return cls(sem.name, path, channels)

    def __str__(self) -> str:
        return f"{self.semantic}={self.path}:{self.channels}"


@dataclass(frozen=True)
class Channel:
    """One column of a `TextureSet`: what it means and where it came from.

    `component` is the semantic component for colour ('r','g','b') and normal ('x','y') channels,
    and the letter read from the file for scalar / generic channels (e.g. 'g' for ARM roughness).
    `source_channel` is the index in the file's own channel list (a grey file has only 0).
    """

    semantic: str
    component: str
    kind: str
    source: str
    source_channel: int
    source_format: str = ""  # stored texel type of the source file (OpenImageIO base type, e.g. uint8)
    value_scale: float = 1.0  # source value = stored (decoded) value * value_scale + value_bias
    value_bias: float = 0.0
    log_gain: float = 0.0  # HDR: learnt in a log domain of this gain (bcfpipe.texset.encoding); 0 linear

    @property
    def name(self) -> str:
        return f"{self.semantic}.{self.component}"

    @property
    def value_range(self) -> tuple[float, float]:
        return (-1.0, 1.0) if self.kind == "normal" else (0.0, 1.0)

    @property
    def peak(self) -> float:
        """Width of the nominal value range (1 for [0,1] data, 2 for normals in [-1,1])."""
        lo, hi = self.value_range
        return hi - lo


@dataclass(frozen=True)
class TextureSet:
    """A material's channels resampled to one size: ``data`` is (height, width, c) float32."""

    data: np.ndarray
    channels: tuple[Channel, ...]
    width: int
    height: int
    # colours a UsdUVTexture reads through rgb whose channels no colour semantic holds in order (issue
    # 57: a folded duplicate or a grey file): (semantic, the set channel of each of its r, g, b slots,
    # repeated where the source repeats it). A classic layout stores each as one texture in that order.
    vectors: tuple[tuple[str, tuple[int, ...]], ...] = ()

    def __post_init__(self) -> None:
        d = self.data
        if not isinstance(d, np.ndarray) or d.ndim != 3 or d.dtype != np.float32:
            raise ValueError("TextureSet.data must be a float32 array of shape (height, width, c)")
        if d.shape != (self.height, self.width, len(self.channels)):
            raise ValueError(f"TextureSet.data has shape {d.shape}, expected "
                             f"({self.height}, {self.width}, {len(self.channels)})")
        object.__setattr__(self, "channels", tuple(self.channels))

    @property
    def num_channels(self) -> int:
        return len(self.channels)

    def groups(self) -> dict[str, list[int]]:
        """Channel indices per semantic, in order of first appearance."""
        out: dict[str, list[int]] = {}
        for i, ch in enumerate(self.channels):
            out.setdefault(ch.semantic, []).append(i)
        return out

    def kind_of(self, semantic: str) -> str:
        """The channel kind ('color' | 'normal' | 'scalar') of a semantic present in this set."""
        return self.channels[self.groups()[semantic][0]].kind


# --------------------------------------------------------------------------------------------
# loading


def _is_pow2(n: int) -> bool:
    return n >= 1 and (n & (n - 1)) == 0


def _check_resolution(resolution: int | tuple[int, int]) -> tuple[int, int]:
    w, h = (resolution, resolution) if isinstance(resolution, (int, np.integer)) else tuple(resolution)
    if not (_is_pow2(int(w)) and _is_pow2(int(h))):
        raise ValueError(f"resolution must be powers of two, got {w}x{h}")
    return int(w), int(h)


@dataclass
class _Source:
    """A decoded file, kept for the duration of one `load_texture_set` call."""

    path: str  # the user's name for it (a worker reads a copy; messages name the original)
    names: tuple[str, ...]
    texels: np.ndarray  # (H, W, n) float32 as decoded (integer files as UNORM)
    is_float: bool  # stored as half/float/double (else integer UNORM, so [0, 1] by construction)
    format: str  # the stored base type, e.g. uint8, uint16, half
    pixels: np.ndarray | None = field(default=None)  # (H, W, n) float32 at the common size

    @property
    def width(self) -> int:
        return self.texels.shape[1]

    @property
    def height(self) -> int:
        return self.texels.shape[0]


def _check_finite(src: _Source, fix: bool) -> None:
    """Refuse (or, with ``fix``, repair) NaN / Inf texels of a float file, per channel."""
    if not src.is_float:
        return
    px = src.texels
    bad = ~np.isfinite(px)
    counts = bad.reshape(-1, px.shape[-1]).sum(0)
    if not counts.any():
        return
    where = ", ".join(f"channel {src.names[c] if c < len(src.names) else c}: {int(n)}"
                      for c, n in enumerate(counts) if n)
    if not fix:
        raise NonFiniteError(f"{src.path}: {int(counts.sum())} NaN/Inf texel(s) ({where}); "
                             "use --fix-nonfinite to replace them")
    for c in np.nonzero(counts)[0]:
        ch = px[..., c]
        finite = ch[np.isfinite(ch)]
        hi, lo = (float(finite.max()), float(finite.min())) if finite.size else (0.0, 0.0)
        ch[np.isnan(ch)] = 0.0
        ch[np.isposinf(ch)] = hi
        ch[np.isneginf(ch)] = lo
    log.warning("%s: replaced %d NaN/Inf texel(s) (%s): NaN by 0, +-Inf by the channel's largest / "
                "smallest finite value", src.path, int(counts.sum()), where)


def _value_range(col: np.ndarray, ch: Channel, src: _Source) -> tuple[np.ndarray, Channel]:
    """Clamp to fp16's range, and normalise a float channel that leaves [0, 1] (module doc)."""
    big = np.abs(col) > FP16_MAX
    if big.any():
        log.warning("%s: %d texel(s) of channel %s beyond fp16's +-65504 clamped to it", src.path,
                    int(big.sum()), ch.name)
        np.clip(col, -FP16_MAX, FP16_MAX, out=col)
    if not src.is_float or ch.kind == "normal":
        return col, ch
    lo, hi = float(col.min()), float(col.max())
    if lo >= 0.0 and hi <= 1.0:
        return col, ch
    gain = log_gain_for(ch.kind, src.is_float, lo, hi)
    lo, hi = min(0.0, lo), max(1.0, hi)
    return (col - lo) / (hi - lo), replace(ch, value_scale=hi - lo, value_bias=lo, log_gain=gain)


def _open(path: str, shown: str) -> _Source:
    try:
        im = images.read(path, as_float=True, unassociated_alpha=True, name=shown)
    except images.ImageReadError as exc:
        raise TextureError(str(exc)) from None
    texels = np.ascontiguousarray(im.pixels, dtype=np.float32)
    texels.setflags(write=True)
    return _Source(shown, im.names, texels, im.is_float, im.format)


def _source_index(src: _Source, letter: str) -> int:
    try:
        return source_channel_index(src.names, letter, src.path)
    except MissingChannel as exc:
        raise TextureError(str(exc)) from None


def _resampled(src: _Source, width: int, height: int) -> np.ndarray:
    import OpenImageIO as oiio  # lazy: start-up

    if src.pixels is None:
        px = src.texels
        if (src.width, src.height) != (width, height):
            n = px.shape[2]
            buf = oiio.ImageBuf(oiio.ImageSpec(src.width, src.height, n, oiio.FLOAT))
            buf.set_pixels(oiio.ROI(0, src.width, 0, src.height, 0, 1, 0, n), px)
            buf = oiio.ImageBufAlgo.resize(buf, RESAMPLE_FILTER, 0.0, oiio.ROI(0, width, 0, height, 0, 1, 0, n))
            if buf.has_error:
                raise TextureError(f"{src.path}: resize to {width}x{height} failed ({buf.geterror().strip()})")
            px = np.asarray(buf.get_pixels(oiio.FLOAT), dtype=np.float32).reshape(height, width, -1)
            if not src.is_float:  # integer texels are UNORM: drop the filter's rounding excursions
                px = np.clip(px, 0.0, 1.0)
        src.pixels = px
    return src.pixels


def load_texture_set(
    specs: Sequence[TextureSpec | str],
    resolution: int | tuple[int, int] | None = None,
    fix_nonfinite: bool = False,
    names: Mapping[str, str] | None = None,
) -> TextureSet:
    """Load and resample a material's textures into one `TextureSet`.

    `specs` are `TextureSpec`s or ``semantic=path[:channels]`` strings; channels appear in spec
    order. `resolution` is a power-of-two side or (width, height); default `common_resolution` of
    all sources. Each file is read and resampled once however many channels it feeds. Raises
    `TextureError` (a ValueError) for missing/unreadable files or channels a file lacks, and
    `NonFiniteError` for NaN/Inf texels unless ``fix_nonfinite`` (module doc). ``names``: {path
    read: the user's name for it}, for a caller that reads copies; messages name the user's file.
    """
    specs = [TextureSpec.parse(s) if isinstance(s, str) else s for s in specs]
    if not specs:
        raise ValueError("a texture set needs at least one texture spec")
    seen: set[str] = set()
    for s in specs:
        if s.semantic != "generic" and s.semantic in seen:
            raise ValueError(f"semantic {s.semantic!r} given twice")
        seen.add(s.semantic)

    sources: dict[str, _Source] = {}
    for s in specs:
        key = os.path.realpath(s.path)
        if key not in sources:
            sources[key] = _open(s.path, (names or {}).get(s.path, s.path))
            _check_finite(sources[key], fix_nonfinite)
    # Resolve every channel before any resampling so bad selections fail fast.
    picks: list[tuple[_Source, int, Channel]] = []
    for s in specs:
        sem = SEMANTICS[s.semantic]
        src = sources[os.path.realpath(s.path)]
        for i, letter in enumerate(s.channels):
            idx = _source_index(src, letter)
            comp = "rgb"[i] if sem.kind == "color" else "xy"[i] if sem.kind == "normal" else letter
            picks.append((src, idx, Channel(sem.name, comp, sem.kind, s.path, idx, src.format)))

    if resolution is None:
        width, height = common_resolution((src.width, src.height) for src in sources.values())
    else:
        width, height = _check_resolution(resolution)

    data = np.empty((height, width, len(picks)), dtype=np.float32)
    channels = []
    for col, (src, idx, ch) in enumerate(picks):
        v = _resampled(src, width, height)[..., idx]
        v = v * 2.0 - 1.0 if ch.kind == "normal" else v.copy()
        data[..., col], ch = _value_range(v, ch, src)
        channels.append(ch)
    for src in sources.values():  # free decoded files now, not when the caller drops the set
        src.pixels = None
    return TextureSet(data, tuple(channels), width, height)


# --------------------------------------------------------------------------------------------
# mips


def build_mip_chain(data: np.ndarray) -> list[np.ndarray]:
    """Box-filtered mip chain of an (H, W[, c]) array with power-of-two sides.

    Level 0 is `data` itself; each next level averages 2x2 texels (per axis: an axis already at 1
    stays 1 and only the other is halved, i.e. 1x2 / 2x1 averages) until 1x1. Computed in float64,
    returned as float32. Box filtering matches what GPU mip generation does for power-of-two sizes.
    """
    a = np.asarray(data)
    if a.ndim not in (2, 3):
        raise ValueError(f"mip data must be (H, W) or (H, W, c), got shape {a.shape}")
    h, w = a.shape[:2]
    if not (_is_pow2(h) and _is_pow2(w)):
        raise ValueError(f"mip chain needs power-of-two sides, got {w}x{h}")
    levels = [a.astype(np.float32, copy=False)]
    cur = levels[0]  # the float64 accumulation starts at level 1: no float64 copy of level 0
    while cur.shape[0] > 1 or cur.shape[1] > 1:
        h, w = cur.shape[:2]
        fy, fx = (2 if h > 1 else 1), (2 if w > 1 else 1)
        cur = cur.reshape(h // fy, fy, w // fx, fx, *cur.shape[2:]).mean(axis=(1, 3), dtype=np.float64)
        levels.append(cur.astype(np.float32))
    return levels
