"""The texture files a material reads (issue 51: below `content`, `density` and `texture_sets`,
which all need them): where a resolved path's bytes are (a plain file, or one inside a package),
its header facts and hash as a `SourceFile`, and the common size of a texture set's sources."""
from __future__ import annotations

import math
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import xxhash

from bcfpipe.formats.images import probe
from bcfpipe.formats.vocabulary import ColorSpace


@dataclass(frozen=True)
class SourceFile:
    """One texture file a job reads: where it is, what it hashes to, how USD decodes it."""

    path: str  # resolved (absolute, or ``package.usdz[inner]``)
    asset_path: str  # as authored
    xxh3_128: str
    size_bytes: int
    width: int
    height: int
    channels: int
    format: str  # OpenImageIO base type of the stored texels, e.g. uint8
    color_space: str  # sourceColorSpace as authored (auto/raw/sRGB)
    resolved_color_space: str  # sRGB or raw (auto resolved as Hydra does)


def package_split(path: str) -> tuple[str, str] | None:
    """``pkg.usdz[inner/a.png]`` -> (pkg.usdz, inner/a.png); None for plain files."""
    m = re.match(r"^(.*)\[([^\[\]]+)\]$", path)
    return (m.group(1), m.group(2)) if m else None


def read_asset(path: str) -> bytes:
    """The bytes of a resolved texture path (a plain file, or a file inside a package via Ar)."""
    if package_split(path) is None:
        return Path(path).read_bytes()
    from pxr import Ar  # lazy: start-up

    asset = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(path))
    if asset is None:
        raise OSError(f"cannot open {path}")
    return bytes(asset.GetBuffer())


def _nearest_pow2(n: int) -> int:
    """Nearest power of two in log scale (1280 -> 1024, 1536 -> 2048, 2832 -> 2048)."""
    return 1 << max(0, round(math.log2(n)))


def common_resolution(sizes: Iterable[tuple[int, int]]) -> tuple[int, int]:
    """The default common (width, height) of a texture set.

    Per axis independently: the largest source size, rounded to the nearest power of two in log
    scale (1280x1024 -> 1024x1024, 2048 stays 2048, 4256x2832 -> 4096x2048). Non-square sets stay
    non-square.
    """
    sizes = list(sizes)
    if not sizes:
        raise ValueError("no texture sizes given")
    return _nearest_pow2(max(w for w, _ in sizes)), _nearest_pow2(max(h for _, h in sizes))


def local_file(path: str, tmp_dir: str | os.PathLike) -> str:
    """A filesystem path with the asset's bytes: the file itself, or a copy of a packaged file."""
    pkg = package_split(path)
    if pkg is None:
        return path
    dst = Path(tmp_dir) / f"{xxhash.xxh3_64_hexdigest(path.encode())}_{Path(pkg[1]).name}"
    if not dst.exists():
        dst.write_bytes(read_asset(path))
    return str(dst)


def _probe(path: str) -> tuple[int, int, int, str]:
    """(width, height, channels, base type) from the image header; zeros when unreadable."""
    with tempfile.TemporaryDirectory() as tmp:
        found = probe(local_file(path, tmp))
    return found if found is not None else (0, 0, 0, "unreadable")


def resolved_color_space(authored: str, channels: int, fmt: str) -> str:
    """Hydra's reading of sourceColorSpace: auto is sRGB for 8-bit files with 3 or 4 channels."""
    if authored == ColorSpace.SRGB:
        return ColorSpace.SRGB
    if authored == "auto":
        return ColorSpace.SRGB if fmt == "uint8" and channels in (3, 4) else "raw"
    return "raw"


def _readable_size(path: str) -> int:
    """Byte size of an asset, after checking that it can be opened (raises OSError if not)."""
    if package_split(path) is not None:
        return len(read_asset(path))
    with open(path, "rb") as f:
        return os.fstat(f.fileno()).st_size


def source_file(path: str, asset_path: str, color_space: str, cache: dict, digest: bool = True) -> SourceFile:
    """The file's header facts; with ``digest`` also the XXH3-128 of its bytes (the build's content
    hash needs it, a scan does not: without it ``xxh3_128`` is empty and only the header is read)."""
    key = (path, digest)
    if key not in cache:
        if digest:
            data = read_asset(path)
            cache[key] = (xxhash.xxh3_128_hexdigest(data), len(data), _probe(path))
        else:
            cache[key] = ("", _readable_size(path), _probe(path))
    digest_hex, size, (w, h, c, fmt) = cache[key]
    return SourceFile(path, asset_path, digest_hex, size, w, h, c, fmt, color_space,
                      resolved_color_space(color_space, c, fmt))
