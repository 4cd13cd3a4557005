"""The texel content of source files, per channel: what is constant and what repeats (issue #18).

A neural decoder output is worth training only for a channel whose texels vary and that no other
modelled channel already holds:

- **constant**: every texel of the channel equals every other within the source's quantisation
  (one 8-bit step, 1/255, for integer files; one fp16 ulp at the channel's magnitude for float
  files). Its value is the channel's mean, in stored units ([0, 1] for integer files).
- **duplicate**: the channel's stored texels are identical, bit for bit and at the same size, to
  another channel's (the same image under two names, or an ORM file whose R equals its G).
  ``digest`` is the XXH3-128 of the stored samples with their size and type.
- **unread**: the texture's st is not connected, so the scene reads it at one point only: the
  value there (:func:`sample_at`) replaces the texture.

Files are read once at their stored type (OpenImageIO), packaged files through Ar.
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass

import numpy as np
import xxhash

from bcfpipe.formats import images
from bcfpipe.formats.addressing import address
from bcfpipe.formats.images import channel_index as source_channel_index
from bcfpipe.formats.vocabulary import wrap_axes
from bcfpipe.scan.sources import local_file

INTEGER_STEP = 1.0 / 255.0


@dataclass(frozen=True)
class ChannelContent:
    """One channel of one file, as stored."""

    lo: float
    hi: float
    mean: float
    digest: str
    constant: bool


def srgb_to_linear(v: float) -> float:
    """The sRGB EOTF (IEC 61966-2-1), as Hydra decodes an sRGB texture before scale and bias."""
    return v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4


def _step(arr: np.ndarray, lo: float, hi: float) -> float:
    if np.issubdtype(arr.dtype, np.integer):
        return INTEGER_STEP
    return float(np.spacing(np.float16(max(abs(lo), abs(hi)))))


def read_stored(path: str) -> tuple[np.ndarray, tuple[str, ...]]:
    """The texels of a resolved path at their stored type, (H, W, C), and its channel names; colour
    as stored (unassociated alpha), as the training loader and Hydra read it."""
    with tempfile.TemporaryDirectory() as tmp:
        im = images.read(local_file(path, tmp), unassociated_alpha=True, name=path)
    return im.pixels, im.names


def channel_contents(arr: np.ndarray) -> tuple[ChannelContent, ...]:
    """Range, mean, digest and constancy of every channel of an (H, W, C) stored image."""
    out = []
    scale = float(np.iinfo(arr.dtype).max) if np.issubdtype(arr.dtype, np.integer) else 1.0
    for c in range(arr.shape[2]):
        ch = np.ascontiguousarray(arr[..., c])
        with np.errstate(invalid="ignore"):
            lo, hi = float(ch.min()) / scale, float(ch.max()) / scale
            mean = float(ch.mean(dtype=np.float64)) / scale
        h = xxhash.xxh3_128()
        h.update(f"{ch.shape[0]}x{ch.shape[1]}:{ch.dtype.str}:".encode())
        h.update(ch.tobytes())
        finite = np.isfinite(lo) and np.isfinite(hi)
        out.append(ChannelContent(lo, hi, mean, h.hexdigest(), bool(finite and hi - lo <= _step(ch, lo, hi))))
    return tuple(out)


def content_of(path: str, letter: str, cache: dict, file_hash: str = "", facts=None) -> ChannelContent:
    """The content of the file channel that a UsdUVTexture output letter (r, g, b, a) reads,
    with the texture-set loader's channel mapping; each file is read once per ``cache``, and not
    at all when ``facts`` (a bcfpipe.cache.facts.FactsStore that outlives the run) holds the facts
    of its ``file_hash`` (XXH3-128 of its bytes)."""
    key = (path, "content")
    if key not in cache:
        facts = facts if file_hash else None
        found = facts.get(file_hash) if facts is not None else None
        if found is None:
            arr, names = read_stored(path)
            found = (channel_contents(arr), names)
            if facts is not None:
                facts.put(file_hash, *found)
        cache[key] = found
    contents, names = cache[key]
    return contents[source_channel_index(names, letter, path)]


def nonfinite_channels(path: str, cache: dict) -> list[str]:
    """Names of the channels of a file read by `content_of` (same ``cache``) that hold NaN or Inf
    texels (their range is not finite); [] for a file not read there."""
    found = cache.get((path, "content"))
    if found is None:
        return []
    contents, names = found
    return [names[i] if i < len(names) else str(i) for i, c in enumerate(contents)
            if not (np.isfinite(c.lo) and np.isfinite(c.hi))]


def sample_at(path: str, letter: str, st: tuple[float, float], wrap, cache: dict) -> float:
    """The value (stored units) that a UsdUVTexture reading ``path`` gives at one ``st``: bilinear
    between texel centres, v = 1 - t, addressed with ``wrap`` (one mode or (S, T): repeat, clamp,
    mirror; mip 0: a constant st has no footprint)."""
    key = (path, "texels")
    if key not in cache:
        cache[key] = read_stored(path)
    arr, names = cache[key]
    ch = arr[..., source_channel_index(names, letter, path)]
    scale = float(np.iinfo(ch.dtype).max) if np.issubdtype(ch.dtype, np.integer) else 1.0
    h, w = ch.shape
    x, y = st[0] * w - 0.5, (1.0 - st[1]) * h - 0.5
    x0, y0 = int(np.floor(x)), int(np.floor(y))
    fx, fy = x - x0, y - y0

    wrap_s, wrap_t = wrap_axes(wrap)

    def texel(i: int, j: int) -> float:
        return float(ch[int(address(np.int64(j), h, wrap_t)), int(address(np.int64(i), w, wrap_s))]) / scale

    top = texel(x0, y0) * (1 - fx) + texel(x0 + 1, y0) * fx
    bottom = texel(x0, y0 + 1) * (1 - fx) + texel(x0 + 1, y0 + 1) * fx
    return top * (1 - fy) + bottom * fy
