"""The compiled quick BC6H encoder (bc6h/quick.cpp, the trainer's first encode) against the torch
encoder with the same settings: the same blocks but for a few in a thousand, where float sums
taken in another order tip a choice, and the same decoded error."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bcfpipe.bc6h import mode10, quick
from bcfpipe.bc6h.decode import decode
from bcfpipe.bc6h.encode import encode_params
from bcfpipe.train.fused import native

TEXTURES = Path(__file__).resolve().parent.parent / "samples" / "textures"


@pytest.fixture(scope="module", autouse=True)
def _compiler():
    try:
        native.load()
    except native.NativeUnavailable as e:
        pytest.skip(str(e))


def _features(signed: bool, seed: int) -> np.ndarray:
    """A real texture (the sample bricks' albedo) as warm features are: about [0, 1.7] unsigned,
    [-1.5, 1.5] signed, with a little noise; the last rows constant, zero and out of range."""
    from bcfpipe.formats.images import read

    img = read(TEXTURES / "bricks_albedo.png").pixels[..., :3].astype(np.float32)
    img = img[:256, :256] / max(float(img.max()), 1.0)
    x = (img - 0.5) * 3.0 if signed else img * 1.7
    x = x + np.random.default_rng(seed).normal(0.0, 0.02, x.shape).astype(np.float32)
    x[-8:-4] = 0.75
    x[-4:, :64] = 0.0
    x[-4:, 64:128] = 1e5  # clamps to 65504
    x[-4:, 128:192] = -1e5  # clamps to 0 unsigned, -65504 signed
    x[-4:, 192:] = 3e-6  # subnormal halves
    return np.ascontiguousarray(x)


@pytest.mark.parametrize("signed", [False, True], ids=["unsigned", "signed"])
@pytest.mark.parametrize("window,rounds", [(1, 1), (4, 2)])
def test_the_quick_encoder_is_the_torch_encoders_one_shape_path(signed, window, rounds):
    x = _features(signed, 0)
    a = encode_params(x, signed=signed, refine_top=1, keep=1, rounds=rounds, window=window)
    b = quick.encode_params(x, signed, native.load(), rounds=rounds, window=window)
    same = np.all(a[0] == b[0], axis=(1, 2)) & np.all(a[1] == b[1], axis=1) & (a[2] == b[2])
    assert same.mean() >= 0.995, same.mean()
    h, w = x.shape[:2]
    err = [float(np.mean((decode(mode10.pack(*prm, signed=signed), w, h, signed) - x.clip(-65504, 65504)
                          .clip(-65504 if signed else 0.0)) ** 2)) for prm in (a, b)]
    assert err[1] <= err[0] * 1.01, err
    assert np.all(b[2] >= 0) and np.all(b[2] < 32) and np.all((b[1] >= 0) & (b[1] < 8))
    lo = -32 if signed else 0
    assert np.all((b[0] >= lo) & (b[0] < lo + 64))
