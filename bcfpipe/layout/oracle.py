"""What a neural part can hold at the mips finer than its T_0, before any training (issue 58).

A model's features are no finer than T_0, so at a reference mip finer than T_0 it decodes from
bilinear samples of T_0-sized textures. The oracle of that mip is the reference's own mip at T_0's
size, magnified bilinearly with the material's addressing: no training fits those mips much
better (an MLP can sharpen an edge, not restore detail), so a candidate whose oracle falls more
than `ORACLE_MARGIN_DB` below the floor at such a mip is not worth a training to explore. It only
vetoes exploring (`fit._train_next`); a first choice is trained on its own figures.
"""
from __future__ import annotations

import numpy as np

from bcfpipe.layout import choose as C
from bcfpipe.layout.classic import magnify
from bcfpipe.texset.metrics import mse_per_channel, psnr_from_mse

ORACLE_MARGIN_DB = 1.0


def oracle_shortfall(ctx, c: C.Candidate) -> float:
    """How far ``c``'s oracle falls below its floor (BC@R - slack) at its worst mip finer than its
    T_0, in dB (<= 0: none does, or no mip is finer). ``ctx``: the fit's `kinds.FitContext`."""
    from bcfpipe.config import PROFILES

    ref = ctx.reference.mips
    t0 = PROFILES[c.profile][0] if c.profile in PROFILES else ctx.probe.resolutions[0]
    side = max(ref[0].shape[:2])
    j = max(0, (side // max(1, t0)).bit_length() - 1)  # the reference mip of T_0's size
    fine = [k for k in ctx.classic.bc.use if k < j]
    if not fine or c.split:
        return 0.0
    kept = {ch for g in ctx.classic.groups if g.group.name in c.classic for ch in g.group.channels}
    cols = [ch for ch in range(ctx.ts.num_channels) if ch not in kept]
    masks = ctx.reference.masks
    e = np.array(ctx.classic.e_bc, np.float64)
    for k in fine:
        up = magnify(ref[j][..., cols], *ref[k].shape[:2], ctx.wrap)
        chans = tuple(ctx.ts.channels[ch] for ch in cols)
        e[k, cols] = mse_per_channel([ref[k][..., cols]], [up], chans, None if masks is None else [masks[k]])[0]
    slack = 0.0 if ctx.match_bc else C.SLACK_DB
    bc = ctx.classic.bc.psnr_per_mip
    return max(bc[k] - slack - psnr_from_mse(float(e[k].mean())) for k in fine)
