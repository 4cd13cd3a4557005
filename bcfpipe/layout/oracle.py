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

from bcfpipe.layout.classic import magnify, magnify_at
from bcfpipe.texset.chain import Reference
from bcfpipe.texset.metrics import mse_per_channel
from bcfpipe.texset.texture_set import Channel

ORACLE_MARGIN_DB = 1.0
SAMPLED_TEXELS = 1 << 18  # a finer mip of more texels is measured on a quarter of them
VALUES_AT_ONCE = 1 << 24


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
    texel's per channel (0.04 over all channels), at a third of the time."""
    from bcfpipe.export.material import sampled_texels  # lazy: start-up

    ref, masks = reference.mips, reference.masks
    side = max(ref[0].shape[:2])
    j = max(0, (side // max(1, t0)).bit_length() - 1)  # the reference mip of T_0's size
    e = np.zeros((len(ref), len(channels)))
    picks = sampled_texels(reference.shapes[:j], sampled_above)
    for k in range(min(j, len(ref))):
        h, w = ref[k].shape[:2]
        mask = None if masks is None else masks[k]
        if picks[k] is None:
            for c, ch in enumerate(channels):  # one channel at a time
                up = magnify(ref[j][..., c:c + 1], h, w, wrap)
                e[k, c] = mse_per_channel([ref[k][..., c:c + 1]], [up], (ch,), None if mask is None else [mask])[0, 0]
            continue
        ys, xs = np.divmod(picks[k], w)
        keep = None if mask is None else [mask.reshape(-1)[picks[k]][:, None]]
        per = max(1, VALUES_AT_ONCE // len(picks[k]))  # channels at once: 64 MiB at most, even at 8K
        for c in range(0, len(channels), per):
            cs = slice(c, c + per)
            truth = ref[k].reshape(h * w, -1)[picks[k], cs][:, None]
            up = magnify_at(ref[j][..., cs], h, w, wrap, ys, xs)[:, None]
            e[k, cs] = mse_per_channel([truth], [up], channels[cs], keep)[0]
    return e


def cap(errors: np.ndarray, oracle: np.ndarray) -> np.ndarray:
    """``errors`` no lower than ``oracle`` less `ORACLE_MARGIN_DB` at any (mip, channel)."""
    return np.maximum(errors, oracle * 10 ** (-ORACLE_MARGIN_DB / 10))
