"""The fixed words of the file contract, as named values: what a material became, what the scan
decided, whether the cache had it, how a texture is addressed, how its texels are encoded.

Each is a `StrEnum`, so its members are the strings the JSON files and the USD layer hold (they
compare, hash and serialise as those strings) while the code names them.
"""
from __future__ import annotations

from enum import Enum

try:
    from enum import StrEnum
except ImportError:  # Python 3.10
    class StrEnum(str, Enum):  # type: ignore[no-redef]
        def __str__(self) -> str:
            return str(self.value)

__all__ = ["StrEnum", "Status", "Decision", "CacheUse", "Wrap", "wrap_axes", "wrap_name", "ColorSpace", "FeatureFormat", "T0", "Kernel", "Source", "Layout"]


class Status(StrEnum):
    """What became of a material in a build (manifest.json, the --json report)."""

    BUILT = "built"
    CONSTANT = "constant"
    FAILED = "failed"
    SKIPPED = "skipped"


class Decision(StrEnum):
    """What the scan and the plan decided for a material."""

    MODEL = "model"
    CONSTANT = "constant"
    SKIP = "skip"


class CacheUse(StrEnum):
    """Whether a job's trained files came from the cache."""

    HIT = "hit"
    MISS = "miss"


class Wrap(StrEnum):
    """Texture addressing of one axis, as UsdUVTexture's wrapS / wrapT say it: what the model is
    trained for and the runtime samples with (GL_REPEAT, GL_CLAMP_TO_EDGE, GL_MIRRORED_REPEAT)."""

    REPEAT = "repeat"
    CLAMP = "clamp"
    MIRROR = "mirror"


def wrap_axes(wrap) -> tuple[Wrap, Wrap]:
    """(S, T) of an addressing given as one mode for both axes ("clamp") or as a pair: the one
    reading every sampler uses, so a plain mode and a per-axis pair (from JSON, a list) both work."""
    pair = (wrap, wrap) if isinstance(wrap, str) else tuple(wrap)
    if len(pair) != 2:
        raise ValueError(f"addressing {wrap!r} is neither one mode nor an (S, T) pair")
    try:
        return Wrap(pair[0]), Wrap(pair[1])
    except ValueError:
        raise ValueError(f"unknown addressing {wrap!r}; choose repeat, clamp or mirror per axis") from None


def wrap_name(wrap) -> str:
    """An addressing as a person reads it: "clamp" when both axes agree, else "clamp S, repeat T"."""
    s, t = wrap_axes(wrap)
    return str(s) if s == t else f"{s} S, {t} T"


class ColorSpace(StrEnum):
    """A UsdUVTexture's sourceColorSpace: as authored (auto, raw, sRGB), resolved to raw or sRGB."""

    AUTO = "auto"
    RAW = "raw"
    SRGB = "sRGB"


class FeatureFormat(StrEnum):
    """How the feature textures T_i are block-compressed: BC6H mode 11110, three channels each
    (the paper's), or BC7, four channels each in the same bytes (issue 29; the default): trained
    layers in mode 6, a fixed T_0 in any mode (`T0`)."""

    BC6H = "bc6h"
    BC7 = "bc7"


class T0(StrEnum):
    """What the finest feature layer T_0 holds: features trained like the others (the paper's), or
    the texture set's principal components, BC7-encoded once in every mode and kept fixed while the
    other layers and the MLP train around them (BC7 only; issue 29, bcfpipe.train.fixed_t0)."""

    TRAINED = "trained"
    PCA = "pca"


class Kernel(StrEnum):
    """How a training step runs (issue 30): torch's ops (the reference, and the only one on CUDA),
    one fused kernel (bcfpipe.train.fused: C++, or numba without a compiler; CPU only), or auto:
    fused on the CPU, torch on CUDA."""

    AUTO = "auto"
    TORCH = "torch"
    FUSED = "fused"

    def on(self, device: str) -> "Kernel":
        """The kernel this choice runs on ``device`` (auto resolved)."""
        if self is Kernel.AUTO:
            return Kernel.FUSED if str(device).startswith("cpu") else Kernel.TORCH
        return self


class Source(StrEnum):
    """Where a material.json output's value comes from (issue 31's layouts)."""

    MLP = "mlp"
    CLASSIC = "classic"
    SPLIT = "split"  # a classic texture below MaterialFile.split, the MLP from it on


class Layout(StrEnum):
    """How a material's outputs are split between neural features and classic BC textures
    (``--layout``, issue 31): all neural, or chosen per material by rate and per-mip distortion."""

    NEURAL = "neural"
    AUTO = "auto"
