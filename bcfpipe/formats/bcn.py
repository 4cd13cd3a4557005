"""The classic BC formats a layout ships beside the feature textures (issue 31): BC1, BC4 and BC5
as BC@R has them, BC6H (UF16) for an HDR colour group, and BC7 for groups repacked at equal bytes;
their DXGI codes, block sizes, and bcfpipe's one decoder of each (`decode_levels`: BC1/BC4/BC5 in
`bcfpipe.formats.s3tc`, BC7 in bcfpipe.bc7, BC6H in bcfpipe.bc6h); quicktex and texture2ddecoder
are the tests' oracles, and `bcfpipe verify` holds what ships to OpenImageIO and texture2ddecoder.
BC1/BC4/BC5/BC7 texels are UNORM in [0, 1], BC1 in four-colour mode as bcfpipe encodes it; BC6H
texels are unsigned half floats, the source's linear values as they are (what a UsdUVTexture reads
from a float texture).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from bcfpipe.formats.vocabulary import StrEnum
from bcfpipe.bc6h import decode as bc6h_decode


class ClassicFormat(StrEnum):
    """Block formats of a classic group (DXGI names in `DXGI`)."""

    BC1 = "bc1"
    BC4 = "bc4"
    BC5 = "bc5"
    BC6H = "bc6h"  # BC6H_UF16: a float colour beyond 1, linear
    BC7 = "bc7"


# DXGI_FORMAT values (dxgiformat.h); bcfpipe.formats.dds names them and knows their block sizes
DXGI = {ClassicFormat.BC1: 71, ClassicFormat.BC4: 80, ClassicFormat.BC5: 83, ClassicFormat.BC6H: 95,
        ClassicFormat.BC7: 98}
FORMAT_OF = {code: fmt for fmt, code in DXGI.items()}
BLOCK_BYTES = {ClassicFormat.BC1: 8, ClassicFormat.BC4: 8, ClassicFormat.BC5: 16, ClassicFormat.BC6H: 16,
               ClassicFormat.BC7: 16}


def decode_levels(fmt: ClassicFormat, levels: Sequence[tuple[np.ndarray, int, int]]) -> list[np.ndarray]:
    """Blocks -> stored texels, (h, w, channels) float32 per level, UNORM in [0, 1] (BC1 3 channels,
    BC4 1, BC5 2, BC7 4): BC1/BC4/BC5 by `bcfpipe.formats.s3tc`, BC7 by `bcfpipe.bc7.kernel` (which
    tests/test_s3tc.py holds to quicktex and texture2ddecoder bit for bit), BC6H by bcfpipe.bc6h
    (linear half-float values)."""
    if fmt == ClassicFormat.BC6H:
        return [bc6h_decode(blocks, w, h, signed=False).astype(np.float32) for blocks, w, h in levels]
    image = unorm_decoder(fmt)
    return [np.divide(image(blocks, w, h), np.float32(255.0), dtype=np.float32) for blocks, w, h in levels]


def unorm_decoder(fmt: ClassicFormat):
    """bcfpipe's decoder of a UNORM format (BC1, BC4, BC5, BC7): (blocks, width, height) -> the
    cropped (height, width, channels) uint8 image."""
    from bcfpipe.bc7.kernel import bc7_image  # lazy: start-up (numba)
    from bcfpipe.formats import s3tc  # lazy: start-up (numba)

    return {ClassicFormat.BC1: s3tc.bc1_image, ClassicFormat.BC4: s3tc.bc4_image, ClassicFormat.BC5: s3tc.bc5_image,
            ClassicFormat.BC7: bc7_image}[ClassicFormat(fmt)]
