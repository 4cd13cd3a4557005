"""Classic codec baselines (BC1/BC5 via quicktex, ASTC via astcenc) on small synthetic images."""
from __future__ import annotations

import numpy as np
import pytest

from bcfpipe.texset.baselines import (
    astc_mips, astcenc_path, bc1_mips, bc4_mips, bc5_mips, encode_texture_set_baseline, pack_texture_set,
)
from bcfpipe.texset.metrics import compute_metrics
from bcfpipe.texset.texture_set import Channel, TextureSet, build_mip_chain

pytest.importorskip("quicktex", reason="quicktex (the BC1/BC5 encoder) is not installed")
needs_astcenc = pytest.mark.skipif(astcenc_path() is None, reason="astcenc not installed (apt-get install astcenc)")


def smooth_rgb(h: int, w: int) -> np.ndarray:
    """One period of a sine across the image, channels correlated as in natural colour images."""
    y, x = np.meshgrid((np.arange(h) + 0.5) / h, (np.arange(w) + 0.5) / w, indexing="ij")
    t = 0.5 + 0.35 * np.sin(2 * np.pi * (x + 0.5 * y))
    return np.stack([t, 0.7 * t + 0.1, 0.4 * t + 0.3 * y], -1).astype(np.float32)


def make_set(h: int = 32, w: int = 32) -> TextureSet:
    rgb = smooth_rgb(h, w)
    data = np.concatenate([rgb, rgb[..., :1] * 0.5, rgb[..., 1:2], rgb[..., 2:] * 0.8,
                           rgb[..., :2] * 1.6 - 0.8, rgb[..., 2:] ** 2], -1)
    ch = [Channel("albedo", c, "color", "d.png", i) for i, c in enumerate("rgb")]
    ch += [Channel(s, c, "scalar", "arm.png", i) for i, (s, c) in enumerate(zip(("occlusion", "roughness", "metallic"), "rgb"))]
    ch += [Channel("normal", c, "normal", "n.png", i) for i, c in enumerate("xy")]
    ch += [Channel("displacement", "r", "scalar", "h.png", 0)]
    return TextureSet(data, tuple(ch), w, h)


def test_bc1_constant_is_near_exact_and_sizes():
    mips = build_mip_chain(np.full((16, 8, 3), [0.2, 0.5, 0.7], np.float32))
    dec, size = bc1_mips(mips)
    assert [d.shape for d in dec] == [m.shape for m in mips]
    for d, m in zip(dec, mips):
        assert np.abs(d - m).max() < 1.5 / 255 + 1 / 64  # 565 endpoints + interpolation
    # 16x8: 8 blocks; 8x4: 2; 4x2, 2x1, 1x1: padded to 1 block each -> 13 blocks of 8 bytes
    assert size == 8 * (8 + 2 + 1 + 1 + 1)


def test_bc1_smooth_quality_and_npot_padding():
    img = smooth_rgb(10, 6)  # not multiples of 4: padded to 12x8 and cropped
    dec, size = bc1_mips([img])
    assert dec[0].shape == (10, 6, 3) and size == 8 * 3 * 2
    assert compute_metrics([img], dec, tuple(Channel("albedo", c, "color", "d", i) for i, c in enumerate("rgb")),
                           ssim=False, flip=False).psnr > 27


def test_bc5_two_channels():
    xy = smooth_rgb(16, 16)[..., :2]
    dec, size = bc5_mips([xy, xy[::2, ::2]])
    assert size == 16 * (16 + 4) and dec[0].shape == (16, 16, 2)
    assert np.abs(dec[0] - xy).max() < 0.05
    with pytest.raises(ValueError, match="expected"):
        bc5_mips([smooth_rgb(4, 4)])


@needs_astcenc
def test_astc_runs_and_sizes():
    mips = build_mip_chain(smooth_rgb(32, 16))
    dec, size = astc_mips(mips, "12x12")
    assert [d.shape for d in dec] == [m.shape for m in mips]
    # 32x16 -> 3x2 blocks, 16x8 -> 2x1, then 1 block each for 8x4, 4x2, 2x1, 1x1
    assert size == 16 * (6 + 2 + 1 + 1 + 1 + 1)
    assert np.abs(dec[0] - mips[0]).mean() < 0.04
    const = [np.full((8, 8, 3), 0.4, np.float32)]
    assert np.abs(astc_mips(const, "4x4", "-fast")[0][0] - 0.4).max() <= 1 / 255 + 1e-6
    with pytest.raises(ValueError, match="ASTC block"):
        astc_mips(const, "12")


def test_bc4_is_near_exact_on_constant_and_sizes():
    mips = build_mip_chain(np.full((16, 8, 1), 0.3, np.float32))
    dec, size = bc4_mips(mips)
    assert [d.shape for d in dec] == [m.shape for m in mips]
    assert size == 8 * (8 + 2 + 1 + 1 + 1)  # 16x8 -> 4x2 blocks, 8x4 -> 2x1, then 1 per level
    for d, m in zip(dec, mips):
        assert np.abs(d - m).max() <= 1 / 255 + 1e-6


def test_packing_follows_engine_layout():
    ts = make_set()
    assert pack_texture_set(ts, "bc") == [("bc1", [0, 1, 2]), ("bc5", [6, 7]), ("bc1", [3, 4, 5]), ("bc4", [8])]
    assert [f for f, _ in pack_texture_set(ts, "astc")] == ["astc"] * 4
    with pytest.raises(ValueError, match="codec"):
        pack_texture_set(ts, "etc2")


def test_texture_set_baseline_full_resolution():
    ts = make_set()
    ref = build_mip_chain(ts.data)
    dec, size = encode_texture_set_baseline(ts, "bc", ref_mips=ref)
    assert [d.shape for d in dec] == [r.shape for r in ref]
    blocks = [64, 16, 4, 1, 1, 1]  # 32, 16, 8, 4, 2, 1
    assert size == sum(blocks) * (8 + 16 + 8 + 8)  # albedo BC1 + normal BC5 + ARM BC1 + disp BC1
    m = compute_metrics(ref, dec, ts.channels, ssim=False, flip=False)
    assert m.psnr > 30 and min(m.psnr_per_group.values()) > 25
    assert dec[0][..., 6:8].min() < -0.5  # normals are back in [-1, 1]


def test_texture_set_baseline_lower_resolution():
    ts = make_set()
    ref = build_mip_chain(ts.data)
    dec, size = encode_texture_set_baseline(ts, "bc", 16, ref_mips=ref)
    assert [d.shape for d in dec] == [r.shape for r in ref]
    assert size == sum([16, 4, 1, 1, 1]) * 40  # level 0 is 16x16
    # mip k >= 1 is the 16x16 baseline's mip k-1, i.e. an encoding of reference mip k
    full, _ = encode_texture_set_baseline(ts, "bc", ref_mips=ref)
    np.testing.assert_array_equal(dec[1], full[1])
    # mip 0 is the baseline's level 0 magnified bilinearly: smooth, close to the reference
    assert np.abs(dec[0] - ref[0]).mean() < 0.05
    assert np.array_equal(encode_texture_set_baseline(ts, "bc", 4096, ref_mips=ref)[0][0], full[0])  # no upsampling
    with pytest.raises(ValueError, match="power of two"):
        encode_texture_set_baseline(ts, "bc", 24, ref_mips=ref)


@needs_astcenc
def test_texture_set_baseline_astc():
    ts = make_set(16, 16)
    ref = build_mip_chain(ts.data)
    dec, size = encode_texture_set_baseline(ts, "astc", astc_block="12x12", astc_preset="-fast", ref_mips=ref)
    assert [d.shape for d in dec] == [r.shape for r in ref]
    assert size == 4 * 16 * (4 + 1 + 1 + 1 + 1)  # 4 textures; 16x16 is 2x2 blocks of 12x12
    assert compute_metrics(ref, dec, ts.channels, ssim=False, flip=False).psnr > 20
