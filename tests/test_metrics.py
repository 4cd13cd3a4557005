"""Evaluation metrics on synthetic mips: PSNR definition, SSIM, FLIP."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bcfpipe.texset.metrics import compute_metrics, mse_per_mip, psnr_from_mse
from bcfpipe.texset.texture_set import Channel, build_mip_chain


def channels(spec: str) -> tuple[Channel, ...]:
    """'albedo:3,roughness:1,normal:2' -> Channels of the matching kinds."""
    kinds = {"albedo": "color", "emissiveColor": "color", "normal": "normal"}
    out = []
    for part in spec.split(","):
        sem, n = part.split(":")
        for i in range(int(n)):
            out.append(Channel(sem, "rgbxy"[i], kinds.get(sem, "scalar"), f"{sem}.png", i))
    return tuple(out)


@pytest.fixture(scope="module")
def ref():
    rng = np.random.default_rng(11)
    x = np.linspace(0, 1, 32)
    smooth = np.stack([np.outer(x, x), np.add.outer(x, x) / 2, np.sin(np.add.outer(3 * x, 5 * x)) * 0.5 + 0.5], -1)
    data = np.concatenate([smooth, rng.random((32, 32, 1)), rng.uniform(-1, 1, (32, 32, 2))], -1)
    return build_mip_chain(data.astype(np.float32))


CH = channels("albedo:3,roughness:1,normal:2")


def test_identical_is_perfect(ref):
    m = compute_metrics(ref, [r.copy() for r in ref], CH)
    assert m.psnr == math.inf and all(v == math.inf for v in m.psnr_per_mip)
    assert set(m.psnr_per_group) == {"albedo", "roughness", "normal"}
    assert m.ssim == pytest.approx(1.0) and all(v == pytest.approx(1.0) for v in m.ssim_per_group.values())
    assert m.flip == pytest.approx(0.0, abs=1e-6) and set(m.flip_per_group) == {"albedo"}


def test_known_error_gives_known_psnr(ref):
    # a constant offset of 0.01 on [0,1] channels and 0.02 on normals (peak 2) is MSE 1e-4 everywhere
    off = np.array([0.01] * 4 + [0.02] * 2, np.float32)
    m = compute_metrics(ref, [r + off for r in ref], CH, ssim=False, flip=False)
    assert m.psnr == pytest.approx(40.0, abs=1e-3)
    assert all(v == pytest.approx(40.0, abs=1e-3) for v in m.psnr_per_mip)
    assert all(v == pytest.approx(40.0, abs=1e-3) for v in m.psnr_per_group.values())
    assert m.ssim is None and m.flip is None


def test_psnr_is_mse_averaged_over_mips_not_psnr_averaged(ref):
    rng = np.random.default_rng(0)
    dec = [r + rng.normal(0, 0.01 * (k + 1), r.shape).astype(np.float32) for k, r in enumerate(ref)]
    m = compute_metrics(ref, dec, CH, ssim=False, flip=False)
    mses = mse_per_mip(ref, dec, CH)
    used = [k for k, r in enumerate(ref) if min(r.shape[:2]) >= 4]  # 32..4: 4 of the 6 mips
    assert m.mips_in_mean == len(used) == 4
    assert m.psnr == pytest.approx(10 * math.log10(1 / np.mean([mses[k] for k in used])))
    assert m.psnr_per_mip == pytest.approx([10 * math.log10(1 / v) for v in mses])
    m_all = compute_metrics(ref, dec, CH, min_size=1, ssim=False, flip=False)
    assert m_all.mips_in_mean == 6 and m_all.psnr < m.psnr  # the noisier tail now counts


def test_gaussian_noise_psnr_matches_sigma():
    rng = np.random.default_rng(1)
    ref = build_mip_chain(rng.random((256, 256, 1)).astype(np.float32))
    ch = channels("roughness:1")
    dec = [r + rng.normal(0, 0.05, r.shape).astype(np.float32) for r in ref]
    m = compute_metrics(ref, dec, ch, ssim=False, flip=False)
    assert m.psnr_per_mip[0] == pytest.approx(-20 * math.log10(0.05), abs=0.1)  # 26.02 dB


def test_normal_peak_is_two():
    ref = [np.zeros((8, 8, 2), np.float32)]
    dec = [np.full((8, 8, 2), 0.2, np.float32)]  # error 0.2 in [-1,1] == 0.1 stored
    m = compute_metrics(ref, dec, channels("normal:2"), ssim=False, flip=False)
    assert m.psnr == pytest.approx(20.0)


def test_ssim_and_flip_degrade_with_noise(ref):
    rng = np.random.default_rng(2)
    dec = [np.clip(r + rng.normal(0, 0.1, r.shape), -1, 1).astype(np.float32) for r in ref]
    m = compute_metrics(ref, dec, CH)
    assert 0.0 < m.ssim < 0.95 and 0.0 < m.flip < 1.0
    assert m.ssim == pytest.approx(np.mean(list(m.ssim_per_group.values())))


def test_no_colour_group_means_no_flip(ref):
    sub = [r[..., 3:] for r in ref]
    m = compute_metrics(sub, sub, channels("roughness:1,normal:2"))
    assert m.flip is None and m.flip_per_group == {} and m.ssim == pytest.approx(1.0)


def test_small_images_and_to_json():
    ref = build_mip_chain(np.random.default_rng(3).random((4, 4, 3)).astype(np.float32))
    dec = [r * 0.9 for r in ref]
    m = compute_metrics(ref, dec, channels("albedo:3"), flip=False)
    assert m.mips_in_mean == 1 and m.ssim is not None  # 4x4: SSIM with a 3x3 window
    d = m.to_json()
    assert set(d) >= {"psnr", "psnr_per_mip", "psnr_per_group", "ssim", "flip"}
    json.dumps(d)


def test_bad_inputs(ref):
    with pytest.raises(ValueError, match="decoded mips"):
        compute_metrics(ref, ref[:-1], CH)
    with pytest.raises(ValueError, match="does not match"):
        compute_metrics(ref, ref, CH[:3])
    with pytest.raises(ValueError, match="NaN"):
        compute_metrics(ref, [r * np.nan for r in ref], CH)
    with pytest.raises(ValueError, match="shape"):
        compute_metrics(ref, [r[:1] for r in ref], CH)
    assert psnr_from_mse(0.0) == math.inf and psnr_from_mse(0.01) == pytest.approx(20.0)
