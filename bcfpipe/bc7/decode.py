"""Bit-exact BC7 decoding of every mode: bcfpipe's trained feature levels are mode 6, and a T_0
that holds the set's principal components is encoded in any mode by ISPC (issue 29). One decoder,
`bcfpipe.bc7.kernel.bc7_image` (Khronos Data Format §"BPTC"; the reserved mode 8 decodes
to zero, as D3D11 and Mesa do); these are its views as blocks and as a float image.
"""
from __future__ import annotations

import numpy as np

__all__ = ["decode", "decode_to_u8"]


def decode_to_u8(blocks: np.ndarray) -> np.ndarray:
    """(n, 16) uint8 blocks -> (n, 16, 4) uint8 texels (row-major within each block)."""
    from bcfpipe.bc7.kernel import bc7_image  # lazy: start-up (numba)

    b = np.asarray(blocks, np.uint8).reshape(-1, 16)
    n = b.shape[0]
    return bc7_image(b, 4, 4 * n).reshape(n, 16, 4)  # one block per 4 rows


def decode(blocks: np.ndarray, width: int, height: int) -> np.ndarray:
    """Row-major blocks of a ``width`` x ``height`` image -> float32 (height, width, 4) in [0, 1]."""
    from bcfpipe.bc7.kernel import bc7_image  # lazy: start-up (numba)

    return np.divide(bc7_image(blocks, width, height), np.float32(255.0), dtype=np.float32)
