"""What a neural part can hold at the mips finer than its T_0, before any training (issue 58).

A model's features are no finer than T_0, so at a reference mip finer than T_0 it decodes from
bilinear samples of T_0-sized textures. The oracle of that mip is the reference's own mip at T_0's
size, magnified bilinearly with the material's addressing: an MLP can sharpen an edge, not restore
detail, so no prediction there is taken above the oracle by more than `ORACLE_MARGIN_DB`
(`cap`). It matters where a prediction comes from figures at another T_0 size: a mip split's
features smaller than the mip they start at (on the teapot at draft a 512² T_0 at the 1024² mip 1
measured 32.4 dB where the profile step predicted 39.6), or a smaller profile than the probe's.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from bcfpipe.export.material import sampled_texels
from bcfpipe.texset.chain import Reference
from bcfpipe.texset import encoding
from bcfpipe.texset.texture_set import Channel

ORACLE_MARGIN_DB = 1.0
SAMPLED_TEXELS = 1 << 18  # a finer mip of more texels is measured on a quarter of them


@dataclass(frozen=True)
class PerfectProbe:
    """A probe that holds all a T_0 of its ``resolutions`` can: no error at all, which every
    prediction then holds to the oracle at the mips finer than T_0. Weighed in the probe's place, it
    tells which candidates no training can bring within the floor (`bcfpipe.layout.decide`)."""

    mse_per_channel: np.ndarray  # (mips, channels) zeros
    resolutions: tuple[int, ...]


def magnified_errors(reference: Reference, t0: int, channels: Sequence[Channel], wrap,
                     sampled_above: int = SAMPLED_TEXELS) -> np.ndarray:
    """(mips, channels) errors of the reference's mip of ``t0``'s size magnified to every finer mip
    (0 at the mips no finer than it); a mip of more than ``sampled_above`` texels on one texel drawn in
    each 2×2 cell (`export.material.sampled_texels`): on the teapot and the brick within 0.07 dB of every
    texel's per channel (0.04 over all channels), at a third of the time. In one compiled pass a mip
    (`oracle_kernel`), as `texset.metrics.mse_per_channel` measures the magnified image."""
    from bcfpipe.layout.oracle_kernel import magnified_sse  # lazy: start-up (numba)

    ref, masks = reference.mips, reference.masks
    side = max(ref[0].shape[:2])
    j = max(0, (side // max(1, t0)).bit_length() - 1)  # the reference mip of T_0's size
    e = np.zeros((len(ref), len(channels)))
    picks = drawn_texels(reference.shapes[:j], sampled_above)
    gains = encoding.gains(channels)
    inv_peak2 = np.array([1.0 / c.peak ** 2 for c in channels])
    for k in range(min(j, len(ref))):
        sse, n = magnified_sse(ref[j], ref[k], picks[k], None if masks is None else masks[k], gains, wrap)
        e[k] = sse * inv_peak2 / n if n else 0.0
    return e


def drawn_texels(shapes: Sequence[tuple[int, int]], above: int = SAMPLED_TEXELS) -> tuple[np.ndarray | None, ...]:
    """`export.material.sampled_texels` of the mips ``shapes``, drawn again for each T_0 size (20 ms at
    2048²): kept for a whole fit, an 8192² reference's draw (170 MiB) raised its peak memory by as much."""
    return tuple(sampled_texels(shapes, above, most=None))  # a quarter of each large mip


def cap(errors: np.ndarray, oracle: np.ndarray) -> np.ndarray:
    """``errors`` no lower than ``oracle`` less `ORACLE_MARGIN_DB` at any (mip, channel)."""
    return np.maximum(errors, oracle * 10 ** (-ORACLE_MARGIN_DB / 10))
