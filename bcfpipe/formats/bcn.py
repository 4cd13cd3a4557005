"""The classic BC formats a layout ships beside the feature textures (issue 31): BC1, BC4 and BC5
as BC@R has them, BC6H (UF16) for an HDR colour group, and BC7 for groups repacked at equal bytes;
their DXGI codes, block sizes, and a decoder (quicktex for BC1/BC4/BC5, texture2ddecoder for BC7,
bcfpipe.bc6h for BC6H; `bcfpipe verify` checks them against OpenImageIO). BC1/BC4/BC5/BC7 texels
are UNORM in [0, 1], BC1 in four-colour mode as bcfpipe encodes it; BC6H texels are unsigned half
floats, the source's linear values as they are (what a UsdUVTexture reads from a float texture).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from bcfpipe.formats.vocabulary import StrEnum


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
    """Blocks -> stored texels, (h, w, channels) float32 per level: UNORM in [0, 1] through
    quicktex's decoders (BC7: texture2ddecoder's), BC6H's half floats through bcfpipe.bc6h's."""
    if fmt == ClassicFormat.BC7:
        return [_decode_bc7(blocks, w, h) for blocks, w, h in levels]
    if fmt == ClassicFormat.BC6H:
        from bcfpipe.bc6h import decode

        return [decode(blocks, w, h, signed=False).astype(np.float32) for blocks, w, h in levels]
    import quicktex
    from quicktex.s3tc.bc1 import BC1Decoder
    from quicktex.s3tc.bc4 import BC4Decoder
    from quicktex.s3tc.bc5 import BC5Decoder

    dec, cls, n = {ClassicFormat.BC1: (BC1Decoder(), quicktex.s3tc.bc1.BC1Texture, 3),
                   ClassicFormat.BC4: (BC4Decoder(0), quicktex.s3tc.bc4.BC4Texture, 1),
                   ClassicFormat.BC5: (BC5Decoder(0, 1), quicktex.s3tc.bc5.BC5Texture, 2)}[fmt]
    out = []
    for blocks, w, h in levels:
        pw, ph = (w + 3) // 4 * 4, (h + 3) // 4 * 4
        tex = cls.from_bytes(np.ascontiguousarray(blocks).tobytes(), pw, ph)
        px = np.frombuffer(dec.decode(tex).tobytes(), np.uint8).reshape(ph, pw, 4)
        out.append(px[:h, :w, :n].astype(np.float32) / 255.0)
    return out


def _decode_bc7(blocks: np.ndarray, width: int, height: int) -> np.ndarray:
    import texture2ddecoder

    pw, ph = (width + 3) // 4 * 4, (height + 3) // 4 * 4
    px = np.frombuffer(texture2ddecoder.decode_bc7(np.ascontiguousarray(blocks).tobytes(), pw, ph),
                       np.uint8).reshape(ph, pw, 4)
    return px[:height, :width, [2, 1, 0, 3]].astype(np.float32) / 255.0  # BGRA -> RGBA
