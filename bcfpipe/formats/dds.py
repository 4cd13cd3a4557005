"""DDS container for BC6H and BC7 textures, with the DX10 extended header.

Layout (Microsoft "DDS" programming guide): the magic ``DDS ``, a 124-byte
DDS_HEADER, a 20-byte DDS_HEADER_DXT10, then every mip level's blocks from the
largest down. Levels smaller than 4x4 still occupy one 16-byte block.
"""
from __future__ import annotations


import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from bcfpipe.errors import InputError
from bcfpipe.formats.atomic import atomic_write

DXGI_FORMAT_BC6H_UF16 = 95
DXGI_FORMAT_BC6H_SF16 = 96
DXGI_FORMAT_BC7_UNORM = 98
# classic textures of a layout (issue 31): 8-byte blocks for BC1 and BC4, 16 for BC5
DXGI_FORMAT_BC1_UNORM, DXGI_FORMAT_BC4_UNORM, DXGI_FORMAT_BC5_UNORM = 71, 80, 83
DXGI_NAMES = {DXGI_FORMAT_BC6H_UF16: "BC6H_UF16", DXGI_FORMAT_BC6H_SF16: "BC6H_SF16",
              DXGI_FORMAT_BC7_UNORM: "BC7_UNORM", DXGI_FORMAT_BC1_UNORM: "BC1_UNORM",
              DXGI_FORMAT_BC4_UNORM: "BC4_UNORM", DXGI_FORMAT_BC5_UNORM: "BC5_UNORM"}
_BLOCK_BYTES_OF = {DXGI_FORMAT_BC1_UNORM: 8, DXGI_FORMAT_BC4_UNORM: 8}


def block_bytes(dxgi_format: int) -> int:
    """Bytes per 4x4 block: 8 for BC1 and BC4, 16 for the others bcfpipe writes."""
    return _BLOCK_BYTES_OF.get(dxgi_format, BLOCK_BYTES)

_MAGIC = b"DDS "
_HEADER = struct.Struct("<7I44x8I4I4x")  # DDS_HEADER without reserved fields' contents
_DX10 = struct.Struct("<5I")
HEADER_BYTES = len(_MAGIC) + _HEADER.size + _DX10.size  # 148: magic + DDS_HEADER + DDS_HEADER_DXT10
# DDS_HEADER.dwFlags
DDSD_CAPS, DDSD_HEIGHT, DDSD_WIDTH = 0x1, 0x2, 0x4
DDSD_PIXELFORMAT, DDSD_MIPMAPCOUNT, DDSD_LINEARSIZE = 0x1000, 0x20000, 0x80000
# DDS_PIXELFORMAT.dwFlags and DDS_HEADER.dwCaps
DDPF_FOURCC = 0x4
DDSCAPS_COMPLEX, DDSCAPS_TEXTURE, DDSCAPS_MIPMAP = 0x8, 0x1000, 0x400000
D3D10_RESOURCE_DIMENSION_TEXTURE2D = 3
_FOURCC_DX10 = int.from_bytes(b"DX10", "little")
BLOCK_BYTES = 16

Level = tuple[np.ndarray, int, int]


class DdsError(InputError):
    """A DDS file that is not a well-formed 2D BC6H or BC7 texture."""


@dataclass(frozen=True)
class DdsTexture:
    """A BC6H or BC7 texture as read from disk: ``levels`` is [(blocks (n,16) uint8, w, h), ...]."""

    dxgi_format: int
    width: int
    height: int
    levels: list[Level]

    @property
    def signed(self) -> bool:
        return self.dxgi_format == DXGI_FORMAT_BC6H_SF16

    @property
    def is_bc7(self) -> bool:
        return self.dxgi_format == DXGI_FORMAT_BC7_UNORM

    @property
    def format_name(self) -> str:
        return DXGI_NAMES[self.dxgi_format]

    @property
    def mip_count(self) -> int:
        return len(self.levels)

    def __iter__(self) -> Iterator:
        """Unpack as ``fmt, width, height, levels = dds.read(path)``."""
        return iter((self.dxgi_format, self.width, self.height, self.levels))


def mip_dims(width: int, height: int, level: int) -> tuple[int, int]:
    """Size of mip ``level`` (each axis halves, floored, never below 1)."""
    return max(1, width >> level), max(1, height >> level)


def block_count(width: int, height: int) -> int:
    return ((width + 3) // 4) * ((height + 3) // 4)


def max_mip_count(width: int, height: int) -> int:
    return max(width, height).bit_length()


def _check_levels(levels: Sequence[Level], bb: int = BLOCK_BYTES) -> None:
    if not levels:
        raise ValueError("a DDS texture needs at least one level")
    _, w0, h0 = levels[0]
    if w0 < 1 or h0 < 1:
        raise ValueError(f"invalid texture size {w0}x{h0}")
    if len(levels) > max_mip_count(w0, h0):
        raise ValueError(f"{len(levels)} levels exceed the full chain of {max_mip_count(w0, h0)} for {w0}x{h0}")
    for k, (blocks, w, h) in enumerate(levels):
        if (w, h) != mip_dims(w0, h0, k):
            raise ValueError(f"level {k} is {w}x{h}, expected {mip_dims(w0, h0, k)} for a {w0}x{h0} chain")
        b = np.asarray(blocks)
        if b.dtype != np.uint8 or b.ndim != 2 or b.shape != (block_count(w, h), bb):
            raise ValueError(f"level {k} ({w}x{h}) needs uint8 blocks of shape ({block_count(w, h)}, {bb}), "
                             f"got {b.dtype} {b.shape}")


def encode_header(width: int, height: int, mip_count: int, signed: bool, dxgi_format: int | None = None) -> bytes:
    """The 148-byte magic + DDS_HEADER + DDS_HEADER_DXT10 for a 2D BC6H texture (``signed`` picks
    95 or 96), or of ``dxgi_format`` when given."""
    flags = DDSD_CAPS | DDSD_HEIGHT | DDSD_WIDTH | DDSD_PIXELFORMAT | DDSD_MIPMAPCOUNT | DDSD_LINEARSIZE
    caps = DDSCAPS_TEXTURE | ((DDSCAPS_COMPLEX | DDSCAPS_MIPMAP) if mip_count > 1 else 0)
    dxgi = dxgi_format if dxgi_format is not None else DXGI_FORMAT_BC6H_SF16 if signed else DXGI_FORMAT_BC6H_UF16
    linear_size = block_count(width, height) * block_bytes(dxgi)
    header = _HEADER.pack(124, flags, height, width, linear_size, 0, mip_count,
                          32, DDPF_FOURCC, _FOURCC_DX10, 0, 0, 0, 0, 0,
                          caps, 0, 0, 0)
    if dxgi not in DXGI_NAMES:
        raise ValueError(f"DXGI format {dxgi} is not one bcfpipe writes ({', '.join(map(str, DXGI_NAMES))})")
    dx10 = _DX10.pack(dxgi, D3D10_RESOURCE_DIMENSION_TEXTURE2D, 0, 1, 0)
    return _MAGIC + header + dx10


def write(path: str | os.PathLike, levels: Sequence[Level], signed: bool = False,
          dxgi_format: int | None = None) -> None:
    """Write a BC6H DDS (DXGI 95 unsigned / 96 signed), or one of ``dxgi_format`` (98: BC7_UNORM),
    with the given mip levels, largest first.

    The file is written to a temporary name and renamed, so a failure never leaves a partial file.
    """
    atomic_write(Path(path), encode(levels, signed, dxgi_format))


def encode(levels: Sequence[Level], signed: bool = False, dxgi_format: int | None = None) -> bytes:
    """The bytes of the DDS file `write` writes (header, then every level's blocks)."""
    _check_levels(levels, block_bytes(dxgi_format or DXGI_FORMAT_BC6H_UF16))
    _, w0, h0 = levels[0]
    return encode_header(w0, h0, len(levels), signed, dxgi_format) + b"".join(
        np.ascontiguousarray(b, dtype=np.uint8).tobytes() for b, _, _ in levels)


def read(path: str | os.PathLike) -> DdsTexture:
    """Read a 2D BC6H or BC7 DDS with a DX10 header; anything else raises a one-line DdsError."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise DdsError(f"{path}: cannot read ({e.strerror or e})") from None
    return parse(data, name=str(path))


def parse(data: bytes, name: str = "<bytes>") -> DdsTexture:
    """Parse DDS bytes (see :func:`read`)."""
    head = len(_MAGIC) + _HEADER.size
    if len(data) < 4 or data[:4] != _MAGIC:
        raise DdsError(f"{name}: not a DDS file (bad magic)")
    if len(data) < head:
        raise DdsError(f"{name}: truncated header ({len(data)} bytes)")
    (size, flags, height, width, _linear, depth, mips, pf_size, pf_flags, fourcc,
     *_masks, caps, caps2, _caps3, _caps4) = _HEADER.unpack_from(data, 4)
    if size != 124 or pf_size != 32:
        raise DdsError(f"{name}: inconsistent header sizes ({size}, {pf_size}); expected 124 and 32")
    if not (pf_flags & DDPF_FOURCC) or fourcc != _FOURCC_DX10:
        raise DdsError(f"{name}: no DX10 header; only BC6H (DXGI 95/96) and BC7 (98) DDS files are supported")
    if len(data) < head + _DX10.size:
        raise DdsError(f"{name}: truncated DX10 header")
    dxgi, dim, misc, array_size, _misc2 = _DX10.unpack_from(data, head)
    if dxgi not in DXGI_NAMES:
        raise DdsError(f"{name}: DXGI format {dxgi} is not one bcfpipe reads "
                       f"({', '.join(f'{v} {k}' for k, v in DXGI_NAMES.items())})")
    if dim != D3D10_RESOURCE_DIMENSION_TEXTURE2D or array_size != 1 or misc & 0x4 or caps2 & 0x200:
        raise DdsError(f"{name}: only single 2D textures are supported (dimension {dim}, "
                       f"array size {array_size}, cube {bool(misc & 0x4)})")
    if (flags & 0x800000) and depth > 1:
        raise DdsError(f"{name}: volume textures are not supported")
    if width < 1 or height < 1 or width > 1 << 16 or height > 1 << 16:
        raise DdsError(f"{name}: invalid size {width}x{height}")
    mips = mips if (flags & DDSD_MIPMAPCOUNT) and mips > 0 else 1
    if mips > max_mip_count(width, height):
        raise DdsError(f"{name}: {mips} mips exceed the {max_mip_count(width, height)} possible for {width}x{height}")
    offset = head + _DX10.size
    levels: list[Level] = []
    for k in range(mips):
        w, h = mip_dims(width, height, k)
        n = block_count(w, h) * block_bytes(dxgi)
        if offset + n > len(data):
            raise DdsError(f"{name}: truncated at mip {k} ({w}x{h}): needs {offset + n} bytes, file has {len(data)}")
        blocks = np.frombuffer(data, dtype=np.uint8, count=n, offset=offset).reshape(-1, block_bytes(dxgi)).copy()
        levels.append((blocks, w, h))
        offset += n
    if offset != len(data):
        raise DdsError(f"{name}: {len(data) - offset} unexpected trailing bytes after {mips} mips")
    return DdsTexture(dxgi, width, height, levels)
