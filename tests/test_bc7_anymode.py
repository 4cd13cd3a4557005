"""BC7 blocks of every mode (0-7 and the reserved 8): bcfpipe's decoder against OpenImageIO,
texture2ddecoder and Mesa's OpenGL, bit for bit (issue 29: a T_0 of principal components is encoded
in any mode by ISPC)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from bcfpipe.bc7 import anymode, mode6
from bcfpipe.bc7.decode import decode_to_u8

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bc7_mode7 import mode7  # noqa: E402  (measured, not adopted: benchmarks/bc7_mode7/)
from test_bc7 import N_DEFAULT, N_SLOW, assert_three_decoders_agree  # noqa: E402


def random_any_mode(n: int, seed: int) -> np.ndarray:
    """Random blocks, the modes 0-8 equally often (mode bits forced), a third of them with bytes
    pushed to 0x00 / 0xFF so that endpoints, p-bits and indices hit their ends."""
    rng = np.random.default_rng(seed)
    b = rng.integers(0, 256, (n, 16), dtype=np.uint8)
    extreme = rng.random(n) < 1 / 3
    pick = rng.integers(0, 3, (n, 16))
    b[extreme] = np.where(pick == 0, 0, np.where(pick == 1, 255, b))[extreme]
    mode = rng.integers(0, 9, n)
    low = np.where(mode < 8, 1 << np.minimum(mode, 7), 0)
    keep = np.where(mode < 8, (0xFF << (np.minimum(mode, 7) + 1)) & 0xFF, 0)
    b[:, 0] = ((b[:, 0] & keep) | low).astype(np.uint8)
    return b


def test_block_modes_and_mode6_mode7_agree_with_their_modules():
    b = random_any_mode(20_000, 1)
    modes = anymode.block_modes(b)
    assert set(np.unique(modes)) == set(range(9))
    six, seven = b[modes == 6], b[modes == 7]
    np.testing.assert_array_equal(decode_to_u8(six), mode6.interpolate(*mode6.unpack(six)))
    np.testing.assert_array_equal(decode_to_u8(seven), mode7.interpolate(*mode7.unpack(seven)))
    assert (decode_to_u8(b[modes == 8]) == 0).all()


def test_modes_without_alpha_are_opaque():
    b = random_any_mode(20_000, 2)
    modes = anymode.block_modes(b)
    out = decode_to_u8(b)
    assert (out[np.isin(modes, (0, 1, 2, 3)), :, 3] == 255).all()


@pytest.mark.gl
def test_random_blocks_of_every_mode_match_three_decoders(tmp_path, record_property):
    assert_three_decoders_agree(random_any_mode(N_DEFAULT, 10), tmp_path, "BC7 every mode", record_property)


@pytest.mark.slow
@pytest.mark.gl
def test_million_blocks_of_every_mode_match_three_decoders(tmp_path):
    assert_three_decoders_agree(random_any_mode(N_SLOW, 20), tmp_path, "BC7 every mode, 1M")


def test_ispc_blocks_decode_as_texture2ddecoder_reads_them():
    ispc = pytest.importorskip("ispc_texcomp")
    from bcfpipe.texset.baselines import bc7_mips

    rng = np.random.default_rng(3)
    img = rng.random((64, 64, 4)).astype(np.float32)
    img[:32] = np.linspace(0, 1, 64, dtype=np.float32)[None, :, None]  # smooth half: other modes win there
    shipped: list = []
    dec, _ = bc7_mips([img], shipped)
    b = np.asarray(shipped[0][0], np.uint8).reshape(-1, 16)
    ours = decode_to_u8(b).reshape(16, 16, 4, 4, 4).transpose(0, 2, 1, 3, 4).reshape(64, 64, 4)
    np.testing.assert_array_equal(ours.astype(np.float32) / 255.0, dec[0])
    assert len(np.unique(anymode.block_modes(b))) > 1
    del ispc
