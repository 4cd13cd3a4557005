"""BC6H mode 10's quick encode (one shape refined) in C++: ``quick.cpp``, built into the fused
training kernel's library (bcfpipe.train.fused.native, which hands it in: the codec sits below the
trainer). The trainer's first encode runs it; it gives
:func:`bcfpipe.bc6h.encode.encode_params` ``(refine_top=1, keep=1)``'s result up to the order of a
few float32 sums, in a fraction of its time (15 s at 2k in torch)."""
from __future__ import annotations

import functools

import numpy as np


@functools.lru_cache(maxsize=2)
def _tables(signed: bool):
    """encode.py's tables for ``signed``: endpoint values, palette rows, weights, shapes."""
    import torch  # lazy: start-up

    from bcfpipe.bc6h.encode import EncodeContext  # lazy: start-up

    ctx = EncodeContext(signed, torch.device("cpu"))
    return (np.ascontiguousarray(ctx.u.numpy(), np.float32), np.ascontiguousarray(ctx.pal_rows.numpy(), np.float32),
            np.ascontiguousarray(ctx.w3.numpy(), np.float32), np.ascontiguousarray(ctx.part.numpy(), np.int32))


def encode_params(texels, signed: bool, lib, *, rounds: int = 1, window: int = 1):
    """Mode-10 parameters of an (H, W, 3) float image, as encode.encode_params returns them
    (endpoints (n, 4, 3), indices (n, 16), shapes (n,), int64, blocks row-major) with one shape
    refined, by ``lib``'s bcf_bc6h_quick (a ctypes library with quick.cpp built in)."""
    from bcfpipe.bc6h.encode import validate_texels, blocks_from_image  # lazy: start-up

    blocks = np.ascontiguousarray(blocks_from_image(validate_texels(texels)), np.float32)
    n = blocks.shape[0]
    e, idx, part = np.empty((n, 4, 3), np.int64), np.empty((n, 16), np.int64), np.empty(n, np.int64)
    u, pal, w3, shapes = _tables(bool(signed))
    lib.bcf_bc6h_quick(blocks.ctypes.data, n, int(signed), int(rounds), int(min(max(window, 0), 31)), u.ctypes.data,
                       pal.ctypes.data, w3.ctypes.data, shapes.ctypes.data, e.ctypes.data, idx.ctypes.data,
                       part.ctypes.data)
    return e, idx, part
