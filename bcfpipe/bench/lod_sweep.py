"""PSNR over a continuous lod s (the paper's learnfilter figure), for any method.

At each s the target is F(M)(u, v, s), bicubic in mips floor(s) and floor(s)+1 lerped by frac(s):
exactly the training target (bcfpipe.texset.reference). A method answers the same query at the
same points: an exported BCf material through its BC6H features and fp16 decoder (onnxruntime),
or a mip chain (the reference's own, or a baseline's decoded mips) through the hardware trilinear
filter. The points are one fixed set of uniformly random uv, the same for every s, so a curve
measures only the change of scale.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from bcfpipe.export import writer as E
from bcfpipe.model.decoder import ONNX_INPUT, ONNX_OUTPUT, normal_xy_index
from bcfpipe.texset.reference import ReferencePyramid, sample_reference
from bcfpipe.model.sampling import sample_trilinear

__all__ = ["LodGrid", "Answer", "exported_answer", "mips_answer", "sweep", "dips"]

Answer = Callable[[np.ndarray, float], np.ndarray]  # (uv (n, 2), s) -> (n, c) set values


class LodGrid:
    """The sweep's s values, its points and the targets there, computed once for every method."""

    def __init__(self, ref: ReferencePyramid, wrap: str, peaks: Sequence[float], step: float = 0.25,
                 points: int = 1 << 16, seed: int = 0):
        s_max = ref.num_levels - 1
        self.s = [float(s) for s in np.linspace(0, s_max, int(round(s_max / step)) + 1)]
        self.uv = np.random.default_rng(seed).random((points, 2), dtype=np.float32)
        self.wrap = wrap
        self.peaks = np.asarray(peaks, np.float32)
        uv = torch.from_numpy(self.uv)
        self.targets = [sample_reference(ref, uv, s, wrap).numpy() for s in self.s]


def exported_answer(folder: str | Path) -> Answer:
    """An exported material's answer: BC6H features sampled as hardware does, fp16 decoder (ONNX)."""
    em = E.load(folder)
    sess = E.onnx_session(em)
    nz = normal_xy_index(em.kinds)

    def answer(uv: np.ndarray, s: float) -> np.ndarray:
        y = sess.run([ONNX_OUTPUT], {ONNX_INPUT: E.sample_exported_features(em, uv, float(s))})[0]
        return np.delete(y, nz + 2, axis=1) if nz is not None else y

    return answer


def mips_answer(mips: Sequence[np.ndarray], wrap: str) -> Answer:
    """The answer of (H, W, c) mips through the trilinear filter (a GPU's mipmapped texture)."""
    levels = [torch.from_numpy(np.ascontiguousarray(np.moveaxis(np.asarray(m, np.float32), -1, 0))) for m in mips]

    def answer(uv: np.ndarray, s: float) -> np.ndarray:
        return sample_trilinear(levels, torch.from_numpy(uv), float(s), wrap).numpy()

    return answer


def sweep(grid: LodGrid, answer: Answer) -> list[float]:
    """PSNR (dB, errors relative to each channel's peak) of ``answer`` at every s of ``grid``."""
    out = []
    for s, target in zip(grid.s, grid.targets):
        y = answer(grid.uv, s)
        mse = float(np.mean(((y - target) / grid.peaks) ** 2))
        out.append(float(10 * np.log10(1 / mse)) if mse > 0 else float("inf"))
    return out


def dips(s: Sequence[float], psnr: Sequence[float], exact: float = 100.0) -> list[tuple[float, float]]:
    """(s, dB below the mean of the two neighbouring values) for every inner s. Triples touching a
    value above ``exact`` dB are left out (trilinear is exact at the 1x1 mip, up to rounding)."""
    p = list(psnr)
    return [(s[i], (p[i - 1] + p[i + 1]) / 2 - p[i]) for i in range(1, len(p) - 1)
            if max(p[i - 1], p[i], p[i + 1]) < exact]
