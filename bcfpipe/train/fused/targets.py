"""The training targets of the fused path: the reference's trilinear-of-bicubic lookup
(:func:`bcfpipe.texset.reference.sample_reference`, one scale per batch) as one numba pass over the
samples, without the (N, 16) tap and weight tensors torch builds. Same taps and weights; the sums
run in another order, so values agree to float rounding (the fused path is keyed apart)."""
from __future__ import annotations

import numpy as np
import torch

from bcfpipe.formats.vocabulary import Wrap
from bcfpipe.texset.reference import KEYS_A, CentreTargets, ReferencePyramid, _level_split
from bcfpipe.train.fused.kernel import _F32, nb  # numba with its cache folder set


@nb.njit(inline="always", cache=True)
def _keys(f, a, w):
    """keys_weights: cubic-convolution weights of the taps at -1, 0, 1, 2 for fraction ``f`` into ``w``."""
    f2 = f * f
    f3 = f2 * f
    w[0] = a * (f3 - _F32(2.0) * f2 + f)
    w[1] = (a + _F32(2.0)) * f3 - (a + _F32(3.0)) * f2 + _F32(1.0)
    w[2] = -(a + _F32(2.0)) * f3 + (_F32(2.0) * a + _F32(3.0)) * f2 - a * f
    w[3] = a * (f2 - f3)


@nb.njit(cache=True)
def _bicubic_into(tex, uv, repeat, t, out):
    """out = lerp(out, bicubic(tex, uv), t) when ``t`` >= 0, else out = bicubic(tex, uv)."""
    c, h, w = tex.shape
    a = _F32(KEYS_A)
    wx = np.zeros(4, np.float32)
    wy = np.zeros(4, np.float32)
    xs = np.zeros(4, np.int64)
    ys = np.zeros(4, np.int64)
    for n in range(uv.shape[0]):
        x = uv[n, 0] * _F32(w) - _F32(0.5)
        y = uv[n, 1] * _F32(h) - _F32(0.5)
        x0 = np.floor(x)
        y0 = np.floor(y)
        _keys(x - x0, a, wx)
        _keys(y - y0, a, wy)
        for k in range(4):
            xi = int(x0) - 1 + k
            yi = int(y0) - 1 + k
            if repeat:
                xs[k] = xi % w
                ys[k] = yi % h
            else:
                xs[k] = min(max(xi, 0), w - 1)
                ys[k] = min(max(yi, 0), h - 1)
        for ch in range(c):
            acc = _F32(0.0)
            for ky in range(4):
                row = _F32(0.0)
                for kx in range(4):
                    row += tex[ch, ys[ky], xs[kx]] * wx[kx]
                acc += row * wy[ky]
            if t >= 0:
                out[n, ch] = out[n, ch] + _F32(t) * (acc - out[n, ch])
            else:
                out[n, ch] = acc


def sample_reference(pyr: ReferencePyramid, uv: torch.Tensor, s: float, wrap: str) -> torch.Tensor:
    """:func:`bcfpipe.texset.reference.sample_reference` at one scale ``s`` (CPU, float32), in the
    fused kernel's backend (native: targets.cpp, the same sums vectorised)."""
    from bcfpipe.train.fused.step import default_backend

    l0, l1, t = _level_split(float(s), pyr.num_levels)
    u = uv.detach().numpy().astype(np.float32, copy=False)
    out = np.zeros((u.shape[0], pyr.num_channels), np.float32)
    repeat = wrap == Wrap.REPEAT
    if default_backend() == "native":
        from bcfpipe.train.fused import native

        native.bicubic_into(pyr.mips[l0].numpy(), u, repeat, KEYS_A, -1.0, out)
        if t > 0.0:
            native.bicubic_into(pyr.mips[l1].numpy(), u, repeat, KEYS_A, float(t), out)
        return torch.from_numpy(out)
    _bicubic_into(pyr.mips[l0].numpy(), u, repeat, -1.0, out)
    if t > 0.0:
        _bicubic_into(pyr.mips[l1].numpy(), u, repeat, float(t), out)
    return torch.from_numpy(out)


def centre_batch(centres: CentreTargets, n: int, s: float, gen: torch.Generator | None
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """:meth:`CentreTargets.batch`'s draws and values, natively where the fused kernel is native:
    without torch's (c, n) gathers and transposes, and in texel order, so the lookups and then the
    kernel's taps walk memory forwards (the same samples; only the order of the gradient's sums
    changes)."""
    from bcfpipe.train.fused.step import default_backend

    if default_backend() != "native":
        return centres.batch(n, s, gen)
    from bcfpipe.train.fused import native

    l0, t, ids = centres.draw(n, s, gen)
    up = centres.up[l0]
    ids = np.sort(ids.numpy())
    uv, target = native.centres(centres.pyr.mips[l0].numpy(), None if t <= 0.0 else up.numpy(), ids, float(t))
    return torch.from_numpy(uv), torch.from_numpy(target)
