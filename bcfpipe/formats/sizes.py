"""The bytes of a neural material's files, known before they are written: its four feature
textures (DDS files of 16-byte 4×4 blocks, every mip down to 4×4: `dds`) and its fp16 weight
record (`weights.record_size`), and a classic texture's (`texture_bytes`). The one byte estimator (issue 51): `scan` reports it, rate control
orders its settings by the feature blocks, and the layout rule sizes profiles and mip splits by
it. `neural_bytes` is what the export writes, byte for byte (tests/test_sizes.py checks a build).

Feature sides are powers of two, at least 4 (every profile's, `config.scaled_profile`'s and a mip
split's), so a level of side s holds s² bytes.
"""
from __future__ import annotations

from typing import Sequence

from bcfpipe.formats import dds, weights
from bcfpipe.formats.bcn import BLOCK_BYTES, ClassicFormat

__all__ = ["DISK_ZSTD_LEVEL", "disk_bytes", "MIN_SIDE", "feature_levels", "feature_bytes", "neural_bytes", "texture_bytes", "widened", "widened_inputs"]

MIN_SIDE = 4  # the smallest feature mip: one block (config.MIN_LEVEL)
DISK_ZSTD_LEVEL = 19  # how games ship BC textures on disk: the GPU's blocks, zstd-compressed


def disk_bytes(blobs) -> int:
    """Bytes on disk of files whose contents are ``blobs`` (bytes or buffers), each compressed on its
    own by zstd at `DISK_ZSTD_LEVEL`, with no dictionary (issue 52: sizes are given twice, as GPU
    bytes, which the layout rule judges, and as these)."""
    import zstandard  # lazy: start-up

    z = zstandard.ZstdCompressor(level=DISK_ZSTD_LEVEL)
    return sum(len(z.compress(bytes(memoryview(b).cast("B")))) for b in blobs)


def feature_levels(side: int) -> tuple[int, ...]:
    """The mip sides of a feature texture whose level 0 is ``side``: halved down to 4
    (`config.mip_count` levels; one for a side of 4)."""
    out = [side]
    while out[-1] // 2 >= MIN_SIDE:
        out.append(out[-1] // 2)
    return tuple(out)


def feature_bytes(resolutions: Sequence[int], headers: bool = False) -> int:
    """Bytes of the feature textures of sides ``resolutions`` (T_0..T_3): every mip's blocks, with
    each file's DDS header when ``headers``."""
    blocks = sum(dds.block_count(s, s) * dds.BLOCK_BYTES for r in resolutions for s in feature_levels(r))
    return blocks + (dds.HEADER_BYTES * len(resolutions) if headers else 0)


def neural_bytes(resolutions: Sequence[int], n_in: int, hidden: int, n_out: int,
                 version: int = weights.RECORD_VERSION) -> int:
    """A neural material's bytes as the export writes them and the manifest counts them: its DDS
    files and its ``n_in``-``hidden``-``n_out`` weight record (n_in 12 for BC6H features, 16 for
    BC7; ``version`` 2 when a channel is HDR, which a scan cannot know before decoding)."""
    halves = weights.record_halves(n_in, hidden, n_out, version)
    return feature_bytes(resolutions, headers=True) + weights.record_size(halves)


def widened(resolutions: Sequence[int], t0_layers: int = 1) -> tuple[int, ...]:
    """The feature sides of a model whose T_0 holds ``t0_layers`` layers (issue 52): T_0's side that
    many times, then T_1..T_3 (`config.ModelConfig.layer_resolutions`)."""
    return (resolutions[0],) * t0_layers + tuple(resolutions[1:])


def widened_inputs(n_in: int, t0_layers: int = 1, n_layers: int = 4) -> int:
    """The MLP inputs of that model, from ``n_in`` of its ``n_layers``-layer profile: 4 (BC7) or 3
    (BC6H) more per T_0 layer past the first."""
    return n_in + n_in // n_layers * (t0_layers - 1)


def texture_bytes(fmt, levels: Sequence[tuple[int, int]]) -> int:
    """One classic DDS file's bytes (a `bcn.ClassicFormat` or its name): header and every level's
    4×4 blocks, ``levels`` as (width, height)."""
    bb = BLOCK_BYTES[ClassicFormat(fmt)]
    return dds.HEADER_BYTES + sum(dds.block_count(w, h) * bb for w, h in levels)
