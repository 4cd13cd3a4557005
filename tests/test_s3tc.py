"""bcfpipe's one decoder of each BC format it ships besides BC6H (BC1/BC4/BC5 in
`bcfpipe.formats.s3tc`, BC7 in `bcfpipe.bc7.kernel`; issue 59) against two independent decoders,
quicktex (BC1/BC4/BC5) and texture2ddecoder (all four), texel for texel: random blocks of every
format and BC7 mode, odd level sizes and an image encoded by bcfpipe's encoders; `decode_levels`,
cropped and in channels as texture2ddecoder; and the compiled decoders with an unwritable cache."""
from __future__ import annotations

import numpy as np
import pytest

from bcfpipe.bc7 import anymode
from bcfpipe.formats import s3tc
from bcfpipe.formats.bcn import ClassicFormat, decode_levels, unorm_decoder

quicktex = pytest.importorskip("quicktex")
t2d = pytest.importorskip("texture2ddecoder")

SIDE = 64 * 4  # a 256² image of 64x64 random blocks: every mode and index, both endpoint orders
# texture2ddecoder's decoder of each format and the planes of its BGRA output that hold the format's channels
T2D = {ClassicFormat.BC1: ("decode_bc1", [2, 1, 0]), ClassicFormat.BC4: ("decode_bc4", [2]),
       ClassicFormat.BC5: ("decode_bc5", [2, 1]), ClassicFormat.BC7: ("decode_bc7", [2, 1, 0, 3])}
FORMATS = [(ClassicFormat.BC1, 8), (ClassicFormat.BC4, 8), (ClassicFormat.BC5, 16), (ClassicFormat.BC7, 16)]


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
    ours = s3tc.bc1_image(b, SIDE, SIDE)
    np.testing.assert_array_equal(ours, _quicktex(b, BC1Decoder(), BC1Texture)[..., :3])
    theirs = np.frombuffer(t2d.decode_bc1(b.tobytes(), SIDE, SIDE), np.uint8).reshape(SIDE, SIDE, 4)
    np.testing.assert_array_equal(ours, theirs[..., [2, 1, 0]])  # BGRA


def test_bc4_and_bc5_match_quicktex_and_texture2ddecoder():
    from quicktex.s3tc.bc4 import BC4Decoder, BC4Texture
    from quicktex.s3tc.bc5 import BC5Decoder, BC5Texture

    b4 = _blocks(8, 2)
    ours = s3tc.bc4_image(b4, SIDE, SIDE)[..., 0]
    np.testing.assert_array_equal(ours, _quicktex(b4, BC4Decoder(0), BC4Texture)[..., 0])
    theirs = np.frombuffer(t2d.decode_bc4(b4.tobytes(), SIDE, SIDE), np.uint8).reshape(SIDE, SIDE, 4)
    np.testing.assert_array_equal(ours, theirs[..., 2])  # red of BGRA
    b5 = _blocks(16, 3)
    ours5 = s3tc.bc5_image(b5, SIDE, SIDE)
    np.testing.assert_array_equal(ours5, _quicktex(b5, BC5Decoder(0, 1), BC5Texture)[..., :2])
    theirs5 = np.frombuffer(t2d.decode_bc5(b5.tobytes(), SIDE, SIDE), np.uint8).reshape(SIDE, SIDE, 4)
    np.testing.assert_array_equal(ours5, theirs5[..., [2, 1]])


@pytest.mark.parametrize("fmt, n_bytes", FORMATS)
def test_decode_levels_crops_a_padded_level_as_the_oracle_does(fmt, n_bytes):
    """A 6x5 level (2x2 blocks, padded) and a 1x1 one, as texture2ddecoder decodes the padded blocks."""
    rng = np.random.default_rng(4)
    levels = [(rng.integers(0, 256, (4, n_bytes), dtype=np.uint8), 6, 5),
              (rng.integers(0, 256, (1, n_bytes), dtype=np.uint8), 1, 1)]
    got = decode_levels(fmt, levels)
    for (blocks, w, h), g in zip(levels, got):
        assert g.dtype == np.float32
        np.testing.assert_array_equal(g, _t2d_image(fmt, blocks, w, h).astype(np.float32) / 255.0)


def _t2d_image(fmt: ClassicFormat, blocks: np.ndarray, w: int, h: int) -> np.ndarray:
    """texture2ddecoder's (h, w, channels) uint8 image of a level: the padded blocks, cropped."""
    name, cols = T2D[fmt]
    pw, ph = -(-w // 4) * 4, -(-h // 4) * 4
    bgra = np.frombuffer(getattr(t2d, name)(np.ascontiguousarray(blocks).tobytes(), pw, ph), np.uint8)
    return bgra.reshape(ph, pw, 4)[:h, :w, cols]


def _random_blocks(fmt: ClassicFormat, n_bytes: int, n: int, seed: int) -> np.ndarray:
    """``n`` random blocks; BC7's of a random mode each (0-7, or the reserved 8: byte 0 zero), the
    bits above the mode bit random; BC1/BC4/BC5's with every 16th block's endpoints equal (BC1's
    three-colour mode, BC4's six-value one)."""
    rng = np.random.default_rng(seed)
    b = rng.integers(0, 256, (n, n_bytes), dtype=np.uint8)
    if fmt == ClassicFormat.BC7:
        modes = rng.integers(0, 9, n)
        low = np.where(modes < 8, 1 << np.minimum(modes, 7), 0)
        b[:, 0] = (b[:, 0] & ~((low << 1) - 1)) | low
    elif fmt == ClassicFormat.BC1:
        b[::16, 2:4] = b[::16, :2]
    else:
        b[::16, 1::8] = b[::16, 0::8]  # each BC4 block's a1 = a0
    return b


def _kernel_image(fmt: ClassicFormat, blocks: np.ndarray, w: int, h: int) -> np.ndarray:
    img = unorm_decoder(fmt)(blocks, w, h)
    assert img.dtype == np.uint8 and img.shape == (h, w, len(T2D[fmt][1]))
    return img


@pytest.mark.parametrize("fmt, n_bytes", FORMATS)
def test_kernels_match_texture2ddecoder_on_random_blocks_of_every_mode(fmt, n_bytes):
    b = _random_blocks(fmt, n_bytes, 64 * 64, 5)
    if fmt == ClassicFormat.BC7:
        assert (np.bincount(anymode.block_modes(b), minlength=9) > 300).all()  # every mode, the reserved 8 too
    got = _kernel_image(fmt, b, SIDE, SIDE)
    np.testing.assert_array_equal(got, _t2d_image(fmt, b, SIDE, SIDE))


@pytest.mark.parametrize("fmt, n_bytes", FORMATS)
@pytest.mark.parametrize("w, h", [(1, 1), (2, 2), (3, 5), (5, 3), (13, 7), (8, 6), (6, 8)])
def test_kernels_crop_odd_levels(fmt, n_bytes, w, h):
    """The padding of a level whose sides are not multiples of 4 is cropped (8x6 and 6x8: whole
    32-bit rows for some formats, a partial block row or column)."""
    b = _random_blocks(fmt, n_bytes, -(-w // 4) * -(-h // 4), 6 + w * h)
    got = _kernel_image(fmt, b, w, h)
    np.testing.assert_array_equal(got, _t2d_image(fmt, b, w, h))
    np.testing.assert_array_equal(decode_levels(fmt, [(b, w, h)])[0], got.astype(np.float32) / 255.0)


def _textured(h: int, w: int) -> np.ndarray:
    """(h, w, 4) in [0, 1]: smooth colour, hard edges and noise, and an alpha of its own (so an
    encoder picks among BC7's modes as it would on a photograph)."""
    rng = np.random.default_rng(7)
    y, x = np.meshgrid((np.arange(h) + 0.5) / h, (np.arange(w) + 0.5) / w, indexing="ij")
    t = 0.5 + 0.35 * np.sin(2 * np.pi * (x + 0.5 * y))
    edges = ((x * 7).astype(int) + (y * 5).astype(int)) % 2
    noise = rng.normal(0, 0.04, (h, w, 3)) * (x[..., None] > 0.5)
    rgb = np.stack([t, 0.7 * t + 0.2 * edges, 0.4 * t + 0.3 * y], -1) + noise
    alpha = np.where(y > 0.6, 1.0, 0.5 + 0.5 * np.cos(6 * np.pi * x))[..., None]
    return np.clip(np.concatenate([rgb, alpha], -1), 0, 1).astype(np.float32)


@pytest.mark.parametrize("fmt", [f for f, _ in FORMATS])
def test_kernels_match_on_an_encoded_image(fmt):
    """Blocks of bcfpipe's own encoders (quicktex for BC1/BC4/BC5, ISPC for BC7, as a layout ships
    them) of a textured 61x45 image, decoded as texture2ddecoder decodes them."""
    from bcfpipe.texset import baselines

    if fmt == ClassicFormat.BC7:
        pytest.importorskip("ispc_texcomp")
    img = _textured(45, 61)
    encode = {ClassicFormat.BC1: lambda m, b: baselines.bc1_mips([m[..., :3]], blocks=b),
              ClassicFormat.BC4: lambda m, b: baselines.bc4_mips([m[..., :1]], blocks=b),
              ClassicFormat.BC5: lambda m, b: baselines.bc5_mips([m[..., :2]], blocks=b),
              ClassicFormat.BC7: lambda m, b: baselines.bc7_mips([m], blocks=b)}[fmt]
    levels: list = []
    encode(img, levels)
    (b, w, h), = levels
    if fmt == ClassicFormat.BC7:
        assert len(np.unique(anymode.block_modes(b))) > 1
    got = _kernel_image(fmt, b, w, h)
    np.testing.assert_array_equal(got, _t2d_image(fmt, b, w, h))


def test_an_unwritable_kernel_cache_decodes_and_writes_nothing_beside_the_package(tmp_path):
    """Where the cache's kernels folder cannot be made (here: it would sit under a file), the
    decoders compile in the process and decode as ever; numba does not fall back to caching them
    beside the package."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    package = Path(s3tc.__file__).parents[1]
    before = {p for p in package.rglob("*.nb[ic]")}
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    code = ("import numpy as np\n"
            "from bcfpipe.formats.bcn import ClassicFormat, decode_levels\n"
            "b = np.random.default_rng(0).integers(0, 256, (4, 16), dtype=np.uint8)\n"
            "for f, n in ((ClassicFormat.BC1, 8), (ClassicFormat.BC4, 8), (ClassicFormat.BC5, 16),\n"
            "             (ClassicFormat.BC7, 16)):\n"
            "    print(f, decode_levels(f, [(b[:, :n], 8, 8)])[0].shape)\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(blocker / "kernels"))
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "bc7 (8, 8, 4)" in r.stdout and "bc1 (8, 8, 3)" in r.stdout, r.stdout
    assert {p for p in package.rglob("*.nb[ic]")} == before, "numba cached a kernel beside the package"
