"""The classic BC formats a layout ships beside the feature textures (issue 31): BC1, BC4 and BC5
as BC@R has them, BC6H (UF16) for an HDR colour group, and BC7 for groups repacked at equal bytes;
their DXGI codes, block sizes, and bcfpipe's own decoder of each (`bcfpipe.formats.s3tc` for
BC1/BC4/BC5, bcfpipe.bc7 and bcfpipe.bc6h; quicktex and texture2ddecoder are the tests' oracles,
and `bcfpipe verify` checks what ships against OpenImageIO). BC1/BC4/BC5/BC7 texels
are UNORM in [0, 1], BC1 in four-colour mode as bcfpipe encodes it; BC6H texels are unsigned half
floats, the source's linear values as they are (what a UsdUVTexture reads from a float texture).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from bcfpipe.bc7.decode import decode as bc7_decode
from bcfpipe.formats import s3tc
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


# texture2ddecoder's BGRA planes that hold each format's channels (its decode is bit for bit bcfpipe's own)
_T2D = {ClassicFormat.BC1: ("decode_bc1", [2, 1, 0]), ClassicFormat.BC4: ("decode_bc4", [2]),
        ClassicFormat.BC5: ("decode_bc5", [2, 1]), ClassicFormat.BC7: ("decode_bc7", [2, 1, 0, 3])}


def decode_levels(fmt: ClassicFormat, levels: Sequence[tuple[np.ndarray, int, int]]) -> list[np.ndarray]:
    """Blocks -> stored texels, (h, w, channels) float32 per level, UNORM in [0, 1]. BC1/BC4/BC5/BC7
    through texture2ddecoder, which decodes them bit for bit as bcfpipe's own decoders do
    (`own_decode_levels`: tests/test_s3tc.py and `bcfpipe verify` hold the two to it) in an eighth
    of the time; BC6H through bcfpipe.bc6h (texture2ddecoder misreads its mode 2)."""
    if fmt == ClassicFormat.BC6H:
        return own_decode_levels(fmt, levels)
    import texture2ddecoder as t2d  # lazy: start-up

    name, cols = _T2D[fmt]
    out = []
    for blocks, w, h in levels:
        pw, ph = -(-w // 4) * 4, -(-h // 4) * 4
        bgra = np.frombuffer(getattr(t2d, name)(np.ascontiguousarray(blocks).tobytes(), pw, ph), np.uint8)
        out.append(np.ascontiguousarray(bgra.reshape(ph, pw, 4)[:h, :w, cols], np.float32) / 255.0)
    return out


def own_decode_levels(fmt: ClassicFormat, levels: Sequence[tuple[np.ndarray, int, int]]) -> list[np.ndarray]:
    """`decode_levels` through bcfpipe's own decoders (`bcfpipe.formats.s3tc`, `bcfpipe.bc7`,
    `bcfpipe.bc6h`): the one `bcfpipe verify` holds texture2ddecoder and OpenImageIO to."""
    if fmt == ClassicFormat.BC6H:
        from bcfpipe.bc6h import decode  # lazy: start-up

        return [decode(blocks, w, h, signed=False).astype(np.float32) for blocks, w, h in levels]
    if fmt == ClassicFormat.BC7:
        return [bc7_decode(blocks, w, h) for blocks, w, h in levels]
    texels = {ClassicFormat.BC1: s3tc.bc1_texels, ClassicFormat.BC4: s3tc.bc4_texels,
              ClassicFormat.BC5: s3tc.bc5_texels}[fmt]
    out = []
    for blocks, w, h in levels:
        img = s3tc.to_image(texels(blocks), w, h)
        out.append((img if img.ndim == 3 else img[..., None]).astype(np.float32) / 255.0)
    return out
