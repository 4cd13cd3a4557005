"""bcfpipe's own BC1/BC4/BC5 decoders (`bcfpipe.formats.s3tc`) and its BC7 one (`own_decode_levels`),
against two independent decoders, quicktex and texture2ddecoder, texel for texel (issue 59); and
`decode_levels`, which measures through texture2ddecoder, cropped and in channels as bcfpipe's own."""
from __future__ import annotations

import numpy as np
import pytest

from bcfpipe.formats import s3tc
from bcfpipe.formats.bcn import ClassicFormat, decode_levels, own_decode_levels

quicktex = pytest.importorskip("quicktex")
t2d = pytest.importorskip("texture2ddecoder")

SIDE = 64 * 4  # a 256² image of 64x64 random blocks: every mode and index, both endpoint orders


def _blocks(n_bytes: int, seed: int) -> np.ndarray:
    b = np.random.default_rng(seed).integers(0, 256, (64 * 64, n_bytes), dtype=np.uint8)
    b[:64, :2] = b[:64, 2:4]  # equal endpoints: BC1's three-colour mode, BC4's six-value one
    return b


def _quicktex(blocks: np.ndarray, decoder, texture) -> np.ndarray:
    tex = texture.from_bytes(blocks.tobytes(), SIDE, SIDE)
    return np.frombuffer(decoder.decode(tex).tobytes(), np.uint8).reshape(SIDE, SIDE, 4)


def test_bc1_matches_quicktex_and_texture2ddecoder():
    from quicktex.s3tc.bc1 import BC1Decoder, BC1Texture

    b = _blocks(8, 1)
    ours = s3tc.to_image(s3tc.bc1_texels(b), SIDE, SIDE)
    np.testing.assert_array_equal(ours, _quicktex(b, BC1Decoder(), BC1Texture)[..., :3])
    theirs = np.frombuffer(t2d.decode_bc1(b.tobytes(), SIDE, SIDE), np.uint8).reshape(SIDE, SIDE, 4)
    np.testing.assert_array_equal(ours, theirs[..., [2, 1, 0]])  # BGRA


def test_bc4_and_bc5_match_quicktex_and_texture2ddecoder():
    from quicktex.s3tc.bc4 import BC4Decoder, BC4Texture
    from quicktex.s3tc.bc5 import BC5Decoder, BC5Texture

    b4 = _blocks(8, 2)
    ours = s3tc.to_image(s3tc.bc4_texels(b4), SIDE, SIDE)
    np.testing.assert_array_equal(ours, _quicktex(b4, BC4Decoder(0), BC4Texture)[..., 0])
    theirs = np.frombuffer(t2d.decode_bc4(b4.tobytes(), SIDE, SIDE), np.uint8).reshape(SIDE, SIDE, 4)
    np.testing.assert_array_equal(ours, theirs[..., 2])  # red of BGRA
    b5 = _blocks(16, 3)
    ours5 = s3tc.to_image(s3tc.bc5_texels(b5), SIDE, SIDE)
    np.testing.assert_array_equal(ours5, _quicktex(b5, BC5Decoder(0, 1), BC5Texture)[..., :2])
    theirs5 = np.frombuffer(t2d.decode_bc5(b5.tobytes(), SIDE, SIDE), np.uint8).reshape(SIDE, SIDE, 4)
    np.testing.assert_array_equal(ours5, theirs5[..., [2, 1]])


@pytest.mark.parametrize("fmt, n_bytes", [(ClassicFormat.BC1, 8), (ClassicFormat.BC4, 8), (ClassicFormat.BC5, 16),
                                          (ClassicFormat.BC7, 16)])
@pytest.mark.parametrize("decode", [decode_levels, own_decode_levels], ids=["t2d", "own"])
def test_decode_levels_crops_a_padded_level_as_the_oracle_does(fmt, n_bytes, decode):
    """A 6x5 level (2x2 blocks, padded) and a 1x1 one, as texture2ddecoder decodes the padded blocks."""
    rng = np.random.default_rng(4)
    levels = [(rng.integers(0, 256, (4, n_bytes), dtype=np.uint8), 6, 5),
              (rng.integers(0, 256, (1, n_bytes), dtype=np.uint8), 1, 1)]
    got = decode(fmt, levels)
    name, cols = {ClassicFormat.BC1: ("decode_bc1", [2, 1, 0]), ClassicFormat.BC4: ("decode_bc4", [2]),
                  ClassicFormat.BC5: ("decode_bc5", [2, 1]), ClassicFormat.BC7: ("decode_bc7", [2, 1, 0, 3])}[fmt]
    for (blocks, w, h), g in zip(levels, got):
        pw, ph = -(-w // 4) * 4, -(-h // 4) * 4
        ref = np.frombuffer(getattr(t2d, name)(blocks.tobytes(), pw, ph), np.uint8).reshape(ph, pw, 4)
        np.testing.assert_array_equal(g, ref[:h, :w, cols].astype(np.float32) / 255.0)
