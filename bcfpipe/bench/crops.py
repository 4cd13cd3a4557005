"""Crops for the eye: reference, BCf and a baseline side by side, with per-pixel error heat maps.

Windows are chosen where the reference has the most detail (energy of mip k minus mip k+1 made
large again), so the crops show what compression loses rather than flat areas. Each channel
group is one row: colour as RGB, a normal as its (x, y, z) in RGB, anything else as grey.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from bcfpipe.extras import require
from bcfpipe.texset.normals import rebuild_z
from bcfpipe.texset.texture_set import Channel

__all__ = ["crop_mips", "choose_window", "crop_figure"]

CROP_MIP0 = 256
CROP_MID = 128


def crop_mips(n_mips: int) -> tuple[int, int]:
    """The two mips the report crops: 0 and a mid mip (a third of the way down the chain)."""
    return 0, max(1, (n_mips - 1) // 3)


def choose_window(ref: Sequence[np.ndarray], mip: int, side: int) -> tuple[int, int, int, int]:
    """(mip, x, y, side) of the most detailed ``side``-square window of ``ref[mip]``, on a grid of
    half-window steps (deterministic)."""
    m = np.asarray(ref[mip], np.float32)
    h, w = m.shape[:2]
    n = min(side, h, w)
    if mip + 1 < len(ref) and min(h, w) > 1:
        up = np.repeat(np.repeat(np.asarray(ref[mip + 1], np.float32), 2, 0), 2, 1)[:h, :w]
        energy = ((m - up) ** 2).mean(axis=-1)
    else:
        energy = ((m - m.mean(axis=(0, 1))) ** 2).mean(axis=-1)
    c = np.pad(energy, ((1, 0), (1, 0))).cumsum(0).cumsum(1)
    step = max(1, n // 2)
    best, at = -1.0, (0, 0)
    for y in range(0, h - n + 1, step):
        for x in range(0, w - n + 1, step):
            e = c[y + n, x + n] - c[y, x + n] - c[y + n, x] + c[y, x]
            if e > best:
                best, at = e, (x, y)
    return mip, at[0], at[1], n


def _rows(channels: Sequence[Channel]) -> list[tuple[str, list[int], str]]:
    rows: dict[str, list[int]] = {}
    for i, ch in enumerate(channels):
        rows.setdefault(ch.semantic, []).append(i)
    return [(sem, idx, channels[idx[0]].kind) for sem, idx in rows.items()]


def _display(a: np.ndarray, idx: list[int], kind: str, channels: Sequence[Channel]) -> np.ndarray:
    """A crop's channels ``idx`` as an (n, n, 3) image in [0, 1]."""
    x = a[..., idx].astype(np.float32)
    if kind == "normal" and len(idx) == 2:
        return np.clip(rebuild_z(x) * 0.5 + 0.5, 0, 1)
    lo, hi = channels[idx[0]].value_range
    x = (x - lo) / max(hi - lo, 1e-12)
    if x.shape[-1] == 3:
        return np.clip(x, 0, 1)
    return np.clip(np.repeat(x[..., :1], 3, -1), 0, 1)


def _error(ref: np.ndarray, dec: np.ndarray, idx: list[int], channels: Sequence[Channel]) -> np.ndarray:
    peaks = np.array([channels[i].peak for i in idx], np.float32)
    return np.abs((dec[..., idx] - ref[..., idx]) / peaks).mean(-1)


def _psnr(ref: np.ndarray, dec: np.ndarray, channels: Sequence[Channel]) -> float:
    peaks = np.array([c.peak for c in channels], np.float32)
    mse = float(np.mean(((dec - ref) / peaks) ** 2))
    return 10 * math.log10(1 / mse) if mse > 0 else float("inf")


def crop_figure(path: Path, title: str, channels: Sequence[Channel], ref: np.ndarray,
                methods: Sequence[tuple[str, np.ndarray]]) -> dict[str, float]:
    """Write the crop figure to ``path``: one row per channel group, columns reference, each
    method, then each method's error |dec - ref| / peak on one colour scale per row. Returns
    each method's PSNR over the crop."""
    require("matplotlib", "bench", "bcfpipe bench's figures").use("Agg")
    import matplotlib.pyplot as plt  # lazy: start-up

    rows = _rows(channels)
    cols = 1 + 2 * len(methods)
    fig, axes = plt.subplots(len(rows), cols, figsize=(2.1 * cols, 2.2 * len(rows) + 0.5), dpi=110, squeeze=False)
    psnrs = {name: _psnr(ref, dec, channels) for name, dec in methods}
    for r, (sem, idx, kind) in enumerate(rows):
        errs = [_error(ref, dec, idx, channels) for _, dec in methods]
        vmax = max(float(np.percentile(np.concatenate([e.ravel() for e in errs]), 99.5)), 1e-6)
        panels = [("reference", _display(ref, idx, kind, channels), None)]
        panels += [(name, _display(dec, idx, kind, channels), None) for name, dec in methods]
        panels += [(f"error {name}", e, vmax) for (name, _), e in zip(methods, errs)]
        for c, (label, img, vm) in enumerate(panels):
            ax = axes[r][c]
            if vm is None:
                ax.imshow(img, interpolation="nearest")
            else:
                im = ax.imshow(img, cmap="inferno", vmin=0, vmax=vm, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(label if c == 0 or vm is not None else f"{label}\n{psnrs[label]:.2f} dB",
                             fontsize=7)
            if c == 0:
                ax.set_ylabel(sem, fontsize=8)
        fig.colorbar(im, ax=axes[r][-1], fraction=0.046, pad=0.04).ax.tick_params(labelsize=6)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return psnrs
