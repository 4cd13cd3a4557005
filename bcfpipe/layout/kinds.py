"""The kinds of layout candidate (issue 51): each one class, weighed by `bcfpipe.layout.decide.decide_layout`.

A kind generates its candidates from the shared fit context (`FitContext`: BC@R and its repacks
measured, the probe, the profiles and their bytes), says how one of them reads, trains the one the
rule picks when it needs a model of its own, and writes the chosen layout to the material folder.
`REGISTRY` is the ordered tuple `decide_layout` weighs; its order is the order the candidates are
weighed in (ties go to the first). A new kind is a subclass of `Kind` with an instance added there:
`decide_layout` and `export_layout` read nothing of a kind but these methods (docs/architecture.md).
"""
from __future__ import annotations

import itertools
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from bcfpipe.config import TrainingOptions
from bcfpipe.config import PROFILES
from bcfpipe.config import max_t0_layers
from bcfpipe.export.material import FIGURES, MaterialResult, train_material, make_config
from bcfpipe.export.material import shipped_disk_bytes
from bcfpipe.formats.dds import HEADER_BYTES
from bcfpipe.formats.sizes import neural_bytes
from bcfpipe.layout import choose as C
from bcfpipe.layout.classic import EncodedGroup, disk_bytes, split_levels
from bcfpipe.layout.classic_fit import ClassicFit, ClassicKinds
from bcfpipe.layout.export import export_groups, export_split
from bcfpipe.layout.oracle import cap
from bcfpipe.layout.oracle import ORACLE_MARGIN_DB
from bcfpipe.layout.oracle import magnified_errors
from bcfpipe.layout.result import LayoutFit
from bcfpipe.texset.chain import Reference
from bcfpipe.texset.texture_set import TextureSet
from bcfpipe.train.gains import profile_gain
from bcfpipe.train.gains import probe_gains
from bcfpipe.train.gains import t0_layer_gains
from bcfpipe.train.progress import ProgressFn


@dataclass(frozen=True)
class Weighed:
    """A candidate and, once measured, what ships it: the model it decodes with (None: all classic)
    on ``channels``, and ``parts``, whatever else its kind's `Kind.export` writes (`LayoutFit.parts`)."""

    candidate: C.Candidate
    model: MaterialResult | None = None
    channels: tuple[int, ...] = ()
    parts: Any = None


@dataclass(frozen=True)
class FitContext:
    """What every kind reads: the set, the options, BC@R measured and the probe (None under
    ``--layout neural``, which trains one layout without a probe)."""

    ts: TextureSet
    out: Path  # neural files go under out/probe, out/neural, out/split
    options: TrainingOptions
    wrap: str
    resolution: int  # R
    forced: tuple[str, ...] = ()  # the groups --classic keeps classic in every candidate
    cap: Any = None  # the schedule no training here exceeds (`capped`); None: each config's own
    progress: ProgressFn | None = None
    coverage: np.ndarray | None = None
    log: Callable[[str], None] = lambda s: None
    classic: ClassicFit | None = None  # BC@R measured (every kind reads it)
    probe: MaterialResult | None = None
    p0: str | None = None  # the probe's profile
    profiles: tuple[str, ...] = ()  # weighed, largest first
    widths: tuple[int, ...] = (1,)  # the T_0 widths weighed (--t0-layers, issue 52), narrowest first
    w0: int = 1  # the probe's T_0 width
    sizes: Mapping[tuple[str, int], int] = field(default_factory=dict)  # a neural part's bytes by (profile, width)
    own: Mapping[str, str] = field(default_factory=dict)  # the profile each trains as (auto-N trains as "auto")
    dims: tuple[int, int] = (0, 0)  # (MLP inputs of a one-layer T_0, hidden)
    reference: Reference | None = None  # the set's chain and coverage masks, built once per fit
    costs: dict[str, float] = field(default_factory=dict)  # seconds by part (the report's phase_seconds, layout_*)
    oracles: dict[int, np.ndarray] = field(default_factory=dict)  # `oracle` by T_0 side, made once each
    most: bool = False  # predict with the most a full training gained over the probe on any set measured

    @property
    def match_bc(self) -> bool:
        return bool(self.options.match_bc)

    @property
    def all_channels(self) -> tuple[int, ...]:
        return tuple(range(self.ts.num_channels))

    def gain(self, profile: str) -> float:
        """The measured gain of ``profile`` (`train.gains`); smoke is no rate-control preset: draft's stand in."""
        preset = self.options.preset
        return profile_gain(profile, preset if preset in ("draft", "fast", "standard", "paper") else "draft")

    @property
    def settings(self) -> tuple[tuple[str, int], ...]:
        """Every (profile, T_0 width) weighed: the profiles largest first, each at every width."""
        return tuple((p, w) for p in self.profiles for w in self.widths)

    def t0_mip(self, profile: str) -> int:
        """The reference mip T_0's level 0 serves at ``profile``."""
        t0 = PROFILES[profile][0] if profile in PROFILES else self.probe.resolutions[0]
        return max(0, (max(self.ts.width, self.ts.height) // t0).bit_length() - 1)

    def probe_gains(self) -> np.ndarray:
        """Per reference mip, what a full training at the preset asked gains over the probe (`train.gains`)."""
        return np.array(probe_gains(self.options.preset, self.probe.mse_per_channel.shape[0], self.t0_mip(self.p0),
                                    self.most))

    def oracle(self, t0: int) -> np.ndarray:
        """(mips, channels) errors of the reference's ``t0``-sized mip magnified to each finer mip
        (`bcfpipe.layout.oracle`), 0 elsewhere."""
        if t0 not in self.oracles:
            self.oracles[t0] = magnified_errors(self.reference, t0, self.ts.channels, self.wrap)
        return self.oracles[t0]

    def width_gains(self, profile: str, width: int) -> np.ndarray:
        """Per reference mip, what ``width`` T_0 layers add over one at ``profile`` (`train.gains`)."""
        return np.array(t0_layer_gains(width, self.probe.mse_per_channel.shape[0], self.t0_mip(profile)))

    def neural_errors(self, profile: str, width: int = 1) -> np.ndarray:
        """(mips, channels) errors of all channels at ``profile`` with a T_0 of ``width`` layers,
        trained in full at the preset asked: the probe's, moved per mip by what a full training
        gains over it, by the profiles' gain and by the widths', and held to the oracle at the
        mips finer than its T_0 (`bcfpipe.layout.oracle.cap`)."""
        db = (self.probe_gains() + self.gain(profile) - self.gain(self.p0)
              + self.width_gains(profile, width) - self.width_gains(self.p0, self.w0))
        t0 = PROFILES[profile][0] if profile in PROFILES else self.probe.resolutions[0]
        return cap(self.probe.mse_per_channel * 10 ** (-db[:, None] / 10), self.oracle(t0))

    def fits_width(self, channels: int, width: int) -> bool:
        """Whether a model of ``channels`` channels can hold ``width`` layers of components."""
        return width <= max_t0_layers(channels, self.options.features)


class Kind(ABC):
    """One kind of layout candidate. Subclass it, override `label` and `predict`; a kind whose
    candidates need a model of their own overrides `trains` and `train`; one that writes anything
    but some of BC@R's groups and the chosen model overrides `export`. Then add an instance to
    `REGISTRY`. The final choice weighs every candidate whose basis is ``measured``."""

    name = ""

    @abstractmethod
    def label(self, c: C.Candidate) -> str:
        """How ``c`` reads in logs and layout.json (unique among the candidates of a fit)."""

    @abstractmethod
    def predict(self, ctx: FitContext) -> list[Weighed]:
        """Its candidates, measured, estimated or predicted, each with ``kind=self`` (a measured one with
        its model and parts)."""

    def trains(self, ctx: FitContext, c: C.Candidate) -> bool:
        """Whether shipping ``c`` needs a model trained for it."""
        return False

    def worth(self, ctx: FitContext, c: C.Candidate, held: C.Candidate) -> bool:
        """Whether ``c``, the first choice, is worth its training against ``held``, the choice among
        what is measured already."""
        return True

    def train(self, ctx: FitContext, c: C.Candidate) -> Weighed:
        """Train and measure ``c`` (only when `trains`)."""
        raise NotImplementedError(f"{type(self).__name__} trains nothing: its candidates are measured")

    def export(self, fit: LayoutFit, c: C.Candidate, ts: TextureSet, out: Path, wrap: str) -> Path:
        """Write ``c``, ``fit``'s choice, to ``out``: by default the groups ``c.classic`` names and the
        chosen model, if any."""
        return export_groups(fit, [g for g in fit.classic if g.group.name in c.classic], ts, out, wrap)

    def json(self, c: C.Candidate) -> dict:
        """Its own keys in layout.json, after the figures every candidate has: the T_0 width of a
        neural part (None without one)."""
        return {"t0_layers": None}


@dataclass(frozen=True)
class Repacked:
    """A repack's part (`BcRepack`, the BC7 quality set): which one, by its label (`classic.Repack`)."""

    repack: str


@dataclass(frozen=True)
class NeuralPart:
    """A neural part's (`NeuralAt`, `Mixed`): the layers of principal components its T_0 holds (issue 52)."""

    t0_layers: int = 1


@dataclass(frozen=True)
class SplitPart:
    """A mip split's (`MipSplit`): BC@R's levels below reference mip ``split``, features T_0..T_3 of
    ``resolutions`` from it on; T_0 of one layer."""

    split: int
    resolutions: tuple[int, ...]
    t0_layers: int = 1


class BcAtR(Kind):
    """BC@R: every group classic, as a user would ship the set (measured, never trained)."""

    name = "bc@r"

    def label(self, c: C.Candidate) -> str:
        return C.ALL_CLASSIC

    def predict(self, ctx: FitContext) -> list[Weighed]:
        return [Weighed(ctx.classic.bc)]


class BcQuality(Kind):
    """The BC7 quality set (`classic.bc7_quality_set`): estimated beside BC@R and reported against,
    never weighed (its BC7 colour takes BC1's bytes twice)."""

    name = "bc7-quality"
    Part = Repacked

    def label(self, c: C.Candidate) -> str:
        return "BC7 quality set" if c.part else C.ALL_CLASSIC

    def predict(self, ctx: FitContext) -> list[Weighed]:
        return []

    def json(self, c: C.Candidate) -> dict:
        return {"t0_layers": None, **({"repack": c.part.repack} if c.part else {})}


class BcRepack(Kind):
    """BC@R with some groups merged into BC7 in the same bytes (`classic.repacks`): estimated, and
    encoded in full when it ships (`classic_fit`)."""

    name = "repack"
    Part = Repacked

    def label(self, c: C.Candidate) -> str:
        return f"BC@R with {c.part.repack}"

    def json(self, c: C.Candidate) -> dict:
        return {"t0_layers": None, "repack": c.part.repack}

    def predict(self, ctx: FitContext) -> list[Weighed]:
        return [Weighed(c) for c in ctx.classic.packed if set(ctx.forced) <= set(c.classic)]

    def export(self, fit: LayoutFit, c: C.Candidate, ts: TextureSet, out: Path, wrap: str) -> Path:
        """BC@R's groups that were not merged, then the BC7 textures that replace the rest."""
        rp, enc = fit.repacked[c.part.repack]
        return export_groups(fit, [g for g in fit.classic if g.group.name not in rp.replaces] + list(enc),
                             ts, out, wrap)


def at_profiles(ctx: FitContext, chosen: Sequence[int], kind: Kind) -> list[Weighed]:
    """The groups ``chosen`` (indices into BC@R's) classic and a model on the other channels, at every
    profile and T_0 width, ``predicted`` from the probe's errors on those channels (`neural_errors`;
    a model on fewer channels fits them at least as well as the all-channel probe)."""
    groups = ctx.classic.groups
    names = tuple(groups[i].group.name for i in chosen)
    cols = [c for i in chosen for c in groups[i].group.channels]
    classic_bytes = sum(groups[i].size_bytes for i in chosen)
    out = []
    for p, w in ctx.settings:
        if not ctx.fits_width(ctx.ts.num_channels - len(cols), w):
            continue
        out.append(Weighed(C.Candidate(names, p, ctx.sizes[(p, w)] + classic_bytes,
                                       C.combine(ctx.neural_errors(p, w), ctx.classic.e_bc, cols),
                                       "predicted", ctx.classic.use, NeuralPart(w), kind=kind)))
    return out


def t0_text(c: C.Candidate) -> str:
    """How a candidate's T_0 width reads in its label: nothing for one layer."""
    return f", T_0 of {c.part.t0_layers} layers" if c.part.t0_layers > 1 else ""


class ModelOnTheRest(Kind):
    """A model on the channels outside the candidate's classic groups, at a profile and T_0 width
    (`NeuralPart`), predicted from the probe and trained when chosen: `NeuralAt` and `Mixed`."""

    def trains(self, ctx: FitContext, c: C.Candidate) -> bool:
        return True

    def train(self, ctx: FitContext, c: C.Candidate) -> Weighed:
        ctx.log(f"training the channels outside the classic groups at {c.profile} for: {c.label}")
        return train_outside(ctx, c.classic, c.profile, self, width=c.part.t0_layers)

    def json(self, c: C.Candidate) -> dict:
        return {"t0_layers": c.part.t0_layers}


class NeuralAt(ModelOnTheRest):
    """Every channel neural at a profile and T_0 width, predicted from the probe."""

    name = "neural"

    def label(self, c: C.Candidate) -> str:
        return f"neural {c.profile}{t0_text(c)}"

    def predict(self, ctx: FitContext) -> list[Weighed]:
        return [] if ctx.forced else at_profiles(ctx, (), self)


class Mixed(ModelOnTheRest):
    """Some of BC@R's groups classic (every one --classic names among them), a model on the rest at
    a profile, predicted from the probe."""

    name = "mixed"

    def label(self, c: C.Candidate) -> str:
        return f"neural {c.profile}{t0_text(c)} + classic {', '.join(c.classic)}"

    def predict(self, ctx: FitContext) -> list[Weighed]:
        n = len(ctx.classic.groups)
        names = [g.group.name for g in ctx.classic.groups]
        return [w for r in range(1, n) for chosen in itertools.combinations(range(n), r)
                if set(ctx.forced) <= {names[i] for i in chosen} for w in at_profiles(ctx, chosen, self)]


class MipSplit(Kind):
    """BC@R's levels below a reference mip k, features for s >= k (`split_candidates`); trained only
    when its prediction beats what is measured already, and weighed only when --classic fixes no group."""

    name = "split"
    MIN_SIDE = 8  # the smallest T_0 side a split's features take

    def label(self, c: C.Candidate) -> str:
        return f"BC@R below mip {c.part.split} + neural {c.profile} from it"

    def json(self, c: C.Candidate) -> dict:
        return {"t0_layers": c.part.t0_layers, "split": c.part.split}

    def predict(self, ctx: FitContext) -> list[Weighed]:
        if ctx.forced:  # --classic keeps its groups classic at every mip
            return []

        halving = max(0.0, ctx.gain("1k") - ctx.gain("0.5k"))  # one halving of T_0
        out = []
        for c in split_candidates(ctx.ts, ctx.classic, ctx.neural_errors(ctx.p0, 1), ctx.resolution,
                                  ctx.dims, ctx.match_bc, ctx.probe.resolutions[0], halving):
            # features smaller than the mips they serve are magnified there: held to the oracle
            floor = ctx.oracle(c.part.resolutions[0]).mean(1) * 10 ** (-ORACLE_MARGIN_DB / 10)
            c = replace(c, mse_per_mip=tuple(m if k < c.part.split else max(m, float(floor[k]))
                                             for k, m in enumerate(c.mse_per_mip)))
            if C.deficit(c, ctx.classic.bc, ctx.match_bc) <= 0:
                out.append(Weighed(c))
        return out

    def trains(self, ctx: FitContext, c: C.Candidate) -> bool:
        return True

    def worth(self, ctx: FitContext, c: C.Candidate, held: C.Candidate) -> bool:
        return c.size_bytes < held.size_bytes if ctx.match_bc else c.psnr > held.psnr

    def train(self, ctx: FitContext, c: C.Candidate) -> Weighed:
        ctx.log(f"training the features of a mip split for: {c.label} (predicted {c.psnr:.2f} dB over all mips)")
        return train_split(ctx, c)

    def export(self, fit: LayoutFit, c: C.Candidate, ts: TextureSet, out: Path, wrap: str) -> Path:
        resolution = max(max(g.levels[0][1], g.levels[0][2]) for g in fit.classic)
        return export_split(fit.classic, fit.neural.out_dir, ts, out, c.part.split, resolution)


BC_AT_R, REPACK, NEURAL, MIXED, SPLIT, QUALITY = BcAtR(), BcRepack(), NeuralAt(), Mixed(), MipSplit(), BcQuality()
REGISTRY: tuple[Kind, ...] = (BC_AT_R, REPACK, NEURAL, MIXED, SPLIT)
CLASSIC = ClassicKinds(BC_AT_R, REPACK, QUALITY)  # what `classic_fit` makes its candidates of


def subset(ts: TextureSet, keep: Sequence[int]) -> TextureSet:
    """``ts`` restricted to the channels ``keep`` (in that order)."""
    keep = list(keep)
    return TextureSet(np.ascontiguousarray(ts.data[..., keep]), tuple(ts.channels[i] for i in keep),
                      ts.width, ts.height)


def capped(cfg, cap):
    """``cfg`` with the schedule ``cap`` (--layout neural's at the profile asked) where its own takes
    more steps: on a CPU a 2048² T_0 trains draft's 900 steps where a smaller fixed T_0 trains 2,500
    (config.FIXED_T0_PRESETS), so a probe at 1k cost 1.5× the neural build's training. Each of the
    layout's at most two trainings then costs no more steps than the neural one (docs/layout.md)."""
    if cap is None or cfg.preset.total_steps <= cap.total_steps:
        return cfg
    return cfg.with_(preset=cap)


def train_outside(ctx: FitContext, classic: Sequence[str], name: str, kind: Kind,
                  profile: str | None = None, width: int | None = None) -> Weighed:
    """Train the channels outside the ``classic`` groups at ``name`` (trained as ``profile``, by
    default ``ctx.own[name]``) with a T_0 of ``width`` layers (by default the options'), and measure
    the layout they make with those groups."""
    keep = tuple(c for c in range(ctx.ts.num_channels)
                 if not any(c in g.group.channels for g in ctx.classic.groups if g.group.name in classic))
    return weigh_trained(ctx, train_channels(ctx, keep, name, profile, width), classic, name, kind, keep)


def train_channels(ctx: FitContext, keep: Sequence[int], name: str, profile: str | None = None,
                   width: int | None = None) -> MaterialResult:
    """`train_outside`'s training: the ``keep`` channels at ``name``, measured (`FIGURES`) from
    their exported files under ``ctx.out``/neural. Reads no classic group: the likeliest training
    (`bcfpipe.layout.speculate`) starts before BC@R is encoded."""
    sub = subset(ctx.ts, list(keep))
    options = replace(ctx.options, profile=profile or ctx.own[name],
                      t0_layers=ctx.options.t0_layers if width is None else width)
    ref = ctx.reference
    if ref is not None and len(keep) < ctx.ts.num_channels:  # the subset's chain: its channels of the set's
        ref = Reference(tuple(np.ascontiguousarray(m[..., list(keep)]) for m in ref.mips), ref.masks, ref.wrap)
    return train_material(sub, ctx.out / "neural", capped(make_config(sub, options, ctx.wrap)[1], ctx.cap), name,
                          progress=ctx.progress, coverage=ctx.coverage, measure=FIGURES, reference=ref)[0]


def weigh_trained(ctx: FitContext, res: MaterialResult, classic: Sequence[str], name: str, kind: Kind,
                  keep: Sequence[int]) -> Weighed:
    """The candidate a model trained on the ``keep`` channels (`train_channels`) makes with the
    ``classic`` groups of BC@R, measured."""
    groups, keep = ctx.classic.groups, list(keep)
    e = ctx.classic.e_bc.copy()
    e[:, keep] = res.mse_per_channel
    classic_bytes = sum(g.size_bytes for g in groups if g.group.name in classic)
    disk = model_disk_bytes(res) + sum(disk_bytes(g) for g in groups if g.group.name in classic)
    return Weighed(C.Candidate(tuple(classic), name, res.size_bytes + classic_bytes, tuple(float(v) for v in e.mean(1)),
                               "measured", ctx.classic.use, NeuralPart(res.t0_layers), disk_bytes=disk, kind=kind),
                   res, tuple(keep))


def split_bytes(groups: Sequence[EncodedGroup], keep: int) -> int:
    """Bytes of BC@R's groups cut to their first ``keep`` levels (headers included)."""
    return sum(HEADER_BYTES + sum(g.level_bytes()[:keep]) for g in groups)


def split_disk_bytes(groups: Sequence[EncodedGroup], keep: int) -> int:
    """`split_bytes` on disk: each group's file of its first ``keep`` levels, zstd-compressed."""
    return sum(disk_bytes(g, keep) for g in groups)


def model_disk_bytes(res: MaterialResult) -> int:
    """A trained model's files on disk, each zstd-compressed: the ones its GPU bytes count (feature
    DDS files and weights.bin; `export.material.exported_size`)."""
    return shipped_disk_bytes(res.out_dir)


def split_candidates(ts: TextureSet, classic: ClassicFit, e_probe: np.ndarray, resolution: int, dims: tuple[int, int],
                     match_bc: bool = False, probe_t0: int = 0, halving_db: float = 0.0) -> list[C.Candidate]:
    """The mip splits worth training, ``predicted``: for each reference mip k >= 1, BC@R's levels
    that serve the mips below k and features T = (t, t, t, t/2) for s >= k, t the largest power of
    two no larger than mip k's side whose bytes (with the DDS headers) keep the whole within BC@R's
    size, t >= `MipSplit.MIN_SIDE`. Errors: BC@R's below k; from k on the probe's (T_0 = ``probe_t0``), worse by
    ``halving_db`` for every halving from probe_t0 to t (the measured gain between profiles, as
    rate control predicts). Only those that hold the floor on that prediction, and only where BC@R
    has more than one level to cut."""
    groups, e_bc, bc = classic.groups, classic.e_bc, classic.bc
    side = max(ts.width, ts.height)
    out = []
    for k in range(1, e_bc.shape[0]):
        keep = split_levels(k, resolution, side)
        if keep >= min(len(g.level_bytes()) for g in groups):
            break
        budget = bc.size_bytes - split_bytes(groups, keep)
        t = 1 << (max(1, side >> k).bit_length() - 1)
        while t >= MipSplit.MIN_SIDE and neural_bytes((t, t, t, t // 2), *dims, ts.num_channels) > budget:  # its files
            t //= 2
        if t < MipSplit.MIN_SIDE:
            continue
        res = (t, t, t, t // 2)
        size = neural_bytes(res, *dims, ts.num_channels)
        halvings = max(0.0, math.log2(probe_t0 / res[0])) if probe_t0 else 0.0
        err = e_probe * 10.0 ** (halvings * halving_db / 10.0)
        err[:k] = e_bc[:k]
        c = C.Candidate(bc.classic, "/".join(map(str, res)), bc.size_bytes - budget + size,
                        tuple(float(v) for v in err.mean(1)), "predicted", classic.use, SplitPart(k, res), kind=SPLIT)
        if C.deficit(c, bc, match_bc) <= 0:
            out.append(c)
    return out


def train_split(ctx: FitContext, cand: C.Candidate) -> Weighed:
    """Train ``cand``'s features (all channels, s >= its split) and measure the split layout. Below
    the split the layout decodes to BC@R exactly, from it on to the model (tests/test_split_layout.py)."""
    cfg = capped(make_config(ctx.ts, replace(ctx.options, t0_layers=1), ctx.wrap)[1], ctx.cap)  # as sized
    part = cand.part
    cfg = cfg.with_(model=replace(cfg.model, resolutions=part.resolutions, split=part.split))
    res, _ = train_material(ctx.ts, ctx.out / "split", cfg, cand.profile, progress=ctx.progress, coverage=ctx.coverage,
                          measure=FIGURES, reference=ctx.reference)
    err = res.mse_per_channel.copy()
    err[:part.split] = ctx.classic.e_bc[:part.split]
    keep = split_levels(part.split, ctx.resolution, max(ctx.ts.width, ctx.ts.height))
    m = replace(cand, size_bytes=res.size_bytes + split_bytes(ctx.classic.groups, keep),
                mse_per_mip=tuple(float(v) for v in err.mean(1)), basis="measured",
                disk_bytes=model_disk_bytes(res) + split_disk_bytes(ctx.classic.groups, keep))
    return Weighed(m, res, ctx.all_channels)
