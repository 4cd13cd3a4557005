"""`texset.flip` against NVlabs' ``flip_evaluator`` (the independent oracle): the same LDR-FLIP
error map, texel by texel, on real textures, on noise and at the edges of the input range, and
the same mean whatever the bands and threads."""
from __future__ import annotations

import numpy as np
import pytest

import flip_evaluator
from bcfpipe.texset import flip, parallel
from bcfpipe.texset.metrics import flip_group

TOL = 2e-5  # per texel: float32 operations in a different compiler's order (measured ≤ 7.2e-6)


def oracle(ref: np.ndarray, test: np.ndarray) -> np.ndarray:
    err, _, _ = flip_evaluator.evaluate(np.ascontiguousarray(ref, np.float32), np.ascontiguousarray(test, np.float32),
                                        "LDR", inputsRGB=True, applyMagma=False, computeMeanError=False)
    err = np.asarray(err)
    return err[..., 0] if err.ndim == 3 else err


def degraded(ref: np.ndarray, seed: int = 0, noise: float = 0.03) -> np.ndarray:
    """What a block codec leaves: noise, then 5-bit quantisation."""
    rng = np.random.default_rng(seed)
    return np.clip(np.round((ref + rng.normal(0, noise, ref.shape)) * 31) / 31, 0, 1).astype(np.float32)


@pytest.mark.parametrize("shape", [(1, 1), (3, 7), (25, 13), (64, 64), (97, 150)])
def test_map_matches_flip_evaluator_on_noise(shape):
    rng = np.random.default_rng(sum(shape))
    ref = rng.random((*shape, 3), dtype=np.float32)
    test = degraded(ref, 1, 0.1)
    ours = flip.flip_map(ref, test)
    assert ours.shape == shape and ours.dtype == np.float32
    np.testing.assert_allclose(ours, oracle(ref, test), rtol=0, atol=TOL)


def test_map_matches_flip_evaluator_on_a_real_texture(shared_scenes):
    from PIL import Image

    img = Image.open(shared_scenes / "gltf_water_bottle" / "WaterBottle_baseColor.png").convert("RGB")
    ref = (np.asarray(img, np.float32) / 255)[600:856, 300:812]  # label and cap: edges, text, flat colour
    test = degraded(ref)
    ours, theirs = flip.flip_map(ref, test), oracle(ref, test)
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=TOL)
    assert abs(ours.mean(dtype=np.float64) - theirs.mean(dtype=np.float64)) < 1e-6
    assert 0.01 < ours.mean() < 0.5  # a real error, not a trivial map


def test_range_edges():
    """Identical images err nowhere; black against white is FLIP's largest colour error; values
    outside [0, 1] count as clamped, as flip_evaluator clamps them."""
    rng = np.random.default_rng(3)
    ref = rng.random((40, 40, 3), dtype=np.float32)
    assert np.all(flip.flip_map(ref, ref) == 0)
    black, white = np.zeros((20, 20, 3), np.float32), np.ones((20, 20, 3), np.float32)
    np.testing.assert_allclose(flip.flip_map(black, white), oracle(black, white), rtol=0, atol=TOL)
    wild = (ref * 3 - 1).astype(np.float32)
    np.testing.assert_allclose(flip.flip_map(wild, ref), oracle(np.clip(wild, 0, 1), ref), rtol=0, atol=TOL)


@pytest.mark.parametrize("cores", [1, 2])
def test_bands_give_the_whole_images_errors(monkeypatch, cores):
    """In bands of rows (each reading `HALO` rows beyond its own), on one core or two, the mean is
    the whole image's."""
    rng = np.random.default_rng(5)
    ref = rng.random((150, 37, 3), dtype=np.float32)
    test = degraded(ref, 6, 0.05)
    whole = float(flip.flip_map(ref, test).mean(dtype=np.float64))
    monkeypatch.setattr(flip, "BAND_TEXELS", 37 * 7)  # four bands of 4·HALO rows
    parallel.set_encode_workers(cores)
    try:
        assert flip_group(ref, test) == pytest.approx(whole, rel=1e-12, abs=0)
    finally:
        parallel.set_encode_workers(None)
