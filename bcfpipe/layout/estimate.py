"""Classic candidates estimated from a sample of their blocks (issue 58), not encoded in full.

BC1/BC4/BC5/BC6H/BC7 encode every 4×4 block on its own, so a block encodes to the same bytes in a
mosaic of blocks as in its level. A level of more than `FULL_BLOCKS` blocks is sampled on a
jittered grid: one block drawn at random in each s×s cell of blocks, s the least that keeps the
draw within `FULL_BLOCKS`; the drawn blocks are gathered into a mosaic and encoded by the encoder
and preset that ship the group (`classic.group_texels`), and the mosaic's per-channel error is
the level's estimate (a stratified sample: every region of the level weighs as its area). Smaller
levels are encoded whole, exactly. When the reference has mips above R, level 0 is encoded whole:
those mips see it magnified, and a magnified texel reads its neighbours' blocks.

`benchmarks/bench_classic_estimate.py` measures the estimate against the full encode per
candidate and mip (docs/benchmarks.md); the layout's rule (`choose.SLACK_DB`) absorbs it, and
what ships is encoded in full and measured (`bcfpipe.layout.decide`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from bcfpipe.config import DEFAULT_ENCODE, EncodePreset
from bcfpipe.layout.classic import EncodedGroup, Group, channel_errors, group_texels, magnify, usd_normals
from bcfpipe.texset.mosaic import block_grid, mosaic
from bcfpipe.texset.normals import slope_scale
from bcfpipe.texset.texture_set import TextureSet

FULL_BLOCKS = 16384  # a level of at most this many blocks (512² texels) is encoded whole
MOSAIC_COLUMNS = 64  # blocks per mosaic row
SEED = 58  # the draw is fixed: the same set estimates the same, run after run


@dataclass(frozen=True)
class BlockSample:
    """Per BC level (largest first), the (row, column) of each block drawn, or None: every block."""

    picks: tuple[np.ndarray | None, ...]

    def fraction(self, shapes: Sequence[tuple[int, int]]) -> float:
        """The share of the levels' texels the sample encodes."""
        total = sum(h * w for h, w in shapes)
        drawn = sum(h * w if p is None else 16 * len(p) for p, (h, w) in zip(self.picks, shapes))
        return drawn / max(1, total)


def draw(shapes: Sequence[tuple[int, int]], whole_first: bool = False, budget: int = FULL_BLOCKS,
         seed: int = SEED) -> BlockSample:
    """The blocks to encode of levels of (height, width) ``shapes``: a jittered grid per level
    larger than ``budget`` blocks (whole sides of 4 only), every block of the others (and of
    level 0 when ``whole_first``)."""
    rng = np.random.default_rng(seed)
    picks: list[np.ndarray | None] = []
    for j, (h, w) in enumerate(shapes):
        bh, bw = h // 4, w // 4
        if (whole_first and j == 0) or h % 4 or w % 4 or bh * bw <= budget:
            picks.append(None)
            continue
        s = int(np.ceil(np.sqrt(bh * bw / budget)))
        rows, cols = np.arange(0, bh, s), np.arange(0, bw, s)
        r0, c0 = np.meshgrid(rows, cols, indexing="ij")
        span_r = np.minimum(s, bh - r0)
        span_c = np.minimum(s, bw - c0)
        r = r0 + (rng.random(r0.shape) * span_r).astype(np.int64)
        c = c0 + (rng.random(c0.shape) * span_c).astype(np.int64)
        picks.append(np.stack([r.ravel(), c.ravel()], 1))
    return BlockSample(tuple(picks))


def gather(img: np.ndarray, pick: np.ndarray | None) -> np.ndarray:
    """The blocks ``pick`` of ``img`` ((H, W, ...) texels) side by side, `MOSAIC_COLUMNS` per row,
    the last row filled with the first block again (`mosaic_weights` leaves those out)."""
    if pick is None:
        return img
    return mosaic(block_grid(img)[pick[:, 0], pick[:, 1]], MOSAIC_COLUMNS)


def mosaic_mask(pick: np.ndarray | None, mask: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    """Which texels of a mosaic count: the drawn blocks' (not the fill), and of those the ones
    ``mask`` covers; None when every texel counts."""
    if pick is None:
        return mask
    real = np.zeros(shape, bool)
    n = len(pick)
    full_rows, rest = divmod(n, MOSAIC_COLUMNS)
    real[:full_rows * 4] = True
    real[full_rows * 4:full_rows * 4 + 4, :rest * 4] = True
    if mask is not None:
        real &= gather(mask, pick)
    return real


def estimate_errors(ts: TextureSet, groups: Sequence[Group], resolution: int, ref: Sequence[np.ndarray],
                    masks: Sequence[np.ndarray] | None = None, wrap: str = "repeat",
                    budget: int = FULL_BLOCKS, enc: EncodePreset = DEFAULT_ENCODE) -> tuple[np.ndarray, float]:
    """(mips, channels) errors of ``groups`` at ``resolution`` as `classic.channel_errors` measures
    them (0 on channels no group holds), estimated from a `draw` of their blocks; and the share of
    texels encoded; a slope normal's m is the whole level 0's, as the full encode takes it.
    ``enc``: the quality preset's encoder presets."""
    d = sum(1 for m in ref if max(m.shape[:2]) > resolution)
    src = ref[d:]
    sample = draw([m.shape[:2] for m in src], whole_first=d > 0, budget=budget)
    refs = list(ref[:d]) + [gather(m, p) for m, p in zip(src, sample.picks)]
    weights: list[np.ndarray] | None = None
    if masks is not None or any(p is not None for p in sample.picks):
        weights = [None if masks is None else masks[k] for k in range(d)]
        weights += [mosaic_mask(p, None if masks is None else masks[d + j], refs[d + j].shape[:2])
                    for j, p in enumerate(sample.picks)]
        weights = [np.ones(r.shape[:2], bool) if w is None else w for r, w in zip(refs, weights)]
    encoded = []
    for g in groups:
        levels: list = []
        m = None
        if g.slope:
            m = slope_scale(src[0][..., list(g.channels)])
        dec = group_texels(ts, g, refs[d:], levels, m, enc)
        if g.slope:  # read as a normal as `classic.encode_group` reads it
            dec = usd_normals(levels, [r.shape[:2] for r in refs], wrap, m)
        else:
            dec = [magnify(dec[0], *ref[k].shape[:2], wrap) for k in range(d)] + dec
        encoded.append(EncodedGroup(g, [], dec))
    return channel_errors(ts, encoded, refs, weights), sample.fraction([m.shape[:2] for m in src])
