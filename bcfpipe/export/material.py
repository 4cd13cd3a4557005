"""One material end to end: train, export, and measure the exported files (not the float state)."""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from bcfpipe.formats.sizes import disk_bytes
from bcfpipe.formats.vocabulary import Wrap
from bcfpipe.export import writer as E
from bcfpipe.formats import material as mf
from bcfpipe.config import TrainConfig, TrainingOptions
from bcfpipe.texset.chain import Reference
from bcfpipe.texset.metrics import Metrics, metrics_and_errors, metrics_from_mse
from bcfpipe.texset.texture_set import Channel, TextureSet
from bcfpipe.train.devices import device_name
from bcfpipe.train.progress import Progress, ProgressFn

if TYPE_CHECKING:
    from bcfpipe.train.trainer import TrainedMaterial

# The metrics after the decode, in units of the decode's own time, for the evaluation's ETA: PSNR
# and per-channel errors alone (0.38-0.39 at 1024² and 2048² x 8 channels, tiny), and with SSIM and
# FLIP at mip 0 (0.42-0.63 of a neural decode, 1.42-1.52 of BC@R's, the water bottle's 2048² x 11
# channels; benchmarks/bench_evaluate_eta.py), on a 2-core CPU (docs/benchmarks.md, issue 58)
METRICS_PER_DECODE = {False: 0.4, True: 1.0}


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
    return options.train_config(max(ts.width, ts.height), wrap, device_name(options.device), ts.num_channels)


def shipped_files(out_dir: Path) -> list[Path]:
    """The files a renderer loads: the feature textures, the weight record and any classic textures
    (not the ONNX decoder or material.json)."""
    desc = mf.read(out_dir)
    return [Path(out_dir) / f for f in desc.files if f != (desc.onnx.file if desc.onnx else None)]


def shipped_disk_bytes(out_dir: Path) -> int:
    """`shipped_files` on disk, each zstd-compressed (`formats.sizes.disk_bytes`)."""
    return disk_bytes([p.read_bytes() for p in shipped_files(out_dir)])


def exported_size(out_dir: Path) -> int:
    """Bytes a renderer loads (`shipped_files`)."""
    return sum(p.stat().st_size for p in shipped_files(out_dir))


class EvaluateProgress:
    """The ``evaluate`` phase as steps: one per mip decoded, then one for the metrics, with an ETA
    (the decode's rate so far over the texels left, plus `METRICS_PER_DECODE` of the decode's
    time for the metrics). Reports at most every ``every`` seconds, and at each step."""

    def __init__(self, progress: ProgressFn | None, shapes, image_metrics: bool = True,
                 start: float | None = None, every: float = 1.0):
        self.progress, self.every = progress, every
        self.texels = [h * w for h, w in shapes]
        self.ratio = METRICS_PER_DECODE[bool(image_metrics)]
        self.start = time.perf_counter() if start is None else start  # the run's start: elapsed counts from it
        self.t0 = time.perf_counter()
        self.done, self.last = 0, float("-inf")

    @property
    def steps(self) -> int:
        return len(self.texels) + 1

    def _send(self, step: int, steps: int, eta: float) -> None:
        now = time.perf_counter()
        self.last = now
        if self.progress:
            self.progress(Progress("evaluate", step, steps, float("nan"), float("nan"), now - self.start, eta))

    def begin(self) -> None:
        """Evaluation starts: no rate yet, so no step count and no ETA."""
        self._send(0, 0, 0.0)

    def _decode_seconds(self) -> float:
        """The whole decode's seconds, estimated from its rate so far."""
        spent = time.perf_counter() - self.t0
        return spent * sum(self.texels) / max(self.done, 1)

    def chunk(self, k: int, texels: int) -> None:
        """`bcfpipe.export.writer.decode_mips`' ``on_chunk``."""
        self.done += texels
        finished = sum(self.texels[:k + 1]) == self.done
        if finished or time.perf_counter() - self.last >= self.every:
            total = self._decode_seconds()
            spent = time.perf_counter() - self.t0
            self._send(k + 1 if finished else k, self.steps, max(0.0, total - spent) + self.ratio * total)

    def metrics(self) -> None:
        """The decode is done; the metrics start."""
        self._send(len(self.texels), self.steps, self.ratio * (time.perf_counter() - self.t0))

    def end(self) -> None:
        self._send(self.steps, self.steps, 0.0)


@dataclass(frozen=True)
class Evaluation:
    """An exported folder measured against its set's reference."""

    metrics: Metrics
    per_channel: np.ndarray  # (mips, channels) MSE (`mse_per_channel`)
    decoded: list[np.ndarray]  # (H_k, W_k, c) per mip, as `bcfpipe.export.writer.decode_mips` returns


# A sampled measure (the layout's probe) decodes, of a mip of more texels than `SAMPLED_TEXELS`, one
# texel in each k×k cell, at a place drawn per cell (fixed seed), k = 2, or 4 where a quarter would
# still be more than `SAMPLED_MOST` texels: spread over the mip and over the places within a BC block
# and a magnified texel, whose errors differ. Whole rows would not do: on the teapot they missed
# mip 0's error by 0.36 dB. A 2048² set's probe decodes 0.9 M texels, where a quarter of its mips
# over 1 M texels (2.4 M) took 2.1 s of its 10 (benchmarks/bench_probe_sample.py).
SAMPLED_TEXELS = 1 << 18
SAMPLED_MOST = 1 << 18
SAMPLE_SEED = 58


def sample_cell(h: int, w: int, above: int, most: int | None = None) -> int:
    """The side of the cells of a (h, w) mip of which a sampled measure decodes one texel each: 1 (every
    texel) at ``above`` texels or fewer; else 2, or 4 where a quarter is more than ``most``."""
    if h * w <= above:
        return 1
    return 4 if most is not None and (h // 2) * (w // 2) > most and h % 4 == 0 and w % 4 == 0 else 2


def sampled_texels(shapes: Sequence[tuple[int, int]], above: int = SAMPLED_TEXELS,
                   most: int | None = SAMPLED_MOST) -> list[np.ndarray | None]:
    """Per mip, the texels a sampled measure decodes (`sample_cell`), row-major indices, cell by
    cell in row-major order (None: all)."""
    out: list[np.ndarray | None] = []
    rng = np.random.default_rng(SAMPLE_SEED)
    for h, w in shapes:
        k = sample_cell(h, w, above, most)
        if k == 1:
            out.append(None)
            continue
        cy, cx = np.mgrid[0:h // k, 0:w // k]
        dy, dx = rng.integers(0, k, (2,) + cy.shape)
        out.append(((k * cy + dy) * w + k * cx + dx).ravel())
    return out


def evaluate_exported(folder: str | os.PathLike, reference: Reference, channels: tuple[Channel, ...],
                      progress: ProgressFn | None = None, image_metrics: bool = True,
                      start: float | None = None, sampled: bool = False) -> Evaluation:
    """Decode ``folder`` at every mip of ``reference`` and measure it (over ``reference.masks``'
    texels too, when it has masks), reporting ``evaluate`` step by step to ``progress``
    (`EvaluateProgress`; elapsed from ``start``, a `time.perf_counter` reading). ``sampled``: of
    the mips over `SAMPLED_TEXELS`, a sixteenth or a quarter of the texels (`sampled_texels`), for
    figures that decide rather than ship (no image metrics then; ``decoded`` holds those texels, one
    per k×k cell in the cells' order, (H/k, W/k, c))."""
    shapes = reference.shapes
    picks = sampled_texels(shapes, SAMPLED_TEXELS, SAMPLED_MOST) if sampled else [None] * len(shapes)
    image_metrics = image_metrics and not sampled
    cells = [(h // k, w // k) for h, w in shapes
             for k in [sample_cell(h, w, SAMPLED_TEXELS, SAMPLED_MOST) if sampled else 1]]

    def taken(levels):
        return [m if p is None else m.reshape(-1, *m.shape[2:])[p].reshape(*c, *m.shape[2:])
                for m, p, c in zip(levels, picks, cells)]

    ep = EvaluateProgress(progress, cells, image_metrics, start)
    ep.begin()
    dec = E.decode_mips(E.load(folder), shapes, on_chunk=ep.chunk if progress else None, texels=picks)
    dec = [d if p is None else d.reshape(*c, -1) for d, p, c in zip(dec, picks, cells)]
    ep.metrics()
    ref = taken(reference.mips)
    masks = None if reference.masks is None else taken(reference.masks)
    metrics, per_channel = metrics_and_errors(ref, dec, channels, masks=masks, ssim=image_metrics, flip=image_metrics)
    ep.end()
    return Evaluation(metrics, per_channel, dec)


@dataclass(frozen=True)
class Measure:
    """What `train_material` measures of the files it exports."""

    image_metrics: bool = True  # SSIM and FLIP (seconds at 2048²)
    float_model: bool = True  # the float model's figures just before quantization (a decode of every mip)
    sampled: bool = False  # the large mips on a sample of their texels (`evaluate_exported`)


# PSNR and per-channel errors: a layout candidate's; not the float model's, which the layout's
# report does not carry (a decode of every mip on the training's threads: 2.9-3.1 s for the water
# bottle's 2048² x 11 channels at 1k and 2k, measured)
FIGURES = Measure(image_metrics=False, float_model=False)
PROBE = Measure(image_metrics=False, float_model=False, sampled=True)  # what decides, never ships


def train_material(ts: TextureSet, out_dir: str | os.PathLike, cfg: TrainConfig, profile: str = "",
                 progress: ProgressFn | None = None, coverage: np.ndarray | None = None,
                 measure: Measure = Measure(), reference: Reference | None = None) -> tuple[MaterialResult, TrainedMaterial]:
    """Train on ``ts``, export to ``out_dir``, then evaluate the exported files (over every texel,
    and with a ``coverage`` mask also over the covered ones). ``progress`` hears the training's
    phases, then ``evaluate`` step by step (`EvaluateProgress`). ``measure``: `FIGURES` for a model
    judged by its PSNR and per-channel errors alone, as a layout's candidates; `PROBE` for the
    layout's probe, which never ships (`Measure`). ``reference``: ``Reference.of(ts, coverage, cfg.model.wrap)`` when
    the caller holds it already (the training and the measure share it), else built here once."""
    from bcfpipe.train.trainer import train  # lazy: start-up

    start = time.perf_counter()
    if reference is None:
        reference = Reference.of(ts, coverage, cfg.model.wrap)
    else:
        reference.check(ts, coverage, cfg.model.wrap)
    tm = train(ts, cfg, progress, coverage=coverage, reference=reference, measure_float=measure.float_model)
    out = E.export(tm, out_dir)
    t0 = time.perf_counter()
    float_metrics = (metrics_from_mse(tm.float_mse, ts.channels, reference.shapes)
                     if tm.float_mse is not None else None)
    ev = evaluate_exported(out, reference, ts.channels, progress, measure.image_metrics, start, measure.sampled)
    metrics, per_channel = ev.metrics, ev.per_channel
    del ev
    phases = dict(tm.phase_seconds, evaluate=time.perf_counter() - t0)
    res = MaterialResult(out, profile, cfg.model.resolutions, cfg.preset_name, cfg.device, metrics, float_metrics,
                         exported_size(out), tm.train_seconds, {k: round(v, 3) for k, v in phases.items()},
                         dict(tm.phase_samples), per_channel, t0_layers=cfg.model.t0_layers)
    return res, tm
