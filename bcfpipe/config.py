"""Model profiles and training presets: the one place for defaults.

Profiles are the paper's Table 1: the resolution of each feature layer T_0..T_3. Every layer is a
pyramid of independently parameterised mips from its resolution down to 4x4 (one BC block), so a
layer of resolution r has log2(r) - 1 mips (512 -> 8, as in Table 1).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Literal

from bcfpipe.errors import InputError
from bcfpipe.formats.record import Record
from bcfpipe.formats.vocabulary import T0, FeatureFormat, Kernel, Layout, wrap_axes

N_LAYERS = 4  # the profile's layers T_0..T_3; a model has t0_layers - 1 more at T_0 (ModelConfig.n_layers)
MAX_T0_LAYERS = 3  # layers of principal components a fixed T_0 may hold (ModelConfig.t0_layers)
MIN_LEVEL = 4  # the smallest mip is one 4x4 BC6H block

PAPER_PROFILES: dict[str, tuple[int, int, int, int]] = {
    "0.5k": (512, 256, 128, 64),
    "1k": (1024, 512, 256, 128),
    "2k": (2048, 1024, 512, 256),
    "2k++": (2048, 2048, 512, 256),
}
# "1k++" goes beyond the paper the way its 2k++ does: six channels at T_0's resolution (T_0 and T_1
# both 1024²), for fine-mip detail that three features cannot hold (issue #9, benchmarks/bound_t0.py).
PROFILES: dict[str, tuple[int, int, int, int]] = {"tiny": (64, 32, 16, 8), **PAPER_PROFILES,
                                                  "1k++": (1024, 1024, 256, 128)}
PROFILE_NAMES = (*PROFILES, "auto")


def scaled_profile(t0: int) -> tuple[int, int, int, int]:
    """The paper's halving pattern (T_i = T_0 / 2^i, at least 4) for a power-of-two T_0."""
    return tuple(max(MIN_LEVEL, t0 >> i) for i in range(N_LAYERS))  # type: ignore[return-value]


def resolve_profile(name: str, source_size: int) -> tuple[str, tuple[int, int, int, int]]:
    """Profile name -> (name, resolutions). ``auto`` is the largest of 0.5k/1k/2k whose T_0 is not
    larger than the source's larger side; below 512 it halves the paper pattern from the source's
    power-of-two size (so a 32x32 texture gets 32/16/8/4). 2k++ and 1k++ are only used when asked for."""
    if name != "auto":
        if name not in PROFILES:
            raise ValueError(f"unknown profile {name!r}; choose from {', '.join(PROFILE_NAMES)}")
        return name, PROFILES[name]
    for n in ("2k", "1k", "0.5k"):
        if PROFILES[n][0] <= source_size:
            return n, PROFILES[n]
    t0 = max(MIN_LEVEL, 1 << max(2, int(math.floor(math.log2(max(source_size, 1))))))
    return f"auto-{t0}", scaled_profile(t0)


def max_t0_layers(n_channels: int, features: FeatureFormat = FeatureFormat.BC7) -> int:
    """The most layers of principal components a fixed T_0 holds usefully: one per ``features``
    layer's channels of the set's ``n_channels`` components, at most MAX_T0_LAYERS."""
    return max(1, min(MAX_T0_LAYERS, -(-int(n_channels) // LAYER_CHANNELS_OF[FeatureFormat(features)])))


def mip_count(resolution: int) -> int:
    return max(1, int(math.log2(resolution)) - 1)


@dataclass(frozen=True)
class PhaseSchedule:
    """Adam learning rates (features, MLP), decay per step, and step count of one phase."""

    steps: int
    lr_features: float
    lr_mlp: float
    gamma_features: float
    gamma_mlp: float


def _decay(steps: int, final: float) -> float:
    """Per-step gamma so the learning rate decays to ``final`` of its start over ``steps``."""
    return final ** (1.0 / max(steps, 1))


def _cpu_preset(warm: int, bc: int, mlp: int, batch: int) -> "Preset":
    # Adam moves a parameter by about lr per step, so phases 10-100x shorter than the paper's need
    # proportionally larger rates to travel as far in the 6-bit endpoint domain (measured: 5e-2
    # gives 21.8 dB where 0.5 gives 29.0 dB on a 200+600+100-step run).
    return Preset(
        warmup=PhaseSchedule(warm, 0.5, 5e-3, _decay(warm, 0.0821), _decay(warm, 0.0821)),
        constrained=PhaseSchedule(bc, 0.1, 5e-3, _decay(bc, 0.05), _decay(bc, 0.05)),
        finetune=PhaseSchedule(mlp, 0.0, 2.5e-3, 1.0, _decay(mlp, 0.1)),
        batch=batch,
        qat_fraction=0.5,
        lod_power=2.0,
        centre_targets=True,
    )


@dataclass(frozen=True)
class Preset:
    """A quality preset: the four phases' schedules and the batch size (samples per step)."""

    warmup: PhaseSchedule
    constrained: PhaseSchedule
    finetune: PhaseSchedule
    batch: int
    qat_fraction: float = 0.0  # last fraction of phase 2 trained quantization-aware
    lod_power: float = 1.0  # batch lods s = s_max * u**lod_power, u stratified uniform: > 1 favours fine mips
    centre_targets: bool = False  # draw steps at large mips at precomputed texel centres (reference.CentreTargets)

    @property
    def total_steps(self) -> int:
        return self.warmup.steps + self.constrained.steps + self.finetune.steps


# "paper" is §6.1 verbatim: 5k warm-up steps (lr 5e-2 / 1e-3, gamma 0.9995), 200k constrained
# steps (lr 1e-2 / 1e-3, gamma 0.9999), 1k MLP fine-tune steps; batches of 512x512.
# The CPU presets shorten the phases and batch and pick gammas that decay about as far over
# their shorter phases (warm-up ends at 0.9995^5000 = 0.082 of its start, as in the paper),
# train the second half of phase 2 quantization-aware (the paper's 200k steps do not need it),
# draw s = s_max * u^2 so the fine mips, which hold most texels, get more of the few steps
# (teapot, fast: +2.5 dB at mips 0-1, +1 dB over all mips; docs/benchmarks.md, issue #9), and
# take the steps at large mips at precomputed texel-centre targets (the same target, cheaper).
# Their step counts spend the fused kernel's speed (issue 30): standard trains 4x the steps it did
# with the torch kernel, in less time (teapot at 1k: 37.55 dB in 256 s, against 35.51 dB in 450 s),
# fast 2.5x, and draft takes batches of 128^2 (4x) (docs/benchmarks.md, "Presets re-tuned").
PRESETS: dict[str, Preset] = {
    "smoke": _cpu_preset(20, 60, 10, 32 * 32),
    "draft": _cpu_preset(200, 600, 100, 128 * 128),
    "fast": _cpu_preset(1000, 5000, 200, 128 * 128),
    "standard": _cpu_preset(3200, 16000, 300, 128 * 128),
    "paper": Preset(
        warmup=PhaseSchedule(5000, 5e-2, 1e-3, 0.9995, 0.9995),
        constrained=PhaseSchedule(200_000, 1e-2, 1e-3, 0.9999, 0.9999),
        finetune=PhaseSchedule(1000, 0.0, 1e-3, 1.0, 0.9999),
        batch=512 * 512,
    ),
}
DEFAULT_PRESET = "standard"

# A 2048² T_0 costs about 2x per step on the CPU: Adam streams every parameter of each level a step
# samples, and the finest level holds 4x the blocks (docs/benchmarks.md, "Presets re-tuned"). To keep
# issue 30's limits for a 2K material on a quiet 2-core machine (standard 5 min, fast 2 min, draft
# 30 s), `standard` takes fewer steps there (the teapot: 255 s; `fast` at full steps: 99 s); CUDA and
# smaller profiles train PRESETS as is.
LARGE_T0 = 2048
CPU_PRESETS_LARGE: dict[str, Preset] = {
    "standard": _cpu_preset(2600, 13500, 300, 128 * 128),
}


# With a fixed T_0 (--t0 pca, bc7's default) the close mips come from the components at once and a
# step trains T_1..T_3 alone, so `draft` spends 3x the steps on them and draws coarse lods as often as
# fine ones (lod_power 1): teapot 1k 38.1 dB in 23 s, within 1.5 dB of standard's 39.3 (it was 35.7 in
# 16 s; issue 30, docs/benchmarks.md "Presets with the fixed T_0"). A 2048² T_0 on a CPU keeps the
# PRESETS draft, within 30 s.
FIXED_T0_PRESETS: dict[str, Preset] = {
    "draft": replace(_cpu_preset(600, 1800, 100, 128 * 128), lod_power=1.0),
}


def shortened(preset: Preset, fraction: float) -> Preset:
    """``preset`` with every phase ``fraction`` as long and its learning rates decaying as far (the
    layout's probe, issue 58): the same schedule, compressed."""
    def phase(p: PhaseSchedule) -> PhaseSchedule:
        steps = max(1, round(p.steps * fraction))
        return replace(p, steps=steps, gamma_features=p.gamma_features ** (p.steps / steps),
                       gamma_mlp=p.gamma_mlp ** (p.steps / steps))

    return replace(preset, warmup=phase(preset.warmup), constrained=phase(preset.constrained),
                   finetune=phase(preset.finetune))


def preset_for(name: str, t0: int, device: str, fixed_t0: bool = False) -> Preset:
    """The schedule that preset ``name`` trains with a T_0 of ``t0`` texels on ``device``;
    ``fixed_t0``: T_0 holds fixed principal components (FIXED_T0_PRESETS)."""
    large_on_cpu = t0 >= LARGE_T0 and not str(device).startswith("cuda")
    if large_on_cpu and name in CPU_PRESETS_LARGE:
        return CPU_PRESETS_LARGE[name]
    if fixed_t0 and not large_on_cpu and name in FIXED_T0_PRESETS:
        return FIXED_T0_PRESETS[name]
    return PRESETS[name]
# The encoder presets of the classic textures a layout weighs and ships, by quality preset (issue 58).
# quicktex's BC1 dominates a classic layout's encode (level 18, its slowest and best: 3.1 s per 1024²
# level on one core). Level 13 loses 0.064 dB on the teapot's colour and 0.040 on the brick's at 5.4x
# the speed, level 16 0.014 at 2.7x (1024² crops, `benchmarks/bench_classic_presets.py`), so
# `draft`, a preview, encodes at 13, `fast` at 16. BC7 (a repack) at `draft` and `smoke` takes the
# ``quick`` profile (`texset.baselines.BC7_PROFILES`: 0.64x the time, within 0.005 dB on the same
# crops); ISPC's own alpha_veryfast loses 0.17 dB on the teapot's colour with its roughness as alpha.
@dataclass(frozen=True)
class EncodePreset:
    """How a layout's classic textures are encoded: quicktex's BC1 level (0..18) and the ISPC BC7
    profile of its repacks (`bcfpipe.texset.baselines.BC7_PROFILES`)."""

    bc1_level: int = 18
    bc7: Literal["basic", "quick"] = "basic"


ENCODE_PRESETS: dict[str, EncodePreset] = {
    "smoke": EncodePreset(13, "quick"), "draft": EncodePreset(13, "quick"), "fast": EncodePreset(16),
    "standard": EncodePreset(18), "paper": EncodePreset(18),
}
DEFAULT_ENCODE = EncodePreset()


# `smoke` checks that a scene and a pipeline (build system, cache, shards, Ray) work end to end, in
# about a second of training per material; its quality is not meant to be looked at. Rate control
# never chooses it, and it is not in the schedules that key a rate-controlled build.
QUALITY_PRESETS = ("draft", "fast", "standard", "paper")

# Torch threads per training, unless --threads says otherwise. A training step is many small
# kernels: on the 2-core reference machine, quiet, the teapot at `fast` trained its constrained
# phase in 105 s with 1 thread and 156 s with 2 (docs/benchmarks.md), and under load extra
# threads are far worse. Parallelism comes from training materials side by side (--jobs).
DEFAULT_THREADS = 1


DEFAULT_PROFILE = "auto"
DEFAULT_HIDDEN = 16  # hidden units of the decoder MLP
DEFAULT_SEED = 0
DEFAULT_DEVICE = "auto"  # cuda when torch sees a GPU, else cpu
DEFAULT_INIT = "random"
# BC7 with a fixed T_0 of principal components beat BC6H on the teapot and the brick at 1k and 0.5k,
# over all mips, in less training time (docs/benchmarks.md, "A fixed T_0 of principal components");
# the rule is "whichever wins". The model record keeps the paper's BC6H as its own default.
DEFAULT_FEATURES = FeatureFormat.BC7
# What T_0 holds, per feature format when --t0 is not given: with BC7 the set's principal components,
# encoded once in every mode (teapot and brick at 1k beat trained mode-6 features at every close mip;
# docs/benchmarks.md, "A fixed T_0 of principal components"); BC6H trains it, as the paper does.
DEFAULT_T0 = {FeatureFormat.BC6H: T0.TRAINED, FeatureFormat.BC7: T0.PCA}
DEFAULT_KERNEL = Kernel.AUTO  # fused on the CPU: 6-10x the torch path's samples/s (docs/benchmarks.md)
# Per material, the best layout within BC@R's size and 0.5 dB of it at every mip, BC@R itself
# included: a default build is never worse than the BC set a user would ship (issue 31). It costs a
# probe training and at most one more (docs/layout.md). --target-psnr sizes an all-neural material
# against a PSNR instead, so with it the default is neural.
DEFAULT_LAYOUT = Layout.AUTO


def default_layout(target_psnr: float | None) -> Layout:
    """The layout when --layout is not given: auto, or neural with --target-psnr."""
    return Layout.NEURAL if target_psnr is not None else DEFAULT_LAYOUT


def t0_of(options) -> T0:
    """What T_0 holds for ``options``: --t0, else its feature format's default (DEFAULT_T0)."""
    return T0(options.t0) if options.t0 is not None else DEFAULT_T0[FeatureFormat(options.features)]


# Channels per feature layer T_i, per format: BC6H holds RGB, BC7 RGBA in the same bytes.
LAYER_CHANNELS_OF = {FeatureFormat.BC6H: 3, FeatureFormat.BC7: 4}

# Version of what training and export produce from the same inputs and options. It is part of
# every cache key (bcfpipe.builder.plan.content_hash): bump it with any change to the trainer, the
# encoder, the export or the files' contents, so that no cached material from before is reused.
MODEL_FORMAT = 17  # 5: the fused kernel by default and the re-tuned presets (issue 30); 6: the quick first encode
# (BC6H and BC7); 7: the BC6H first encode compiled (bc6h/quick.cpp: a few blocks in a thousand differ);
# 8: --layout auto the default (a record without a layout meant neural before); fast and standard take
# fewer steps at a 2048² T_0 on a CPU (CPU_PRESETS_LARGE); 9: --layout auto weighs mip splits (material.json
# format 4); 10: --layout auto weighs BC7 repacks of BC@R (classic BC7_UNORM textures); 11: --t0 pca, the
# bc7 default: a fixed T_0 of principal components in any BC7 mode; 12: the all-channels BC7 repack keeps every
# colour and normal whole at a texture's r, g(, b), so that a UsdUVTexture reads it (issue 50); 13: a layout's
# probe and second model train no more steps than --layout neural at the profile asked (layout.kinds.capped);
# 14: --layout auto weighs T_0 widths (issue 52) and layout.json reports the BC7 quality set and disk bytes;
# 15: addressing per axis, as USD's wrapS / wrapT say it (repeat, clamp, mirror; issue 57): the job's wrap
# is an (S, T) pair, and mirror is trained as mirror
# 16: a layout's classic normal is BC7 of (x, y, z), z stored for USD, and a colour read through rgb keeps its
# channels in their slots (TextureSet.vectors, material.json classic[].slots; issue 57)
# 17: a layout's classic normal is BC5 of its slopes (x / z, y / z) / m, read by USD as (s_x, s_y, 1) and by
# decoders normalised (material.json outputs' encoding "slope", format version 8; issue 57)

# --pca-clip: the percentage of texels at each end of a principal component's range that the PCA
# start and a fixed T_0 clip (0.1: the 0.1st..99.9th percentiles span the feature range)
DEFAULT_PCA_CLIP = 0.1

# How phase 1 starts: "random" as the paper does, or "pca" from the reference's principal
# components with the matching linear decoder (bcfpipe/train/feature_init.py: sharper fine mips, weaker
# coarse ones; issue #9).
FEATURE_INITS = ("random", "pca")


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of one neural material."""

    resolutions: tuple[int, int, int, int] = PROFILES["1k"]
    hidden: int = DEFAULT_HIDDEN
    signed: bool = False  # BC6H_UF16 by default: finer endpoint steps over the positive range
    wrap: tuple[str, str] = ("repeat", "repeat")  # (S, T) addressing: repeat, clamp or mirror per axis
    max_feature: float = 2.0  # decoded features are kept within +-max_feature (model.features.endpoint_range)
    features: FeatureFormat = DEFAULT_FEATURES
    # The first reference mip the features serve: 0 for a neural material; k > 0 in a mip-split
    # layout (issue 31), whose classic textures serve the mips below k, so steps draw s in [k, s_max].
    split: int = 0
    # The fraction of texels clipped at each end of a principal component's range where the PCA
    # start (or a fixed T_0) maps it onto the feature range: outliers then cost their own error,
    # not every texel's precision (bcfpipe.train.feature_init.pca_init).
    pca_clip: float = DEFAULT_PCA_CLIP / 100
    # Layers at T_0's resolution and lod bias (issue 52): with a fixed T_0 (--t0 pca) layer j < t0_layers
    # holds principal components 4j..4j+3; the model's layers are these, then T_1..T_3 (`profile_slots`).
    t0_layers: int = 1

    def __post_init__(self) -> None:
        if not 1 <= int(self.t0_layers) <= MAX_T0_LAYERS:
            raise ValueError(f"t0_layers must be 1..{MAX_T0_LAYERS}, got {self.t0_layers}")
        object.__setattr__(self, "wrap", tuple(str(w) for w in wrap_axes(self.wrap)))  # one mode: both axes

    @property
    def layer_channels(self) -> int:
        return LAYER_CHANNELS_OF[self.features]

    @property
    def profile_slots(self) -> tuple[int, ...]:
        """Per model layer, the profile's layer it stands at (its resolution and lod bias): the
        T_0 layers first, then T_1..T_3."""
        return (0,) * self.t0_layers + tuple(range(1, len(self.resolutions)))

    @property
    def n_layers(self) -> int:
        return len(self.profile_slots)

    @property
    def layer_resolutions(self) -> tuple[int, ...]:
        """Each model layer's resolution (``resolutions`` is the profile's, T_0..T_3)."""
        return tuple(self.resolutions[j] for j in self.profile_slots)

    @property
    def n_inputs(self) -> int:
        return self.n_layers * self.layer_channels

    @property
    def mip_counts(self) -> tuple[int, ...]:
        """Each model layer's mip count."""
        return tuple(mip_count(r) for r in self.layer_resolutions)


@dataclass(frozen=True)
class TrainConfig:
    """Everything a training run depends on; with the texture set it fixes the result on CPU."""

    model: ModelConfig = field(default_factory=ModelConfig)
    preset: Preset = PRESETS[DEFAULT_PRESET]
    preset_name: str = DEFAULT_PRESET
    seed: int = 0
    device: str = "cpu"
    threads: int | None = None  # torch intra-op threads; None = torch's default
    # decode only the sampled texels each step instead of whole levels (same forward values). Off by
    # default: on a quiet 2-core machine whole levels were faster at batch 128² and 512² (benchmarks.md)
    tap_decode: bool = False
    feature_init: str = DEFAULT_INIT  # see FEATURE_INITS
    kernel: Kernel = DEFAULT_KERNEL  # phases 1-2 through torch's ops or the fused kernel; see Kernel.on
    t0: T0 | None = None  # what T_0 holds (bcfpipe.train.fixed_t0); None: DEFAULT_T0 of the model's features
    # the ISPC BC7 profile a T_0 of principal components is encoded with (`texset.baselines.BC7_PROFILES`):
    # what ships takes "basic", whose blocks its figures and cache keys hold; the layout's probe, which
    # never ships, "alpha_modes": the same blocks or nearly, in half the time
    t0_bc7: Literal["basic", "alpha_modes"] = "basic"

    def __post_init__(self) -> None:
        if self.t0 is None:
            object.__setattr__(self, "t0", DEFAULT_T0[FeatureFormat(self.model.features)])

    def with_(self, **kw) -> "TrainConfig":
        return replace(self, **kw)


#: metadata of an option field that does not change what a job trains, and so is no part of its
#: cache key (bcfpipe.builder.plan.content_hash); the value says where its effect goes instead
UNKEYED = "unkeyed"
#: metadata of an option field that manifest.json does not record (`JobOptions.recorded`): how a
#: build ran, not what it made; the value says why
UNRECORDED = "unrecorded"


@dataclass(frozen=True)
class TrainingOptions(Record):
    """What the user chooses for training, validated once, here, when it is made.

    One field per training option of `bcfpipe train`, `plan` and `build`: the command line adds one
    click option per field, by name (bcfpipe.cli.options), and hands the record on whole. A build's
    plan resolves it into each job's `JobOptions` (this record and what the scene fixes), which the
    executors hand to the worker and `bcfpipe.fit.fit` whole; its JSON, bar the `UNKEYED` fields, is
    the job's cache key. A new option is one field here, one click option and its use.
    """

    profile: str = DEFAULT_PROFILE
    preset: str = DEFAULT_PRESET
    hidden: int = DEFAULT_HIDDEN
    signed: bool = False
    init: str = DEFAULT_INIT
    fix_nonfinite: bool = False
    seed: int = DEFAULT_SEED
    device: str = DEFAULT_DEVICE
    threads: int = field(default=DEFAULT_THREADS, metadata={UNKEYED: "torch threads: how fast, not what",
                                                            UNRECORDED: "how fast, not what"})
    target_psnr: float | None = None
    bench_data: str | None = field(default=None, metadata={UNKEYED: "read into the job's anchors, which are keyed",
                                                           UNRECORDED: "a path outside the build folder"})
    features: FeatureFormat = DEFAULT_FEATURES
    kernel: Kernel = DEFAULT_KERNEL
    layout: Layout | None = None  # None: default_layout(target_psnr)
    match_bc: bool = False  # with layout auto: the smallest layout whose every mip reaches BC@R
    classic: tuple[str, ...] = ()  # semantics whose channel groups stay classic BC textures (BC@R)
    t0: T0 | None = None  # None: DEFAULT_T0 of the feature format
    pca_clip: float = DEFAULT_PCA_CLIP  # % of texels clipped at each end of a principal component's range
    t0_layers: int | None = None  # BC7 layers of principal components in a fixed T_0; None: --layout auto weighs 1..3

    def __post_init__(self) -> None:
        if self.features in tuple(FeatureFormat) and not isinstance(self.features, FeatureFormat):
            object.__setattr__(self, "features", FeatureFormat(self.features))  # "bc7" from a command line
        if self.kernel in tuple(Kernel) and not isinstance(self.kernel, Kernel):
            object.__setattr__(self, "kernel", Kernel(self.kernel))
        if self.t0 in tuple(T0) and not isinstance(self.t0, T0):
            object.__setattr__(self, "t0", T0(self.t0))
        if self.layout is None:
            object.__setattr__(self, "layout", default_layout(self.target_psnr))
        elif self.layout in tuple(Layout) and not isinstance(self.layout, Layout):
            object.__setattr__(self, "layout", Layout(self.layout))
        given = (self.classic,) if isinstance(self.classic, str) else tuple(self.classic or ())
        names = tuple(s.strip() for g in given for s in g.split(",") if s.strip())  # "normal,opacity", repeated
        if names != self.classic:
            object.__setattr__(self, "classic", names)
        for problem in self.problems():
            raise InputError(problem)

    def problems(self) -> list[str]:
        """What is wrong with these choices, as one-line messages (empty when nothing is)."""
        out = []
        if self.profile not in PROFILE_NAMES:
            out.append(f"unknown profile {self.profile!r}; choose from {', '.join(PROFILE_NAMES)}")
        if self.preset not in PRESETS:
            out.append(f"unknown quality preset {self.preset!r}; choose from {', '.join(PRESETS)}")
        if self.init not in FEATURE_INITS:
            out.append(f"unknown feature start {self.init!r}; choose from {', '.join(FEATURE_INITS)}")
        if int(self.hidden) < 1:
            out.append(f"--hidden must be at least 1, got {self.hidden}")
        if self.threads is not None and int(self.threads) < 1:
            out.append("--threads must be at least 1")
        if self.target_psnr is not None and not (0 < self.target_psnr < float("inf")):
            out.append(f"--target-psnr must be a positive number of dB, got {self.target_psnr}")
        if self.bench_data is not None and self.target_psnr is None:
            out.append("--bench-data is only used with --target-psnr")
        if self.features not in tuple(FeatureFormat):
            out.append(f"unknown feature format {self.features!r}; choose from "
                       f"{', '.join(f.value for f in FeatureFormat)}")
        elif self.signed and FeatureFormat(self.features) != FeatureFormat.BC6H:
            out.append("--signed is a BC6H choice (BC6H_SF16): add --features bc6h (BC7 features are unsigned)")
        if self.t0 is not None and self.t0 not in tuple(T0):
            out.append(f"unknown --t0 {self.t0!r}; choose from {', '.join(v.value for v in T0)}")
        elif self.t0 == T0.PCA and self.features == FeatureFormat.BC6H:
            out.append("--t0 pca keeps T_0 as BC7 blocks of any mode: use it with --features bc7")
        if self.layout not in tuple(Layout):
            out.append(f"unknown layout {self.layout!r}; choose from {', '.join(v.value for v in Layout)}")
        elif self.match_bc and self.target_psnr is not None:
            out.append("--match-bc sizes a layout against BC@R; --target-psnr sizes an all-neural material against "
                       "a PSNR: use one")
        elif self.match_bc and self.layout != Layout.AUTO:
            out.append("--match-bc chooses a layout: use it with --layout auto")
        elif self.layout == Layout.AUTO and self.target_psnr is not None:
            out.append("--layout auto chooses the profile against BC; --target-psnr chooses it against a PSNR: "
                       "use one (--layout neural --target-psnr DB)")
        if self.classic and self.target_psnr is not None:
            out.append("--classic fixes part of the layout against BC@R; --target-psnr sizes an all-neural "
                       "material against a PSNR: use one")
        if self.t0_layers is not None and not 1 <= int(self.t0_layers) <= MAX_T0_LAYERS:
            out.append(f"--t0-layers must be 1..{MAX_T0_LAYERS}, got {self.t0_layers}")
        elif (self.t0_layers or 1) > 1 and self.features == FeatureFormat.BC6H:
            out.append("--t0-layers widens a T_0 of principal components in BC7: use it with --features bc7 "
                       "(the default)")
        elif (self.t0_layers or 1) > 1 and self.t0_resolved != T0.PCA:
            out.append("--t0-layers widens a T_0 of principal components: use it with --t0 pca (bc7's default)")
        if not 0 <= self.pca_clip < 50:
            out.append(f"--pca-clip must be a percentage in [0, 50), got {self.pca_clip}")
        if self.kernel not in tuple(Kernel):
            out.append(f"unknown kernel {self.kernel!r}; choose from {', '.join(k.value for k in Kernel)}")
        elif self.kernel == Kernel.FUSED and str(self.device).startswith("cuda"):
            out.append("--kernel fused runs on the CPU; use --kernel torch with --device cuda")
        return out

    def with_(self, **kw) -> "TrainingOptions":
        return replace(self, **kw)

    @property
    def t0_resolved(self) -> T0:
        """What T_0 holds: --t0, else the feature format's default (DEFAULT_T0)."""
        return t0_of(self)

    def t0_width(self, n_channels: int | None = None) -> int:
        """The layers of components a fixed T_0 holds for a set of ``n_channels``: --t0-layers (1
        when not given), no more than the components the set has (`max_t0_layers`)."""
        if self.t0_resolved != T0.PCA:
            return 1
        asked = int(self.t0_layers or 1)
        return asked if n_channels is None else min(asked, max_t0_layers(n_channels, FeatureFormat(self.features)))

    def train_config(self, source_size: int, wrap, device: str,
                     n_channels: int | None = None) -> tuple[str, TrainConfig]:
        """The `TrainConfig` of these choices for a texture set whose larger side is
        ``source_size`` (of ``n_channels``, which caps the T_0 layers), addressed with ``wrap`` (one
        mode, or the (S, T) pair a UsdUVTexture's wrapS / wrapT give: repeat, clamp, mirror), on
        the resolved ``device``; and the profile's resolved name (``auto`` picks from the size)."""
        wrap = tuple(str(w) for w in wrap_axes(wrap))
        name, res = resolve_profile(self.profile, source_size)
        mc = ModelConfig(resolutions=res, hidden=self.hidden, signed=self.signed, wrap=wrap,
                         features=FeatureFormat(self.features), pca_clip=self.pca_clip / 100,
                         t0_layers=self.t0_width(n_channels))
        fixed = self.t0_resolved == T0.PCA
        return name, TrainConfig(model=mc, preset=preset_for(self.preset, res[0], device, fixed),
                                 preset_name=self.preset,
                                 seed=self.seed,
                                 device=device, threads=self.threads, feature_init=self.init,
                                 kernel=Kernel(self.kernel).on(device), t0=self.t0_resolved)


@dataclass(frozen=True)
class JobOptions(TrainingOptions):
    """One build job's record: the user's `TrainingOptions` as the plan resolved them (``device``
    the device class, ``kernel`` what runs there) and what the scene fixes for this texture set.
    Being a `TrainingOptions`, every training option reaches the worker by construction."""

    resolution: int | None = None  # the texture set resampled to this larger side (a density cap)
    texel_density: float | None = field(default=None, metadata={UNKEYED: "acts through resolution"})  # px/m
    coverage: bool = True  # training draws from the texels the bound meshes read (its mask is keyed)

    @classmethod
    def of(cls, training: TrainingOptions, device_class: str, **scene) -> "JobOptions":
        """``training`` resolved on ``device_class``, with the scene's fields ``scene``."""
        own = {f.name: getattr(training, f.name) for f in fields(TrainingOptions)}
        return cls(**{**own, "device": device_class, "kernel": Kernel(training.kernel).on(device_class), **scene})

    def keyed(self) -> dict:
        """The record's canonical JSON without its `UNKEYED` fields: what the cache key states."""
        skip = {f.name for f in fields(self) if UNKEYED in f.metadata}
        return {k: v for k, v in self.to_json().items() if k not in skip}

    def recorded(self) -> dict:
        """The record's canonical JSON without its `UNRECORDED` fields: manifest.json's ``options``."""
        skip = {f.name for f in fields(self) if UNRECORDED in f.metadata}
        return {k: v for k, v in self.to_json().items() if k not in skip}
