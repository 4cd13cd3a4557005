"""One material end to end: train, export, and measure the exported files (not the float state)."""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bcfpipe.formats.vocabulary import Wrap
from bcfpipe.export import writer as E
from bcfpipe.formats import material as mf
from bcfpipe.config import TrainConfig, TrainingOptions
from bcfpipe.texset.metrics import Metrics, compute_metrics, metrics_from_mse, mse_per_channel
from bcfpipe.texset.texture_set import TextureSet, build_mip_chain
from bcfpipe.train.trainer import Progress, ProgressFn, TrainedMaterial, resolve_device, train


@dataclass(frozen=True)
class MaterialResult:
    """What a trained and exported material measured."""

    out_dir: Path
    profile: str
    resolutions: tuple[int, ...]
    preset: str
    device: str
    metrics: Metrics  # of the exported files (BC6H DDS + fp16 weights through onnxruntime)
    float_metrics: Metrics | None  # of the float model just before quantization (phase 3)
    size_bytes: int
    train_seconds: float
    phase_seconds: dict[str, float]
    phase_samples: dict[str, int] | None = None
    mse_per_channel: np.ndarray | None = None  # (mips, channels) of the exported files (bcfpipe.layout)
    layout: dict | None = None  # --layout auto: the decision (bcfpipe.layout.choose.Decision.to_json)
    t0_layers: int = 1  # layers of principal components its fixed T_0 holds (ModelConfig.t0_layers)

    def to_dict(self) -> dict:
        m = self.metrics
        d = {"psnr": m.psnr, "ssim": m.ssim, "flip": m.flip, "size_bytes": self.size_bytes,
             "size_mib": self.size_bytes / 2**20, "train_seconds": self.train_seconds,
             "out": str(self.out_dir), "profile": self.profile, "resolutions": list(self.resolutions),
             "preset": self.preset, "device": self.device, "phase_seconds": self.phase_seconds,
             "phase_samples": self.phase_samples, "t0_layers": self.t0_layers,
             "metrics": m.to_json()}
        if self.float_metrics is not None:
            d["float_psnr"] = self.float_metrics.psnr
            d["quantization_loss_db"] = self.float_metrics.psnr - m.psnr
        if self.layout is not None:
            d["layout"] = self.layout
        return d


def make_config(ts: TextureSet, options: TrainingOptions, wrap: str = Wrap.REPEAT) -> tuple[str, TrainConfig]:
    """The TrainConfig of ``options`` (validated when it was made) for ``ts``, on the device it
    names resolved here; returns the resolved profile name too (``auto`` picks from the set's size)."""
    return options.train_config(max(ts.width, ts.height), wrap, str(resolve_device(options.device)), ts.num_channels)


def shipped_files(out_dir: Path) -> list[Path]:
    """The files a renderer loads: the feature textures, the weight record and any classic textures
    (not the ONNX decoder or material.json)."""
    desc = mf.read(out_dir)
    return [Path(out_dir) / f for f in desc.files if f != (desc.onnx.file if desc.onnx else None)]


def shipped_disk_bytes(out_dir: Path) -> int:
    """`shipped_files` on disk, each zstd-compressed (`formats.sizes.disk_bytes`)."""
    from bcfpipe.formats.sizes import disk_bytes

    return disk_bytes([p.read_bytes() for p in shipped_files(out_dir)])


def exported_size(out_dir: Path) -> int:
    """Bytes a renderer loads (`shipped_files`)."""
    return sum(p.stat().st_size for p in shipped_files(out_dir))


def fit_material(ts: TextureSet, out_dir: str | os.PathLike, cfg: TrainConfig, profile: str = "",
                 progress: ProgressFn | None = None, coverage: np.ndarray | None = None,
                 image_metrics: bool = True) -> tuple[MaterialResult, TrainedMaterial]:
    """Train on ``ts``, export to ``out_dir``, then evaluate the exported files (over every texel,
    and with a ``coverage`` mask also over the covered ones). ``progress`` hears the training's
    phases, then ``evaluate``. ``image_metrics=False`` leaves out SSIM and FLIP (seconds at 2048²)
    for a model that is judged by its PSNR and per-channel errors alone, as the layout's probe."""
    start = time.perf_counter()
    tm = train(ts, cfg, progress, coverage=coverage)
    out = E.export(tm, out_dir)
    if progress:
        progress(Progress("evaluate", 0, 0, float("nan"), float("nan"), time.perf_counter() - start, 0.0))
    t0 = time.perf_counter()
    ref = build_mip_chain(ts.data)
    float_metrics = (metrics_from_mse(tm.float_mse, ts.channels, [m.shape[:2] for m in ref])
                     if tm.float_mse is not None else None)
    em = E.load(out)
    dec = E.decode_mips(em, [m.shape[:2] for m in ref])
    masks = None
    if coverage is not None:
        from bcfpipe.scan.coverage import mask_mips

        masks = mask_mips(coverage, len(ref), cfg.model.wrap)
    metrics = compute_metrics(ref, dec, ts.channels, masks=masks, ssim=image_metrics, flip=image_metrics)
    per_channel = mse_per_channel(ref, dec, ts.channels, masks)
    del dec
    phases = dict(tm.phase_seconds, evaluate=time.perf_counter() - t0)
    res = MaterialResult(out, profile, cfg.model.resolutions, cfg.preset_name, cfg.device, metrics, float_metrics,
                         exported_size(out), tm.train_seconds, {k: round(v, 3) for k, v in phases.items()},
                         dict(tm.phase_samples), per_channel, t0_layers=cfg.model.t0_layers)
    return res, tm
