"""Where `bcfpipe verify` samples a material: texel centres and edges of every level, borders
and wrap, s below 0, fractional s, s past the last mip, random points, and the runtime extremes:
uv far outside [0, 1] (+-1e4), s far outside the mip range (+-1e30, +-inf), and lods from zero,
tiny, huge and infinite uv derivatives."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from bcfpipe.verify.glsl import MaterialDesc


CATEGORIES = ("texel centres", "texel edges", "borders / wrap", "s < 0", "fractional s", "s > last mip", "random",
              "uv +-1e4", "s far out", "derivatives")
FAR_UV = 1.0e4
FAR_LODS = (-np.inf, -1e30, -1e4, -100.0, 100.0, 1e4, 1e30, np.inf)


def verification_points(m: MaterialDesc, level_sizes: Sequence[Sequence[tuple[int, int]]], seed: int = 0,
                        per_level: int = 24, n_random: int = 4096) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(uv (N, 2) float32, s (N,) float32, category index (N,)) covering the cases in CATEGORIES."""
    rng = np.random.default_rng(seed)
    uvs, ss, cats = [], [], []

    def add(uv, s, cat):
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        uvs.append(uv)
        ss.append(np.broadcast_to(np.asarray(s, np.float64), (uv.shape[0],)))
        cats.append(np.full(uv.shape[0], CATEGORIES.index(cat)))

    biases = m.lod_biases
    s_last = max(n - 1 - b for n, b in zip(m.mip_counts, biases))  # every layer at its last mip beyond this
    for i, sizes in enumerate(level_sizes):
        for k, (w, h) in enumerate(sizes):
            xi = np.concatenate([[0, w - 1], rng.integers(0, w, per_level - 2)])
            yi = np.concatenate([[h - 1, 0], rng.integers(0, h, per_level - 2)])
            s = k - biases[i]  # layer i exactly at level k (others wherever that puts them)
            add(np.stack([(xi + 0.5) / w, (yi + 0.5) / h], 1), s, "texel centres")
            add(np.stack([xi / w, yi / h], 1), s, "texel edges")
            add(np.stack([xi / w, (yi + 0.5) / h], 1), s + 0.5, "texel edges")
    w0 = level_sizes[0][0][0]
    border = np.array([-2.25, -1.0, -0.5, -0.5 / w0, -1e-4, 0.0, 1e-4, 0.5 / w0, 1 - 0.5 / w0, 1 - 1e-4, 1.0,
                       1 + 1e-4, 1.5, 3.75])
    bu, bv = np.meshgrid(border, border, indexing="ij")
    grid = np.stack([bu.ravel(), bv.ravel()], 1)
    for s in (-2.0, 0.0, 0.5, 1.75, s_last + 1):
        add(grid, s, "borders / wrap")
    for s in (-8.0, -2.5, -1.0, -0.3):
        add(rng.random((256, 2)), s, "s < 0")
    for s in (0.25, 0.5, 1.37, 2.9, 3.5, 4.125):
        add(rng.random((256, 2)), s, "fractional s")
    add(rng.random((512, 2)), rng.uniform(-1, s_last + 1, 512), "fractional s")
    for s in (s_last, s_last + 0.5, s_last + 3, 40.0):
        add(rng.random((128, 2)) * 3 - 1, s, "s > last mip")
    add(rng.random((n_random, 2)) * 5 - 2, rng.uniform(-4, s_last + 2, n_random), "random")
    # far uvs: texel centres of level 0 and random points, shifted by whole periods of +-1e4
    w, h = level_sizes[0][0]
    for du, dv in ((FAR_UV, FAR_UV), (-FAR_UV, FAR_UV), (FAR_UV, -FAR_UV), (-FAR_UV, -FAR_UV)):
        xi, yi = rng.integers(0, w, 64), rng.integers(0, h, 64)
        add(np.stack([(xi + 0.5) / w + du, (yi + 0.5) / h + dv], 1), 0.0, "uv +-1e4")
        add(rng.random((128, 2)) + (du, dv), rng.uniform(-1, s_last + 1, 128), "uv +-1e4")
    for s in FAR_LODS:
        add(rng.random((64, 2)) * 3 - 1, s, "s far out")
    return (np.concatenate(uvs).astype(np.float32), np.concatenate(ss).astype(np.float32),
            np.concatenate(cats))


def gradient_points(ref_size: tuple[int, int], seed: int = 0, n: int = 96) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(uv, du/dx, du/dy), each (N, 2) float32, for the derivative path (bcfDecodeGrad): zero,
    subnormal, tiny, one reference texel, anisotropic, huge (their squares overflow fp32) and
    infinite derivatives."""
    rng = np.random.default_rng(seed + 1)
    w, h = ref_size
    texel = np.array([1.0 / w, 0.0])
    cases = [(np.zeros(2), np.zeros(2)), (np.full(2, 1e-45), np.zeros(2)), (np.full(2, 1e-30), np.full(2, 1e-30)),
             (texel, texel[::-1]), (texel * 0.3, texel[::-1] * 5.0), (texel * 37.0, texel[::-1] * 0.1),
             (np.full(2, 1e20), np.zeros(2)), (np.full(2, 3e38), np.full(2, 3e38)),
             (np.array([np.inf, 0.0]), np.zeros(2)), (np.zeros(2), np.array([0.0, -np.inf]))]
    uvs, dxs, dys = [], [], []
    for dx, dy in cases:
        uvs.append(rng.random((n, 2)) * 3 - 1)
        dxs.append(np.broadcast_to(dx, (n, 2)))
        dys.append(np.broadcast_to(dy, (n, 2)))
    return tuple(np.concatenate(a).astype(np.float32) for a in (uvs, dxs, dys))


def lod_from_grad(duvdx: np.ndarray, duvdy: np.ndarray, ref_size: tuple[int, int]) -> np.ndarray:
    """bcfLodFromGrad in fp32, as the shader computes it: log2(max(|dx * W|, |dy * W|, 1e-20))."""
    size = np.asarray(ref_size, np.float32)
    with np.errstate(over="ignore", invalid="ignore"):
        rho = np.maximum(np.sqrt(np.sum(np.square(duvdx.astype(np.float32) * size), 1, dtype=np.float32)),
                         np.sqrt(np.sum(np.square(duvdy.astype(np.float32) * size), 1, dtype=np.float32)))
        return np.log2(np.maximum(rho, np.float32(1e-20))).astype(np.float32)
