"""One bench cell: a BCf (profile, preset) or a classic baseline, measured with the same metric code.

A BCf cell trains, exports, and is measured from the exported files (BC6H DDS + fp16 decoder
through onnxruntime), as `bcfpipe train` does. A baseline cell encodes and decodes every mip of
the texture set with a classic codec (bcfpipe.texset.baselines). Both keep what the report needs
beyond the metrics: a lod sweep and the decoded texels of the crop windows.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from bcfpipe.formats.vocabulary import Wrap
from bcfpipe.bench import lod_sweep as L
from bcfpipe.texset.baselines import encode_texture_set_baseline
from bcfpipe.texset.texture_set import TextureSet
from bcfpipe.texset.metrics import Metrics, compute_metrics

__all__ = ["Baseline", "Cell", "baseline_grid", "measure_baseline", "train_cell", "Windows"]

# (mip, x, y, side) of each crop window; a cell keeps its decoded texels there
Windows = Sequence[tuple[int, int, int, int]]
CURVE_POINTS = 200


@dataclass(frozen=True)
class Baseline:
    """A classic encoding of the set: ``codec`` 'bc' (BC1/BC4/BC5 as an engine packs the set) or
    'astc' with ``block``, at the set's resolution divided by 2**``shift``."""

    codec: str
    block: str | None
    shift: int

    def label(self, side: int) -> str:
        name = "BC" if self.codec == "bc" else f"ASTC {self.block}"
        return f"{name} @{side >> self.shift}"


def baseline_grid(codecs: Sequence[str], astc_blocks: Sequence[str], shifts: Sequence[int]) -> list[Baseline]:
    """Every requested codec at every resolution step: BC once, ASTC once per block size."""
    out = []
    for shift in shifts:
        for codec in codecs:
            blocks = astc_blocks if codec == "astc" else (None,)
            out.extend(Baseline(codec, b, shift) for b in blocks)
    return out


@dataclass
class Cell:
    """A measured cell; ``json`` is what the report and its data file keep."""

    method: str
    kind: str  # "bcf", "bc" or "astc"
    metrics: Metrics
    size_bytes: int
    seconds: float  # BCf: training wall time; baselines: encode + decode
    sweep: list[float]
    crops: list[np.ndarray]  # one (side, side, c) array per window
    extra: dict = field(default_factory=dict)
    textures: list | None = None  # a BC baseline's blocks, for the decode-cost pass
    folder: Path | None = None  # a BCf cell's exported material

    def to_json(self) -> dict:
        m = self.metrics
        return {"method": self.method, "kind": self.kind, **self.extra, "size_bytes": self.size_bytes,
                "size_mib": self.size_bytes / 2**20, "psnr": m.psnr, "psnr_per_mip": list(m.psnr_per_mip),
                "psnr_per_group": dict(m.psnr_per_group), "ssim": m.ssim, "flip": m.flip, "seconds": self.seconds,
                "lod_sweep": self.sweep}


def _crops(mips: Sequence[np.ndarray], windows: Windows) -> list[np.ndarray]:
    return [np.array(mips[k][y:y + n, x:x + n]) for k, x, y, n in windows]


def measure_baseline(ts: TextureSet, ref: Sequence[np.ndarray], b: Baseline, grid: L.LodGrid, windows: Windows,
                     tmp_dir: str | None = None) -> Cell:
    """Encode and decode every mip with baseline ``b``; metrics, lod sweep and crops of the result."""
    side = max(ts.width, ts.height)
    textures: list | None = [] if b.codec == "bc" and b.shift == 0 else None
    t0 = time.perf_counter()
    dec, size = encode_texture_set_baseline(ts, b.codec, side >> b.shift, ref_mips=ref,
                                            astc_block=b.block or "12x12", textures=textures, tmp_dir=tmp_dir)
    seconds = time.perf_counter() - t0
    metrics = compute_metrics(ref, dec, ts.channels)
    sweep = L.sweep(grid, L.mips_answer(dec, grid.wrap))
    extra = {"codec": b.codec, "block": b.block, "resolution": side >> b.shift,
             "encoder": "quicktex (BC1 level 18, BC4, BC5)" if b.codec == "bc" else "astcenc -thorough, LDR linear"}
    return Cell(b.label(side), b.codec, metrics, size, seconds, sweep, _crops(dec, windows), extra, textures)


def train_cell(ts: TextureSet, ref: Sequence[np.ndarray], options, out_dir: Path, grid: L.LodGrid,
               windows: Windows, *, wrap: str = Wrap.REPEAT, progress: Callable[[float], None] | None = None) -> Cell:
    """Train BCf as ``options`` (a `config.TrainingOptions` with its profile, preset and features;
    all neural) ask into ``out_dir``; measure the exported files. A bc7 cell's method name ends in
    " bc7"."""
    from bcfpipe.export import writer as E
    from bcfpipe.fit import fit

    preset, features = options.preset, options.features.value
    curve: list[tuple[float, float]] = []

    def on_progress(p) -> None:
        if np.isfinite(p.psnr):
            curve.append((round(p.elapsed, 2), round(p.psnr, 3)))
        if progress is not None and p.steps:
            progress(min(1.0, (p.elapsed / max(p.elapsed + p.eta, 1e-9))))

    res = fit(ts, options, out_dir, wrap=wrap, progress=on_progress).result
    name = res.profile
    dec = E.decode_mips(E.load(out_dir), [m.shape[:2] for m in ref])
    crops = _crops(dec, windows)
    del dec
    sweep = L.sweep(grid, L.exported_answer(out_dir))
    step = max(1, len(curve) // CURVE_POINTS)
    extra = {"profile": name, "preset": preset, "features": features, "resolutions": list(res.resolutions), "device": res.device,
             "train_seconds": res.train_seconds,
             "float_psnr": res.float_metrics.psnr if res.float_metrics is not None else None,
             "training_curve": curve[::step] + ([curve[-1]] if curve and (len(curve) - 1) % step else [])}
    return Cell(f"BCf {name} {preset}" + ("" if features == "bc6h" else f" {features}"), "bcf", res.metrics, res.size_bytes, res.train_seconds, sweep, crops,
                extra, folder=Path(out_dir))
