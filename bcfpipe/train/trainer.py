"""Training schedule (paper §5.1, §6.1): warm-up, BC init + constrained, quantize, MLP fine-tune.

  (T_0)    with --t0 pca (bc7's default) T_0 is the set's principal components, BC7-encoded once
           and fixed through every phase (bcfpipe.train.fixed_t0), kept apart from the layers the
           phases train (`bcfpipe.model.features.Layers`)
  phase 1  warmup       free features + MLP, Adam (lr_f, lr_m), exponential decay
  phase 2  constrained  features re-initialised by encoding the warm features (BC6H: this picks
                        every block's partition), then endpoints/indices trained through the
                        differentiable emulation of the feature format (bcfpipe.model.features)
  phase 3  quantize     endpoints and indices rounded to the format's bits, then frozen
  phase 4  finetune     MLP only, on the frozen exact features

Every step runs through the run's backend (bcfpipe.train.backend: torch's autograd or the fused
kernel), chosen once where the run starts. One call trains one material. It touches no global
state except torch's thread count when ``TrainConfig.threads`` is set (workers of a parallel build
each own a process).
"""
from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass, field
from dataclasses import replace
from typing import Callable, Iterator

import numpy as np
import torch

from bcfpipe.model import neural as M
from bcfpipe.config import ModelConfig, TrainConfig
from bcfpipe.errors import InputError
from bcfpipe.formats.vocabulary import T0
from bcfpipe.model.features import BlockParams, FixedLevel, Layers, QuantizedLevel, codec_of
from bcfpipe.model.decoder import MlpWeights
from bcfpipe.train.adam import DecayedAdam
from bcfpipe.train.backend import Step, StepBackend, make_backend
from bcfpipe.train.feature_init import pca_init
from bcfpipe.train.fixed_t0 import pca_t0
from bcfpipe.train.pace import Pace, Pacer
from bcfpipe.train.progress import Progress, ProgressFn
from bcfpipe.texset.reference import CentreTargets, ReferencePyramid, random_batch
from bcfpipe.texset import encoding
from bcfpipe.texset.chain import Reference
from bcfpipe.texset.texture_set import TextureSet





BlockLevel = QuantizedLevel  # one mip of one layer as the exact block parameters that are written
# (a layer encoded once, a T_0 of principal components, is `Layers.fixed`: FixedLevels)


@dataclass
class TrainedMaterial:
    """The result of :func:`train`: exact block parameters, the decoder, and what happened."""

    config: TrainConfig
    texture_set: TextureSet
    layers: Layers[BlockLevel]
    mlp: MlpWeights  # fp16-rounded
    lod_biases: tuple[float, ...]
    phase_seconds: dict[str, float]
    float_mse: np.ndarray | None = None  # (mips, channels): the float model's squared error before phase 3
    history: list[tuple[str, int, float]] = field(default_factory=list)
    phase_samples: dict[str, int] = field(default_factory=dict)  # training samples drawn per phase

    @property
    def kinds(self) -> tuple[str, ...]:
        return tuple(c.kind for c in self.texture_set.channels)

    @property
    def train_seconds(self) -> float:
        return sum(self.phase_seconds.values())


def resolve_device(name: str) -> torch.device:
    """'auto' -> cuda when available, else cpu; 'cuda' without CUDA is an error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError("--device cuda requested but torch has no CUDA device")
    return torch.device(name)


def _optimizer(feature_params, mlp_params, sched, device) -> DecayedAdam:
    """Adam over the features (when the step does not update them itself) and the MLP, each at its
    own decayed rate (`TrainConfig`'s schedule)."""
    groups, rates, gammas = [mlp_params], [sched.lr_mlp], [sched.gamma_mlp]
    if feature_params:
        groups.insert(0, feature_params)
        rates.insert(0, sched.lr_features)
        gammas.insert(0, sched.gamma_features)
    return DecayedAdam(groups, rates, gammas, device)


class _Clock:
    """Elapsed time and an ETA from per-phase step rates."""

    def __init__(self, steps: dict[str, int]):
        self.t0 = time.perf_counter()
        self.steps = steps
        self.rate: dict[str, float] = {}

    def eta(self, phase: str, step: int, phase_t0: float) -> float:
        now = time.perf_counter()
        per = (now - phase_t0) / max(step, 1)
        self.rate[phase] = per
        left = (self.steps[phase] - step) * per
        seen = False
        for p, n in self.steps.items():
            if seen:
                left += n * self.rate.get(p, per if p != "finetune" else per * 0.3)
            seen = seen or p == phase
        return left

    def left(self, phase: str) -> float:
        """Seconds left from the start of ``phase`` on, at the step rates measured so far (a phase
        not yet run at the latest one; the fine-tune at 0.3 of it, as `eta` does)."""
        per = list(self.rate.values())[-1] if self.rate else 0.0
        total, seen = 0.0, False
        for p, n in self.steps.items():
            seen = seen or p == phase
            if seen:
                total += n * self.rate.get(p, per if p != "finetune" else per * 0.3)
        return total


def exact_level(bl: BlockLevel, mc: ModelConfig, device) -> torch.Tensor:
    """Bit-exact decoded texels (C, H, W) of quantized block parameters."""
    return M.blocks_to_image(codec_of(mc).exact(bl, mc, device), bl.size, bl.size)


def exact_levels(layers: Layers[BlockLevel], mc: ModelConfig, device) -> list[list[torch.Tensor]]:
    """Every level's bit-exact decoded texels (C, H, W), fixed and quantized, per layer, per mip."""
    return layers.each(lambda lv: M.blocks_to_image(lv.texels(device), lv.size, lv.size),
                       lambda bl, i, k: exact_level(bl, mc, device))


class StratifiedScale:
    """One random s per batch, stratified: every ``strata`` consecutive steps draw u from each of
    ``strata`` equal slices of [0, 1], in random order, and s = s_max * u**power. Each step still
    sees a single s (as in the paper), but every lod range is revisited every few steps, so short
    CPU schedules do not end with some scales under-trained. ``power`` 2 gives the two finest of
    12 mips 41 % of the steps instead of 18 %: they hold most of the texels (issue #9)."""

    def __init__(self, s_max: float, gen: torch.Generator, strata: int = 16, power: float = 1.0,
                 s_min: float = 0.0):
        self.s_max, self.gen, self.strata, self.power, self.s_min = s_max, gen, strata, power, min(s_min, s_max)
        self.order: list[int] = []

    def share(self, s: float) -> float:
        """The share of the scales drawn below ``s``."""
        if self.s_max <= self.s_min:
            return float(s > self.s_min)
        return min(1.0, max(0.0, (s - self.s_min) / (self.s_max - self.s_min))) ** (1.0 / self.power)

    def __call__(self) -> float:
        if not self.order:
            self.order = torch.randperm(self.strata, generator=self.gen).tolist()
        k = self.order.pop()
        u = ((k + float(torch.rand((), generator=self.gen))) / self.strata) ** self.power
        return u * self.s_max if self.s_min == 0 else self.s_min + u * (self.s_max - self.s_min)


def _draws(preset, scale: StratifiedScale, levels: int) -> list[float]:
    """The texels a run of ``preset`` is expected to draw at each of ``levels`` reference mips: its
    steps' samples times the share of its scales s (`StratifiedScale`) with floor(s) = k."""
    samples = (preset.warmup.steps + preset.constrained.steps + preset.finetune.steps) * preset.batch
    return [samples * (scale.share(k + 1) - scale.share(k)) for k in range(levels)]


def evaluate_levels(level_fn: M.LevelFn, mlp: dict[str, torch.Tensor], mc, kinds: tuple[str, ...], biases,
                    ref_shapes, chunk: int = 1 << 18):
    """The float model decoded at every reference mip's texel centres with s = mip index, clamped
    to each channel's range (no normal z): per mip k, its chunks (k, first texel, (n, c) values),
    in the learnt domain; O(chunk) memory, whatever the set's size."""
    with torch.no_grad():
        levels = [[level_fn(i, k).detach() for k in range(n)] for i, n in enumerate(mc.mip_counts)]
    cached = M.cached_level_fn(levels)
    dev = levels[0][0].device
    lo = torch.tensor([-1.0 if t == "normal" else 0.0 for t in kinds], device=dev)
    with torch.no_grad():
        for k, (h, w) in enumerate(ref_shapes):
            for a in range(0, h * w, chunk):  # texel-centre uvs made per chunk: O(chunk) scratch at 8K
                ids = torch.arange(a, min(a + chunk, h * w), device=dev)
                uv = torch.stack([(ids % w + 0.5) / w, (ids // w + 0.5) / h], 1)
                y = M.forward(cached, mlp, mc, biases, uv, float(k))
                yield k, a, torch.maximum(torch.minimum(y, torch.ones_like(lo)), lo)


def float_model_mse(level_fn: M.LevelFn, mlp: dict[str, torch.Tensor], mc, kinds: tuple[str, ...], biases,
                    ref: ReferencePyramid) -> np.ndarray:
    """(mips, channels) squared error of the float model against ``ref``, both in the learnt domain
    (where `bcfpipe.texset.metrics` measures HDR channels), accumulated chunk by chunk: the decoded
    mips are never held (an 8K set's would be 2.7 GiB)."""
    shapes = [tuple(m.shape[1:]) for m in ref.mips]
    total = np.zeros((len(shapes), len(kinds)))
    for k, a, y in evaluate_levels(level_fn, mlp, mc, kinds, biases, shapes):
        r = ref.mips[k].reshape(len(kinds), -1)[:, a:a + y.shape[0]].T
        total[k] += ((y.double() - r.double()) ** 2).sum(0).cpu().numpy()
    return total / np.array([[h * w] for h, w in shapes], np.float64)


@dataclass
class _Run:
    """What the phases of one training share: the model, its reference and how steps sample it."""

    cfg: TrainConfig
    device: torch.device
    backend: StepBackend
    gen: torch.Generator
    ref: ReferencePyramid
    biases: tuple[float, ...]
    mlp: dict[str, torch.Tensor]
    clock: _Clock
    next_s: StratifiedScale
    centres: CentreTargets | None
    mask_levels: list[torch.Tensor] | None
    progress: ProgressFn | None
    pace: Pace
    pacer: Pacer
    seconds: dict[str, float] = field(default_factory=dict)
    samples: dict[str, int] = field(default_factory=dict)
    history: list[tuple[str, int, float]] = field(default_factory=list)

    @property
    def mlp_params(self) -> list[torch.Tensor]:
        return [self.mlp[k] for k in ("w1", "b1", "w2", "b2")]

    @property
    def s_max(self) -> float:
        return float(self.ref.num_levels - 1)


def _batch_at(run: _Run, s: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """uv, targets and per-sample loss weights (None: all 1) of one step at scale s: at precomputed
    texel centres where the reference mip is large (covered ones only), else continuous uv with the
    bicubic lookup, weighted by the coverage of mip floor(s)."""
    batch = run.cfg.preset.batch
    if run.centres is not None and run.centres.covers(s):
        return (*run.backend.centre_batch(run.centres, batch, s, run.gen), None)
    uv, _ = random_batch(batch, run.gen, run.device, run.s_max)
    w = None
    if run.mask_levels is not None:
        m = run.mask_levels[min(int(s), len(run.mask_levels) - 1)]
        h, wd = m.shape
        x = torch.remainder(torch.floor(uv[:, 0] * wd), wd).long()
        y = torch.remainder(torch.floor(uv[:, 1] * h), h).long()
        w = m[y, x].to(uv.dtype)
    return uv, run.backend.sample_reference(run.ref, uv, s, run.cfg.model.wrap), w


def _run_phase(run: _Run, name: str, step: Step, feature_params, sched, project=None, on_step=None) -> None:
    """``sched.steps`` Adam steps of the MSE against the reference (paper §5.1), features then MLP,
    each step's loss and gradients from ``step`` (the run's backend made it)."""
    t0 = time.perf_counter()
    own = step.owns_adam  # the step's own Adam updates the features
    opt = _optimizer([] if own else feature_params, run.mlp_params, sched, run.device)
    ema = None
    for i in range(1, sched.steps + 1):
        if on_step is not None:
            on_step(i)
        s = run.next_s()
        uv, target, weight = _batch_at(run, s)
        run.samples[name] = run.samples.get(name, 0) + uv.shape[0]
        opt.zero_grad()
        val = step(uv, target, weight, s)
        opt.step()
        if own:
            step.adam(sched.lr_features * sched.gamma_features ** (i - 1))  # the same decayed rate
        if project is not None:
            with torch.no_grad():
                project()
        if not math.isfinite(val):
            raise FloatingPointError(f"{name}: loss became {val} at step {i}")
        ema = val if ema is None else 0.9 * ema + 0.1 * val
        on_pace = i % run.pace.every == 0 or i == sched.steps
        if on_pace:
            run.history.append((name, i, ema))
        if run.progress and (on_pace or run.pacer.due()):
            run.pacer.mark()
            run.progress(Progress(name, i, sched.steps, ema, -10 * math.log10(max(ema, 1e-12)),
                                  time.perf_counter() - run.clock.t0, run.clock.eta(name, i, t0)))
    run.seconds[name] = time.perf_counter() - t0


def _report(run: _Run, phase: str, step: int, steps: int, eta: float) -> None:
    """A report without a loss, from a phase that takes no training steps (encode, quantize)."""
    if run.progress:
        run.pacer.mark()
        run.progress(Progress(phase, step, steps, float("nan"), float("nan"), time.perf_counter() - run.clock.t0,
                              eta))


def _warmup(run: _Run) -> Layers[torch.Tensor]:
    """Phase 1: unconstrained features (from noise, or the PCA start) and the MLP; a T_0 of
    principal components (--t0 pca, ``t0_layers`` layers) is encoded here, once, and kept apart as
    fixed layers."""
    mc = run.cfg.model
    layers = M.init_free(mc, run.gen, run.device)
    fixed: dict[int, list[FixedLevel]] = {}
    if run.cfg.t0 == T0.PCA:
        t0 = time.perf_counter()
        fixed = pca_t0(mc, run.ref.mips, run.biases, layers, run.mlp,
                       on_layer=lambda done, n: _report(run, "t0", done, n, run.clock.left("warmup")),
                       profile=run.cfg.t0_bc7)
        run.seconds["t0"] = time.perf_counter() - t0
    elif run.cfg.feature_init == "pca":
        pca_init(mc, run.ref.mips, run.biases, layers, run.mlp)
    free = Layers.of(layers, fixed)
    codec = codec_of(mc)
    lo, hi = codec.param_range(mc)
    step = run.backend.free_step(free)
    params = free.trained_levels()
    first = [True]

    def project() -> None:
        for t in _sampled(params, first):
            t.clamp_(lo, hi)

    _run_phase(run, "warmup", step, params, _scaled(run.cfg.preset.warmup, codec, "warmup"), project=project)
    return free


def _sampled(params: list[torch.Tensor], first: list[bool]) -> list[torch.Tensor]:
    """The parameters a projection must clamp: all of them after a phase's first step, then those
    the step sampled (Adam moves no parameter without a gradient, so the others stay in range)."""
    if first[0]:
        first[0] = False
        return params
    return [t for t in params if t.grad is not None]


def _scaled(sched, codec, phase: str):
    """The phase's schedule with feature learning rates in the format's endpoint units."""
    scale = codec.lr_scale[phase]
    if scale == 1.0:
        return sched

    return replace(sched, lr_features=sched.lr_features * scale)


def _encode(run: _Run, free: Layers[torch.Tensor]) -> Layers[BlockParams]:
    """Phase 2's start: encode the warm features (BC6H: this chooses each block's partition); a
    fixed layer stays as it is."""
    mc = run.cfg.model
    codec = codec_of(mc)
    lo, hi = codec.param_range(mc)
    t0 = time.perf_counter()
    levels, done = sum(len(mips) for mips in free), 0
    lib = run.backend.library()  # the fused kernel's compiled encoder, where it runs natively

    def encode(p: torch.Tensor, i: int, k: int) -> BlockParams:
        nonlocal done
        texels = codec.value(p.clamp(lo, hi), mc).permute(1, 2, 0).cpu().numpy()
        b = codec.encode(texels, mc, run.device, lib)
        done += 1
        if done == levels or run.pacer.due():
            _report(run, "encode", done, levels, run.clock.left("constrained"))
        return b

    _report(run, "encode", 0, levels, run.clock.left("constrained"))
    with torch.no_grad():
        blocks = free.map(encode)
    run.seconds["encode"] = time.perf_counter() - t0
    return blocks


class _QuantizationAware:
    """Whether the constrained phase decodes with rounded parameters (straight-through): on for its
    last ``qat_fraction`` of steps, so that phase 3's rounding costs little."""

    def __init__(self, steps: int, fraction: float):
        self.start, self.on = steps - int(round(fraction * steps)), False

    def step(self, step: int) -> None:
        self.on = step > self.start

    def __call__(self) -> bool:
        return self.on


def _constrained(run: _Run, blocks: Layers[BlockParams]) -> None:
    """Phase 2: the block parameters themselves, kept in the encodable range, with the QAT tail."""
    mc = run.cfg.model
    codec = codec_of(mc)
    sched = _scaled(run.cfg.preset.constrained, codec, "constrained")
    lo, hi = codec.param_range(mc)
    qat = _QuantizationAware(sched.steps, run.cfg.preset.qat_fraction)
    step = run.backend.block_step(blocks, qat)
    feat = [t for b in blocks.trained_levels() for t in (b.endpoints, b.x)]

    first = [True]

    def project() -> None:
        for t in _sampled(feat, first):
            if t.dim() == 3:  # endpoints
                t.clamp_(lo, hi)
            else:
                t.clamp_(0.0, 1.0)

    _run_phase(run, "constrained", step, feat, sched, project=project, on_step=qat.step)


def _quantize(run: _Run, blocks: Layers[BlockParams]) -> tuple[Layers[BlockLevel], list]:
    """Phase 3: round to the format's blocks and freeze; returns them and their exact decoded levels."""
    mc = run.cfg.model
    codec = codec_of(mc)
    t0 = time.perf_counter()
    with torch.no_grad():
        layers = blocks.map(lambda b, i, k: codec.quantize(b, mc, max(4, mc.layer_resolutions[i] >> k)))
        exact = exact_levels(layers, mc, run.device)
    run.seconds["quantize"] = time.perf_counter() - t0
    return layers, exact


def train(ts: TextureSet, cfg: TrainConfig, progress: ProgressFn | None = None,
          pace: Pace = Pace(), measure_float: bool = True, coverage: np.ndarray | None = None,
          reference: Reference | None = None) -> TrainedMaterial:
    """Train one neural material on ``ts`` (see module docstring): warm-up, encode,
    constrained, quantize, MLP fine-tune. ``coverage``: a (H, W) bool mask of the texels the
    scene reads (bcfpipe.scan.coverage); steps then draw their samples there only, which weights
    the loss by the mask. ``reference``: ``ts``'s chain and ``coverage``'s masks when the caller
    holds them already (`Reference.of(ts, coverage, cfg.model.wrap)`), else built here. ``progress``
    is called as ``pace`` says, and as each phase starts."""
    if cfg.model.t0_layers > 1 and cfg.t0 != T0.PCA:
        raise InputError(f"a T_0 of {cfg.model.t0_layers} layers holds fixed principal components: use it with --t0 pca")
    with torch_threads(cfg.threads):
        return _train(ts, cfg, progress, pace, measure_float, coverage, reference)


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """torch's intra-op threads are ``n`` (None: as they are) meanwhile, and what they were after.
    The count is process-wide and reaches beyond torch: FLIP's OpenMP ran on one thread after a
    training left it at 1 (a 2048² colour group 3.1 s against 6.1, measured)."""
    before = torch.get_num_threads()
    if n:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if torch.get_num_threads() != before:
            torch.set_num_threads(before)


def _train(ts: TextureSet, cfg: TrainConfig, progress: ProgressFn | None, pace: Pace, measure_float: bool,
           coverage: np.ndarray | None, reference: Reference | None) -> TrainedMaterial:
    """`train`, on the thread count it sets."""
    device = resolve_device(cfg.device)
    mc, preset = cfg.model, cfg.preset
    gen = torch.Generator().manual_seed(cfg.seed)
    gains = encoding.gains(ts.channels)
    if reference is None:
        reference = Reference.of(ts, coverage, mc.wrap)
    else:
        reference.check(ts, coverage, mc.wrap)
    # the trainer's own copy: planar, encoded, on the device; the numpy chain stays the caller's
    ref = ReferencePyramid.from_mips(encoding.encode_levels(reference.mips, gains), device)
    masks = reference.masks
    del reference
    c = ts.num_channels
    biases = M.layer_lod_biases(mc, ts.width, ts.height)
    kinds = tuple(ch.kind for ch in ts.channels)
    mean = torch.as_tensor(encoding.encode_levels([ts.data], gains)[0].reshape(-1, c).mean(0))
    mlp = M.init_mlp(mc.n_inputs, mc.hidden, c, gen, device, mean)
    backend = make_backend(cfg, device, mlp, biases)
    clock = _Clock({"warmup": preset.warmup.steps, "constrained": preset.constrained.steps,
                    "finetune": preset.finetune.steps})
    next_s = StratifiedScale(float(ref.num_levels - 1), gen, power=preset.lod_power, s_min=float(mc.split))
    t0 = time.perf_counter()
    centres = (CentreTargets(ref, mc.wrap, min_texels=4 * preset.batch, covered=masks,
                             bicubic=backend.bicubic(), interleave=backend.library() is not None,
                             draws=_draws(preset, next_s, ref.num_levels) if backend.bicubic() else None)
               if preset.centre_targets else None)
    mask_levels = [torch.as_tensor(m, device=device) for m in masks] if masks is not None else None
    run = _Run(cfg, device, backend, gen, ref, biases, mlp, clock, next_s, centres, mask_levels, progress, pace,
               Pacer(pace.seconds, pace.clock))
    if centres is not None:
        run.seconds["targets"] = time.perf_counter() - t0  # part of the training time, not hidden before it
    free = _warmup(run)
    blocks = _encode(run, free)
    del free
    _constrained(run, blocks)
    _report(run, "quantize", 0, 0, run.clock.left("finetune"))
    float_mse = float_model_mse(M.block_level_fn(blocks, mc), mlp, mc, kinds, biases, ref) if measure_float else None
    layers, exact = _quantize(run, blocks)
    del blocks
    _run_phase(run, "finetune", backend.cached_step(exact), [], preset.finetune)  # phase 4

    w = MlpWeights(*(mlp[k].detach().cpu().numpy().astype(np.float32)
                     for k in ("w1", "b1", "w2", "b2", "out_scale", "out_bias")),
                   log_gain=gains if np.any(gains > 0) else None).to_fp16()
    return TrainedMaterial(cfg, ts, layers, w, biases, run.seconds, float_mse, run.history, run.samples)
