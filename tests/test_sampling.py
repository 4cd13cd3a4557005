"""The hardware sampler against independent references: torch grid_sample and an explicit loop."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from bcfpipe.model.sampling import sample_bilinear, sample_trilinear


def _grid_sample(tex, uv, wrap):
    """grid_sample (align_corners=False puts texel centres at (i+0.5)/w, as GL does)."""
    c, h, w = tex.shape
    if wrap == "repeat":  # pad one texel circularly, map uv into the padded texture
        tex = F.pad(tex[None], (1, 1, 1, 1), mode="circular")[0]
        uv = torch.stack([(torch.remainder(uv[:, 0], 1.0) * w + 1) / (w + 2),
                          (torch.remainder(uv[:, 1], 1.0) * h + 1) / (h + 2)], 1)
    grid = (uv * 2 - 1).view(1, -1, 1, 2)
    pad = "border" if wrap == "clamp" else "zeros"
    out = F.grid_sample(tex[None].double(), grid.double(), mode="bilinear", padding_mode=pad, align_corners=False)
    return out[0, :, :, 0].t()


def _texel_index(i, n, mode):
    """Texel i of n by the GL spec's wording (OpenGL 4.5 §8.14.2): repeat takes i mod n, clamp-to-edge
    clamps, mirrored repeat takes (n - 1) - mirror((i mod 2n) - n), mirror(a) = a >= 0 ? a : -(1 + a)."""
    if mode == "repeat":
        return i % n
    if mode == "mirror":
        a = (i % (2 * n)) - n
        return (n - 1) - (a if a >= 0 else -(1 + a))
    return min(max(i, 0), n - 1)


def _loop_bilinear(tex, u, v, wrap):
    c, h, w = tex.shape
    ws, wt = (wrap, wrap) if isinstance(wrap, str) else wrap
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = math.floor(x), math.floor(y)
    fx, fy = x - x0, y - y0
    acc = np.zeros(c)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            xi, yi = _texel_index(x0 + dx, w, ws), _texel_index(y0 + dy, h, wt)
            acc += wx * wy * tex[:, yi, xi].numpy().astype(np.float64)
    return acc


def _loop_trilinear(levels, u, v, lod, wrap):
    n = len(levels)
    lod = min(max(lod, 0.0), n - 1)
    lo = int(math.floor(lod))
    hi = min(lo + 1, n - 1)
    t = lod - lo
    a = _loop_bilinear(levels[lo], u, v, wrap)
    return a if hi == lo else (1 - t) * a + t * _loop_bilinear(levels[hi], u, v, wrap)


@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
@pytest.mark.parametrize("h,w", [(8, 8), (16, 4), (5, 7)])
def test_bilinear_matches_grid_sample(wrap, h, w):
    g = torch.Generator().manual_seed(h * 100 + w)
    tex = torch.rand((3, h, w), generator=g, dtype=torch.float64)
    # random points, texel centres, texel edges, and points beyond the borders on both sides
    i = torch.arange(w, dtype=torch.float64)
    special = torch.stack([torch.cat([(i + 0.5) / w, i / w]), torch.full((2 * w,), 0.5 / h, dtype=torch.float64)], 1)
    uv = torch.cat([torch.rand((500, 2), generator=g, dtype=torch.float64) * 3 - 1, special,
                    torch.tensor([[0.0, 0.0], [1.0, 1.0], [-0.001, 0.999], [0.9999, 0.0001]], dtype=torch.float64)])
    ours = sample_bilinear(tex, uv, wrap)
    ref = _grid_sample(tex, uv, wrap)
    assert torch.allclose(ours, ref, atol=1e-12), (ours - ref).abs().max()


def test_texel_centres_return_texels_exactly():
    tex = torch.rand((3, 8, 8), generator=torch.Generator().manual_seed(1))
    ys, xs = torch.meshgrid((torch.arange(8) + 0.5) / 8, (torch.arange(8) + 0.5) / 8, indexing="ij")
    uv = torch.stack([xs.reshape(-1), ys.reshape(-1)], 1)
    assert torch.equal(sample_bilinear(tex, uv, "repeat"), tex.reshape(3, -1).t())


PER_AXIS = [("clamp", "repeat"), ("repeat", "clamp"), ("clamp", "mirror"), ("mirror", "repeat"), ("mirror", "mirror")]


@pytest.mark.parametrize("h,w", [(8, 8), (16, 4), (5, 7)])
def test_mirror_matches_grid_sample_reflection(h, w):
    """Mirror on both axes is grid_sample's reflection padding (reflected about the image's edges),
    for uv within one period beyond each border."""
    g = torch.Generator().manual_seed(h * 10 + w)
    tex = torch.rand((3, h, w), generator=g, dtype=torch.float64)
    uv = torch.cat([torch.rand((500, 2), generator=g, dtype=torch.float64) * 2.8 - 0.9,
                    torch.tensor([[0.0, 0.0], [1.0, 1.0], [-0.001, 0.999], [1.0001, -0.0001], [-0.5, 1.5]],
                                 dtype=torch.float64)])
    grid = (uv * 2 - 1).view(1, -1, 1, 2)
    ref = F.grid_sample(tex[None], grid, mode="bilinear", padding_mode="reflection", align_corners=False)[0, :, :, 0].t()
    assert torch.allclose(sample_bilinear(tex, uv, "mirror"), ref, atol=1e-12)


@pytest.mark.parametrize("wrap", PER_AXIS)
def test_bilinear_per_axis_matches_explicit_loop(wrap):
    """S and T addressed apart: u by the first mode, v by the second, far uvs included."""
    g = torch.Generator().manual_seed(11)
    tex = torch.rand((2, 6, 10), generator=g, dtype=torch.float64)
    uv = torch.cat([torch.rand((400, 2), generator=g, dtype=torch.float64) * 7 - 3,
                    torch.tensor([[-0.01, 1.01], [1.01, -0.01], [-1.0, 2.0], [0.0, 1.0]], dtype=torch.float64)])
    ours = sample_bilinear(tex, uv, wrap)
    for n in range(uv.shape[0]):
        np.testing.assert_allclose(ours[n].numpy(), _loop_bilinear(tex, float(uv[n, 0]), float(uv[n, 1]), wrap),
                                   atol=1e-12)


@pytest.mark.parametrize("wrap", ["repeat", "clamp"] + PER_AXIS)
def test_trilinear_matches_explicit_loop(wrap):
    g = torch.Generator().manual_seed(7)
    levels = [torch.rand((3, 32 >> k, 32 >> k), generator=g, dtype=torch.float64) for k in range(4)]  # 32..4
    uv = torch.rand((300, 2), generator=g, dtype=torch.float64) * 2 - 0.5
    lods = torch.cat([torch.rand(290, generator=g, dtype=torch.float64) * 6 - 1,
                      torch.tensor([-2.0, -0.5, 0.0, 1.0, 2.0, 2.5, 3.0, 3.5, 9.0, 0.999], dtype=torch.float64)])
    per_point = sample_trilinear(levels, uv, lods, wrap)
    for n in range(uv.shape[0]):
        ref = _loop_trilinear(levels, float(uv[n, 0]), float(uv[n, 1]), float(lods[n]), wrap)
        np.testing.assert_allclose(per_point[n].numpy(), ref, atol=1e-12)
    # one lod for the whole batch (the training path) agrees with the per-point path
    for lod in (-1.0, 0.0, 0.3, 1.5, 2.75, 3.0, 7.0):
        batch = sample_trilinear(levels, uv, lod, wrap)
        pp = sample_trilinear(levels, uv, torch.full((uv.shape[0],), lod, dtype=torch.float64), wrap)
        assert torch.allclose(batch, pp, atol=1e-12)
