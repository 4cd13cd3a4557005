"""Reference sampling (paper §5.1): Catmull-Rom bicubic in two mips, lerped by frac(s)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from bcfpipe.texset.reference import ReferencePyramid, keys_weights, random_batch, sample_reference
from bcfpipe.texset.texture_set import Channel, TextureSet, build_mip_chain


def keys(x: float, a: float = -0.5) -> float:
    """Keys cubic convolution kernel k(x), written from its textbook definition."""
    x = abs(x)
    if x <= 1:
        return (a + 2) * x**3 - (a + 3) * x**2 + 1
    if x < 2:
        return a * x**3 - 5 * a * x**2 + 8 * a * x - 4 * a
    return 0.0


def slow_bicubic(img: np.ndarray, u: float, v: float, wrap: str) -> np.ndarray:
    """Per-point loop: sum over the 4x4 texels around (u, v) of k(dx) k(dy) texel."""
    img = img.astype(np.float64)
    h, w, _ = img.shape
    x, y = u * w - 0.5, v * h - 0.5
    out = np.zeros(img.shape[2])
    for j in range(math.floor(y) - 1, math.floor(y) + 3):
        for i in range(math.floor(x) - 1, math.floor(x) + 3):
            ii, jj = (i % w, j % h) if wrap == "repeat" else (min(max(i, 0), w - 1), min(max(j, 0), h - 1))
            out += keys(x - i) * keys(y - j) * img[jj, ii]
    return out


def slow_sample(mips: list[np.ndarray], u: float, v: float, s: float, wrap: str) -> np.ndarray:
    s = max(s, 0.0)
    last = len(mips) - 1
    l0, l1 = min(math.floor(s), last), min(math.floor(s) + 1, last)
    t = s - math.floor(s) if l0 != l1 else 0.0
    return (1 - t) * slow_bicubic(mips[l0], u, v, wrap) + t * slow_bicubic(mips[l1], u, v, wrap)


@pytest.fixture(scope="module")
def mips():
    rng = np.random.default_rng(3)
    return build_mip_chain(rng.random((16, 32, 3)).astype(np.float32))


@pytest.fixture(scope="module")
def pyr(mips):
    return ReferencePyramid.from_mips(mips, "cpu", torch.float64)


def test_keys_weights_match_kernel_and_sum_to_one():
    f = torch.linspace(0, 1, 11, dtype=torch.float64)
    w = keys_weights(f)
    torch.testing.assert_close(w.sum(-1), torch.ones(11, dtype=torch.float64))
    for fi, wi in zip(f.tolist(), w.tolist()):
        assert wi == pytest.approx([keys(1 + fi), keys(fi), keys(1 - fi), keys(2 - fi)], abs=1e-12)


@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
@pytest.mark.parametrize("s", [0.0, 1.0, 2.0, 0.3, 1.75, 3.5, 5.0, 9.0])
def test_matches_slow_loop_scalar_s(mips, pyr, wrap, s):
    g = torch.Generator().manual_seed(int(s * 100))
    uv = torch.rand(40, 2, generator=g, dtype=torch.float64)
    uv[:4] = torch.tensor([[0.0, 0.0], [0.999, 0.001], [0.01, 0.99], [0.5, 0.999]], dtype=torch.float64)  # borders
    got = sample_reference(pyr, uv, s, wrap).numpy()
    want = np.stack([slow_sample(mips, u, v, s, wrap) for u, v in uv.tolist()])
    np.testing.assert_allclose(got, want, atol=1e-10)


@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
def test_matches_slow_loop_per_point_s(mips, pyr, wrap):
    g = torch.Generator().manual_seed(1)
    uv = torch.rand(64, 2, generator=g, dtype=torch.float64)
    s = torch.rand(64, generator=g, dtype=torch.float64) * 7 - 0.5  # includes s < 0 and s > last level
    s[:3] = torch.tensor([0.0, 2.0, 5.0], dtype=torch.float64)
    got = sample_reference(pyr, uv, s, wrap).numpy()
    want = np.stack([slow_sample(mips, u, v, si, wrap) for (u, v), si in zip(uv.tolist(), s.tolist())])
    np.testing.assert_allclose(got, want, atol=1e-10)
    # per-point s equal everywhere == scalar s
    torch.testing.assert_close(sample_reference(pyr, uv, torch.full((64,), 1.25, dtype=torch.float64), wrap),
                               sample_reference(pyr, uv, 1.25, wrap))


def test_texel_centres_exact_at_integer_s(mips):
    pyr = ReferencePyramid.from_mips(mips)  # float32, as in training
    for k in range(len(mips)):
        h, w, _ = mips[k].shape
        jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
        uv = torch.tensor(np.stack([(ii.ravel() + 0.5) / w, (jj.ravel() + 0.5) / h], -1), dtype=torch.float32)
        for wrap in ("repeat", "clamp"):
            got = sample_reference(pyr, uv, float(k), wrap).numpy().reshape(h, w, -1)
            np.testing.assert_allclose(got, mips[k], atol=1e-6)


def test_wrap_repeat_is_periodic_and_clamp_is_not(pyr):
    g = torch.Generator().manual_seed(5)
    uv = torch.rand(32, 2, generator=g, dtype=torch.float64)
    shifted = uv + torch.tensor([1.0, -2.0], dtype=torch.float64)
    torch.testing.assert_close(sample_reference(pyr, shifted, 0.6, "repeat"), sample_reference(pyr, uv, 0.6, "repeat"))
    # clamp: beyond the edge the value is the edge texel (constant in the outward direction)
    edge = torch.tensor([[1.5, 0.3], [3.0, 0.3]], dtype=torch.float64)
    a, b = sample_reference(pyr, edge, 0.0, "clamp")
    torch.testing.assert_close(a, b)
    assert not torch.allclose(sample_reference(pyr, torch.tensor([[0.999, 0.3]], dtype=torch.float64), 0.0, "repeat"),
                              sample_reference(pyr, torch.tensor([[0.999, 0.3]], dtype=torch.float64), 0.0, "clamp"))


def test_large_s_gives_mean_and_constant_is_preserved(mips, pyr):
    uv = torch.rand(10, 2, dtype=torch.float64)
    torch.testing.assert_close(sample_reference(pyr, uv, 50.0), torch.as_tensor(mips[-1][0, 0], dtype=torch.float64).expand(10, 3))
    const = ReferencePyramid.from_mips(build_mip_chain(np.full((8, 8, 2), 0.25, np.float32)))
    torch.testing.assert_close(sample_reference(const, torch.rand(20, 2), 1.3), torch.full((20, 2), 0.25))


def test_from_texture_set_and_validation():
    data = np.random.default_rng(0).random((4, 8, 2)).astype(np.float32)
    ch = (Channel("normal", "x", "normal", "n.png", 0), Channel("normal", "y", "normal", "n.png", 1))
    pyr = ReferencePyramid.from_texture_set(TextureSet(data, ch, 8, 4), "cpu")
    assert pyr.num_levels == 4 and pyr.num_channels == 2 and tuple(pyr.mips[0].shape) == (2, 4, 8)
    torch.testing.assert_close(pyr.mips[0], torch.from_numpy(data).permute(2, 0, 1))
    with pytest.raises(ValueError, match="unknown addressing 'black'; choose repeat, clamp or mirror"):
        sample_reference(pyr, torch.zeros(1, 2), 0.0, "black")
    with pytest.raises(ValueError, match=r"uv must have shape"):
        sample_reference(pyr, torch.zeros(3), 0.0)
    with pytest.raises(ValueError, match="per-point s"):
        sample_reference(pyr, torch.zeros(3, 2), torch.zeros(4))


def test_random_batch():
    g = torch.Generator().manual_seed(0)
    uv, s = random_batch(1000, g, "cpu", 11.0)
    assert uv.shape == (1000, 2) and uv.dtype == torch.float32
    assert float(uv.min()) >= 0.0 and float(uv.max()) < 1.0
    assert isinstance(s, float) and 0.0 <= s <= 11.0
    ss = [random_batch(1, g, "cpu", 4.0)[1] for _ in range(200)]
    assert min(ss) < 0.5 and max(ss) > 3.5
    uv2, s2 = random_batch(1000, torch.Generator().manual_seed(0), torch.device("cpu"), 11.0)
    assert torch.equal(uv, uv2) and s == s2  # reproducible from the generator
    with pytest.raises(ValueError):
        random_batch(0, g, "cpu", 1.0)


@pytest.mark.parametrize("interleave", [False, True])
@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
def test_centre_targets_equal_sample_reference(wrap, interleave):
    """Precomputed texel-centre targets are the bicubic reference at those points, bit for bit,
    for integer and fractional s and for the last mips (where floor(s) + 1 is clamped), with the
    levels kept plane by plane or texel by texel."""
    from bcfpipe.texset.reference import CentreTargets

    rng = np.random.default_rng(5)
    data = rng.uniform(0, 1, (64, 32, 3)).astype(np.float32)
    pyr = ReferencePyramid.from_mips(build_mip_chain(data))
    ct = CentreTargets(pyr, wrap, min_texels=64, interleave=interleave)
    assert [t is not None for t in ct.texels[:4]] == [interleave] * 3 + [False]
    assert [u is not None for u in ct.up[:4]] == [not interleave] * 3 + [False]
    gen = torch.Generator().manual_seed(0)
    covered = [s for s in (0.0, 0.25, 1.0, 1.5, 2.75, 3.0, 5.9) if ct.covers(s)]
    assert covered == [0.0, 0.25, 1.0, 1.5, 2.75]  # mips of >= 64 texels: 64x32, 32x16, 16x8
    for s in covered:
        uv, target = ct.batch(500, s, gen)
        torch.testing.assert_close(target, sample_reference(pyr, uv, s, wrap), rtol=0, atol=0)
        k = int(s)
        h, w = pyr.mips[k].shape[1:]
        cx, cy = uv[:, 0] * w - 0.5, uv[:, 1] * h - 0.5
        assert torch.equal(cx, torch.round(cx)) and torch.equal(cy, torch.round(cy))  # texel centres
