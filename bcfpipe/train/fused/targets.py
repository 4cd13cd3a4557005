"""The training targets of the fused path: the reference's trilinear-of-bicubic lookup
(:func:`bcfpipe.texset.reference.sample_reference`, one scale per batch) as one pass over the
samples (targets.cpp, or numba in kernel.py), without the (N, 16) tap and weight tensors torch
builds. Same taps and weights; the sums run in another order, so values agree to float rounding
(the fused path is keyed apart); the texel-centre batches are bit-identical."""
from __future__ import annotations

import numpy as np
import torch

from bcfpipe.train.fused import native
from bcfpipe.train.fused.common import wrap_code
from bcfpipe.texset.reference import KEYS_A, CentreTargets, ReferencePyramid, level_split
from bcfpipe.train.fused.step import default_backend


def sample_reference(pyr: ReferencePyramid, uv: torch.Tensor, s: float, wrap: str) -> torch.Tensor:
    """:func:`bcfpipe.texset.reference.sample_reference` at one scale ``s`` (CPU, float32), in the
    fused kernel's backend (native: targets.cpp, the same sums vectorised)."""
    l0, l1, t = level_split(float(s), pyr.num_levels)
    u = uv.detach().numpy().astype(np.float32, copy=False)
    out = np.zeros((u.shape[0], pyr.num_channels), np.float32)
    code = wrap_code(wrap)
    if default_backend() == "native":
        native.bicubic_into(pyr.mips[l0].numpy(), u, code, KEYS_A, -1.0, out)
        if t > 0.0:
            native.bicubic_into(pyr.mips[l1].numpy(), u, code, KEYS_A, float(t), out)
        return torch.from_numpy(out)
    from bcfpipe.train.fused.kernel import bicubic_into, uncached  # lazy: start-up

    uncached(lambda: bicubic_into(pyr.mips[l0].numpy(), u, code, -1.0, out))
    if t > 0.0:
        uncached(lambda: bicubic_into(pyr.mips[l1].numpy(), u, code, float(t), out))
    return torch.from_numpy(out)


def bicubic(tex: torch.Tensor, uv: torch.Tensor, wrap: str) -> torch.Tensor:
    """reference.bicubic_sample's (N, c) lookup of one level (CPU, float32) in targets.cpp: the same taps
    and weights, summed in another order (CentreTargets' precomputed images, natively)."""
    out = np.zeros((uv.shape[0], tex.shape[0]), np.float32)
    native.bicubic_into(tex.numpy(), uv.detach().numpy().astype(np.float32, copy=False), wrap_code(wrap), KEYS_A,
                        -1.0, out)
    return torch.from_numpy(out)


def centre_batch(centres: CentreTargets, n: int, s: float, gen: torch.Generator | None
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """:meth:`CentreTargets.batch`'s draws and values, natively where the fused kernel is native:
    without torch's (c, n) gathers and transposes, and in texel order, so the lookups and then the
    kernel's taps walk memory forwards (the same samples; only the order of the gradient's sums
    changes)."""
    if default_backend() != "native":
        return centres.batch(n, s, gen)

    l0, t, ids = centres.draw(n, s, gen)
    up, rows = centres.up[l0], centres.texels[l0]
    ids = np.sort(ids.numpy())
    if centres.lazy[l0]:  # B_k+1 looked up at these centres, then lerped as a precomputed level's
        mip = centres.pyr.mips[l0].numpy()
        uv, a = native.centres(mip, None, ids, 0.0)
        if t <= 0.0:
            return torch.from_numpy(uv), torch.from_numpy(a)
        both = np.concatenate([a, centres.up_at(l0, torch.from_numpy(ids)).numpy()], 1)
        _, target = native.centre_rows(both, 1, len(ids), np.arange(len(ids)), float(t))
        return torch.from_numpy(uv), torch.from_numpy(target)
    if rows is not None:
        _, h, w = centres.pyr.mips[l0].shape
        uv, target = native.centre_rows(rows.numpy(), h, w, ids, float(t))
    else:
        uv, target = native.centres(centres.pyr.mips[l0].numpy(), None if t <= 0.0 else up.numpy(), ids, float(t))
    return torch.from_numpy(uv), torch.from_numpy(target)
