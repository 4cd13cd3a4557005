"""A DDS that a UsdUVTexture names (a layout's classic texture in OUT), read as the renderer draws
it: every stored mip decoded by bcfpipe's own decoders, rgba slots as UsdUVTexture outputs r, g, b,
a (a one- or two-channel format reads 0 in the missing colour slots and 1 in alpha, as GL's R and RG
textures do). Generic over the DXGI formats bcfpipe writes: the classic formats of
bcfpipe.formats.bcn (BC1, BC4, BC5, BC7 UNORM, and whatever else it lists), and BC6H (UF16/SF16) and
BC7 as feature layers store them.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from bcfpipe.formats import dds
from bcfpipe.formats.bcn import FORMAT_OF, decode_levels
from bcfpipe.bc6h import decode as bc6h_decode

__all__ = ["DecodedTexture", "read_dds", "is_dds"]


@dataclass(frozen=True)
class DecodedTexture:
    """Every stored mip, (h, w, 4) float32 rgba, largest first; ``unorm``: texels are k / 255
    (8-bit exact), else half floats (BC6H)."""

    levels: list[np.ndarray]
    unorm: bool
    channels: int  # channels the format stores (1 BC4, 2 BC5, 3 BC1/BC6H, 4 BC7)


def is_dds(path: str) -> bool:
    """Whether a (resolved) texture path is a DDS file (by its extension, as Hio picks a reader)."""
    return os.path.splitext(path.split("[")[0].rstrip("]"))[1].lower() == ".dds"


def _decode(tex: dds.DdsTexture) -> tuple[list[np.ndarray], bool]:
    if tex.dxgi_format in FORMAT_OF:
        levels = decode_levels(FORMAT_OF[tex.dxgi_format], tex.levels)
        return levels, "BC6H" not in tex.format_name
    if tex.dxgi_format in (dds.DXGI_FORMAT_BC6H_UF16, dds.DXGI_FORMAT_BC6H_SF16):
        return [bc6h_decode(b, w, h, signed=tex.signed).astype(np.float32) for b, w, h in tex.levels], False
    raise dds.DdsError(f"DXGI format {tex.dxgi_format} ({tex.format_name}) has no decoder here")


def read_dds(path: str | os.PathLike) -> DecodedTexture:
    """``path`` decoded; a malformed file or a format without a decoder raises a one-line DdsError."""
    tex = dds.read(path)
    levels, unorm = _decode(tex)
    channels = levels[0].shape[-1] if levels[0].ndim == 3 else 1
    out = []
    for lv in levels:
        lv = lv.reshape(*lv.shape[:2], -1).astype(np.float32)
        rgba = np.zeros((*lv.shape[:2], 4), np.float32)
        rgba[..., 3] = 1.0
        rgba[..., :lv.shape[-1]] = lv[..., :4]
        out.append(rgba)
    return DecodedTexture(out, unorm, int(channels))
