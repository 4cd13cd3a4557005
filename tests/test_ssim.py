"""`texset.ssim` against scikit-image's ``structural_similarity`` (Gaussian weights, population
covariance), the oracle it reproduces: the same value on noise, on real textures and at the
smallest size, whatever the bands and threads."""
from __future__ import annotations

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from bcfpipe.texset import parallel, ssim
from bcfpipe.texset.metrics import ssim_group

KW = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)


def oracle(ref: np.ndarray, dec: np.ndarray, peak: float) -> float:
    """skimage's SSIM per channel (float32 input), averaged over the channels in float64."""
    return float(np.mean([structural_similarity(ref[..., c], dec[..., c], data_range=peak, **KW)
                          for c in range(ref.shape[2])]))


@pytest.mark.parametrize("shape,peak", [((11, 11, 1), 1.0), ((12, 37, 3), 1.0), ((64, 40, 2), 2.0),
                                        ((130, 131, 1), 1.0)])
def test_equals_skimage_on_noise(shape, peak):
    rng = np.random.default_rng(shape[0])
    lo = -1.0 if peak == 2.0 else 0.0
    ref = rng.uniform(lo, 1, shape).astype(np.float32)
    dec = np.clip(ref + rng.normal(0, 0.1, shape), lo, 1).astype(np.float32)
    assert ssim.mean_ssim(ref, dec, peak) == pytest.approx(oracle(ref, dec, peak), rel=0, abs=1e-12)


def test_equals_skimage_on_a_real_texture(shared_scenes):
    from PIL import Image

    img = Image.open(shared_scenes / "gltf_water_bottle" / "WaterBottle_baseColor.png").convert("RGB")
    ref = (np.asarray(img, np.float32) / 255)[500:900, 200:700]
    rng = np.random.default_rng(0)
    dec = np.clip(np.round((ref + rng.normal(0, 0.02, ref.shape)) * 63) / 63, 0, 1).astype(np.float32)
    value = ssim.mean_ssim(ref, dec, 1.0)
    assert value == pytest.approx(oracle(ref, dec, 1.0), rel=0, abs=1e-12)
    assert 0.3 < value < 0.99


@pytest.mark.parametrize("cores", [1, 2])
def test_bands_and_threads_change_nothing(monkeypatch, cores):
    rng = np.random.default_rng(9)
    ref = rng.random((90, 33, 3), dtype=np.float32)
    dec = np.clip(ref + rng.normal(0, 0.05, ref.shape), 0, 1).astype(np.float32)
    whole = ssim.mean_ssim(ref, dec, 1.0)
    monkeypatch.setattr(ssim, "BAND_TEXELS", 33 * 4)
    parallel.set_encode_workers(cores)
    try:
        assert ssim_group(ref, dec, 1.0) == pytest.approx(whole, rel=1e-12, abs=0)
    finally:
        parallel.set_encode_workers(None)


def test_small_images():
    """Below 11x11 the Gaussian window does not fit: `mean_ssim` says so, and `ssim_group` takes
    skimage's uniform window as wide as the image allows (None below 3x3)."""
    rng = np.random.default_rng(2)
    ref = rng.random((7, 9, 1), dtype=np.float32)
    with pytest.raises(ValueError, match="at least 11"):
        ssim.mean_ssim(ref, ref, 1.0)
    assert ssim_group(ref, ref * 0.5, 1.0) == pytest.approx(
        structural_similarity(ref[..., 0], ref[..., 0] * 0.5, data_range=1.0, win_size=7))
    assert ssim_group(ref[:2], ref[:2], 1.0) is None
