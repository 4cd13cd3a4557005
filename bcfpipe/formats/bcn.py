"""The classic BC formats a layout ships beside the feature textures (issue 31): BC1, BC4 and BC5
as BC@R has them, and BC7 for groups repacked at equal bytes; their DXGI codes, and a decoder
(quicktex for BC1/BC4/BC5, texture2ddecoder for BC7; `bcfpipe verify` checks both against
OpenImageIO). Texels are UNORM in [0, 1]; BC1 in four-colour mode, as bcfpipe encodes it.
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
    BC7 = "bc7"


# DXGI_FORMAT values (dxgiformat.h); bcfpipe.formats.dds names them and knows their block sizes
DXGI = {ClassicFormat.BC1: 71, ClassicFormat.BC4: 80, ClassicFormat.BC5: 83, ClassicFormat.BC7: 98}
FORMAT_OF = {code: fmt for fmt, code in DXGI.items()}


def decode_levels(fmt: ClassicFormat, levels: Sequence[tuple[np.ndarray, int, int]]) -> list[np.ndarray]:
    """Blocks -> stored texels t in [0, 1], (h, w, channels) per level, through quicktex's decoders
    (BC7: texture2ddecoder's)."""
    if fmt == ClassicFormat.BC7:
        return [_decode_bc7(blocks, w, h) for blocks, w, h in levels]
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
