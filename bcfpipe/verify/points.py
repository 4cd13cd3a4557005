"""Where `bcfpipe verify` samples a material: texel centres and edges of every level, borders
and wrap, s below 0, fractional s, s past the last mip, and random points."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from bcfpipe.verify.glsl import MaterialDesc


CATEGORIES = ("texel centres", "texel edges", "borders / wrap", "s < 0", "fractional s", "s > last mip", "random")


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
    return (np.concatenate(uvs).astype(np.float32), np.concatenate(ss).astype(np.float32),
            np.concatenate(cats))
