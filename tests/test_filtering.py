"""`bcfpipe.formats.filtering`, the numpy trilinear filter through which the exported files'
classic textures are measured: the same bits as the torch sampler training uses
(`bcfpipe.model.sampling`), at every wrap mode, at lods below, between and past the levels, and at
uvs far outside [0, 1)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from bcfpipe.formats.filtering import trilinear, whole_level
from bcfpipe.model.sampling import sample_trilinear

WRAPS = ["repeat", "clamp", "mirror", ("repeat", "mirror"), ("clamp", "repeat")]


@pytest.mark.parametrize("wrap", WRAPS)
@pytest.mark.parametrize("lod", [-2.0, 0.0, 0.3, 1.0, 2.75, 5.0, 9.0])
def test_numpy_trilinear_gives_the_torch_samplers_bits(wrap, lod):
    rng = np.random.default_rng(7)
    levels = [rng.random((48 >> k, 32 >> k, 3), dtype=np.float32) for k in range(5)]  # non-square
    uv = (rng.random((4000, 2)) * 6 - 3).astype(np.float32)
    uv[:200] = rng.integers(-100000, 100000, (200, 2)).astype(np.float32) + np.float32(0.37)
    texel_centres = (np.stack([np.arange(32) % 32, np.arange(32) % 48], 1) + 0.5) / np.array([32, 48])
    uv[200:232] = texel_centres.astype(np.float32)
    ours = trilinear(levels, uv, lod, wrap)
    theirs = sample_trilinear([torch.from_numpy(l).permute(2, 0, 1) for l in levels], torch.from_numpy(uv),
                              lod, wrap).numpy()
    assert ours.dtype == np.float32
    assert np.array_equal(ours, theirs)


def test_texel_centres_at_a_levels_own_lod_read_its_texels():
    levels = [np.arange(8 * 4 * 2, dtype=np.float32).reshape(8, 4, 2), np.zeros((4, 2, 2), np.float32)]
    yy, xx = np.mgrid[0:8, 0:4]
    uv = np.stack([(xx.ravel() + 0.5) / 4, (yy.ravel() + 0.5) / 8], 1).astype(np.float32)
    assert np.array_equal(trilinear(levels, uv, 0.0, "repeat"), levels[0].reshape(-1, 2))


@pytest.mark.parametrize("wrap", WRAPS)
@pytest.mark.parametrize("k", [0, 2, 4])
def test_a_levels_own_texel_centres_give_the_torch_samplers_bits(wrap, k):
    """Every uv a texel centre of level k at lod k: `filtering.bilinear` reads each texel once."""
    rng = np.random.default_rng(k)
    levels = [rng.random((48 >> j, 32 >> j, 2), dtype=np.float32) for j in range(5)]
    h, w = levels[k].shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    uv = np.stack([(xx.ravel() + 0.5) / w, (yy.ravel() + 0.5) / h], 1).astype(np.float32)
    ours = trilinear(levels, uv, float(k), wrap)
    theirs = sample_trilinear([torch.from_numpy(l).permute(2, 0, 1) for l in levels], torch.from_numpy(uv),
                              float(k), wrap).numpy()
    assert np.array_equal(ours, theirs) and np.array_equal(ours, levels[k].reshape(-1, 2))


@pytest.mark.parametrize("wrap", WRAPS)
@pytest.mark.parametrize("lod", [-1.0, 0.0, 0.5, 1.0, 3.0, 4.0, 7.0])
def test_a_whole_level_is_what_trilinear_gives_at_every_texel_centre(wrap, lod):
    """`whole_level`: where a mip's every texel centre reads one level texel for texel, that level,
    the same bits as `trilinear`; None where trilinear blends, magnifies or the sides are not powers of two."""
    rng = np.random.default_rng(3)
    for levels in ([rng.random((64 >> k, 32 >> k, 3), dtype=np.float32) for k in range(6)],
                   [rng.random((48 >> k, 32 >> k, 3), dtype=np.float32) for k in range(4)]):
        for h, w in {lv.shape[:2] for lv in levels}:
            whole = whole_level(levels, lod, h, w)
            yy, xx = np.mgrid[0:h, 0:w]
            uv = np.stack([(xx.ravel() + 0.5) / w, (yy.ravel() + 0.5) / h], 1).astype(np.float32)
            read = levels[int(min(max(lod, 0), len(levels) - 1))]
            if lod != int(lod) or read.shape[:2] != (h, w) or h & (h - 1):  # 48, 24, 12, 6 rows: not powers of two
                assert whole is None
                continue
            assert whole is not None and np.shares_memory(whole, read)
            assert np.array_equal(whole, trilinear(levels, uv, lod, wrap))
