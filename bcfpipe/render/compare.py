"""Frames as pictures: sRGB 8-bit encoding, a difference heat map, the side-by-side comparison
image and its numbers (measured on the 8-bit sRGB pixels a viewer sees)."""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from bcfpipe.formats.atomic import write_atomically

__all__ = ["Difference", "difference", "to_srgb8", "heat_map", "side_by_side", "write_png", "BACKGROUND"]

BACKGROUND = (0.05, 0.05, 0.055)  # linear, where nothing was drawn
GAP = 8  # pixels between the panels of a comparison

#: Heat map stops (|difference| in 8-bit sRGB levels -> colour): black, blue, red, yellow, white.
HEAT_STOPS = np.array([0.0, 4.0, 12.0, 32.0, 64.0])
HEAT_COLOURS = np.array([[0, 0, 0], [40, 40, 200], [220, 40, 30], [250, 210, 40], [255, 255, 255]], np.float64)


def to_srgb8(frame: np.ndarray) -> np.ndarray:
    """(H, W, 4) linear rgb + coverage -> (H, W, 3) uint8 sRGB over :data:`BACKGROUND`."""
    rgb = np.where(frame[..., 3:4] > 0, frame[..., :3], np.asarray(BACKGROUND, np.float32))
    rgb = np.clip(np.nan_to_num(rgb, nan=0.0), 0.0, 1.0)
    enc = np.where(rgb <= 0.0031308, rgb * 12.92, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
    return np.clip(np.rint(enc * 255), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class Difference:
    """Neural against original over the pixels either frame covers, in 8-bit sRGB levels."""

    psnr: float  # dB, over rgb (inf when identical)
    mean_abs: float
    p99_abs: float  # 99th percentile of the per-pixel mean |difference|
    max_abs: float
    pixels: int

    def to_dict(self) -> dict[str, float | int]:
        return {"psnr_db": round(self.psnr, 3) if np.isfinite(self.psnr) else None,
                "mean_abs_8bit": round(self.mean_abs, 4), "p99_abs_8bit": round(self.p99_abs, 3),
                "max_abs_8bit": round(self.max_abs, 3), "pixels": self.pixels}


def difference(a: np.ndarray, b: np.ndarray) -> tuple[Difference, np.ndarray]:
    """(numbers, per-pixel mean |a - b| over rgb in 8-bit levels) of two float frames."""
    covered = (a[..., 3] > 0) | (b[..., 3] > 0)
    d = np.abs(to_srgb8(a).astype(np.float64) - to_srgb8(b).astype(np.float64))
    per_pixel = d.mean(axis=2)
    sel = d[covered]
    n = int(covered.sum())
    if n == 0:
        return Difference(float("inf"), 0.0, 0.0, 0.0, 0), per_pixel
    mse = float((sel ** 2).mean())
    psnr = float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)
    pp = per_pixel[covered]
    return Difference(psnr, float(pp.mean()), float(np.percentile(pp, 99)), float(sel.max()), n), per_pixel


def heat_map(per_pixel: np.ndarray) -> np.ndarray:
    """Per-pixel |difference| (8-bit levels) -> (H, W, 3) uint8 with the :data:`HEAT_STOPS` scale."""
    out = np.empty(per_pixel.shape + (3,), np.float64)
    for c in range(3):
        out[..., c] = np.interp(per_pixel, HEAT_STOPS, HEAT_COLOURS[:, c])
    return np.rint(out).astype(np.uint8)


def side_by_side(*panels: np.ndarray) -> np.ndarray:
    """Panels of one height left to right, :data:`GAP` white pixels apart."""
    h = panels[0].shape[0]
    gap = np.full((h, GAP, 3), 255, np.uint8)
    parts = []
    for i, p in enumerate(panels):
        parts += ([gap] if i else []) + [p]
    return np.concatenate(parts, axis=1)


def write_png(path: str | os.PathLike, rgb8: np.ndarray) -> None:
    """An 8-bit sRGB PNG, written through a temporary sibling and a rename (no partial file)."""
    import OpenImageIO as oiio  # lazy: start-up

    h, w, c = rgb8.shape
    spec = oiio.ImageSpec(w, h, c, oiio.UINT8)

    def write(tmp) -> None:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise OSError(f"{os.fspath(path)}: cannot write PNG ({oiio.geterror()})")
        try:
            out.write_image(np.ascontiguousarray(rgb8))
        finally:
            out.close()

    write_atomically(path, write, suffix=".png")
