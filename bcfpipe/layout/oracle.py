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

from bcfpipe.layout.classic import magnify
from bcfpipe.texset.chain import Reference
from bcfpipe.texset.metrics import mse_per_channel
from bcfpipe.texset.texture_set import Channel

ORACLE_MARGIN_DB = 1.0


@dataclass(frozen=True)
class PerfectProbe:
    """A probe that holds all a T_0 of its ``resolutions`` can: no error at all, which every
    prediction then holds to the oracle at the mips finer than T_0. Weighed in the probe's place, it
    tells which candidates no training can bring within the floor (`bcfpipe.layout.fit`)."""

    mse_per_channel: np.ndarray  # (mips, channels) zeros
    resolutions: tuple[int, ...]


def magnified_errors(reference: Reference, t0: int, channels: Sequence[Channel], wrap) -> np.ndarray:
    """(mips, channels) errors of the reference's mip of ``t0``'s size magnified to every finer mip
    (0 at the mips no finer than it)."""
    ref, masks = reference.mips, reference.masks
    side = max(ref[0].shape[:2])
    j = max(0, (side // max(1, t0)).bit_length() - 1)  # the reference mip of T_0's size
    e = np.zeros((len(ref), len(channels)))
    for k in range(min(j, len(ref))):
        for c, ch in enumerate(channels):  # one channel magnified at a time: an 8K mip is 256 MiB each
            up = magnify(ref[j][..., c:c + 1], *ref[k].shape[:2], wrap)
            e[k, c] = mse_per_channel([ref[k][..., c:c + 1]], [up], (ch,), None if masks is None else [masks[k]])[0, 0]
    return e


def cap(errors: np.ndarray, oracle: np.ndarray) -> np.ndarray:
    """``errors`` no lower than ``oracle`` less `ORACLE_MARGIN_DB` at any (mip, channel)."""
    return np.maximum(errors, oracle * 10 ** (-ORACLE_MARGIN_DB / 10))
