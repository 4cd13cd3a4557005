"""Fit one material's layout (issue 31): measure BC@R, probe, weigh every kind's candidates,
train the one chosen, choose among what is measured.

1. Encode BC@R (every classic group, every mip) and its BC7 repacks and measure them per channel:
   exact, no training.
2. The probe: one neural model on all channels at p0, the largest profile no larger than the one
   asked for whose bytes fit within BC@R's (the smallest when none does: it measures the neural
   part of a mip split or a mixed layout), with a T_0 of one layer of principal components (or
   --t0-layers), trained and measured from its exported files, per channel. No probe, and no
   training, when not even the smallest features fit within BC@R's bytes (`predict`): BC@R and
   its repacks are all that can ship.
3. Candidates: every kind of `bcfpipe.layout.kinds.REGISTRY` generates its own from (1) and (2)
   (BC@R, its repacks, neural at a profile and T_0 width, mixed: classic groups + neural, mip
   splits), with ``measured``, ``bound`` or ``predicted`` figures (`bcfpipe.layout.choose`). The
   rule picks one. The BC7 quality set is measured beside BC@R and reported, never weighed.
4. One more training at most, through the chosen candidate's kind: a mip split only when its
   prediction beats what is measured already (`Kind.worth`); when the pick needs no new model
   (BC@R, a repack, the probe), the explorable candidate closest to qualifying
   (`choose.most_promising`: a mixed one, or a wider T_0 than the probe's) is trained instead.
   The final choice is made among measured layouts only: BC@R, the repacks, the probe, and that
   one model; `bcfpipe.layout.export.export_layout` writes it as its kind does.

Cost: the probe plus at most one training, each at a profile no larger than the one asked for and
with no more steps than `--layout neural` trains there (`capped`), so at most twice its training.
BC@R's bytes, hence p0, follow from block counts (`bcfpipe.layout.predict`), so BC@R and its
repacks encode in a thread beside the probe's training, over the job's cores
(`bcfpipe.texset.parallel`). Splits are not weighed when ``--classic`` fixes groups.

``--classic`` names groups that stay classic: with ``auto`` every candidate keeps them; with
``neural`` the one layout they make is trained (the other channels at the profile asked), no probe.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from bcfpipe.config import N_LAYERS, PROFILES, TrainingOptions
from bcfpipe.export.fit import MaterialResult, fit_material, make_config
from bcfpipe.formats.display import bytes_text
from bcfpipe.formats.sizes import neural_bytes, widened, widened_inputs
from bcfpipe.formats.vocabulary import Layout
from bcfpipe.layout import choose as C
from bcfpipe.layout import kinds as K
from bcfpipe.layout.classic import (MAX_REPACK_SIDE, EncodedGroup, Group, Repack, bc7_quality_set, channel_errors,
                                    disk_bytes, encode, measure_repack, repacks)
from bcfpipe.layout.classic import groups as classic_groups
from bcfpipe.layout.kinds import ClassicFit, capped, split_bytes, split_candidates, subset  # noqa: F401
from bcfpipe.layout.predict import LayoutPrediction, Query, predict, widths_of
from bcfpipe.texset.parallel import encode_workers, workers
from bcfpipe.texset.texture_set import TextureSet, build_mip_chain
from bcfpipe.train.trainer import ProgressFn


@dataclass
class LayoutFit:
    """What `fit_layout` decided and trained."""

    decision: C.Decision  # among measured layouts
    first: C.Decision  # among all candidates, some predicted: what was trained next
    classic: list[EncodedGroup]  # every group of BC@R
    neural: MaterialResult | None  # the chosen layout's model (None: all classic)
    neural_channels: tuple[int, ...]  # the texture set's channels it decodes
    probe: MaterialResult | None  # None when --classic fixed the layout
    train_seconds: float  # training of the probe and of the second model, if any
    seconds: float  # everything: BC@R, trainings, exports and measuring
    repacked: dict[str, tuple[Repack, list[EncodedGroup]]] = field(default_factory=dict)  # by Repack.label
    encode_seconds: float = 0.0  # BC@R's and its repacks' encodes and measuring (beside the probe: overlapping it)
    parts: Any = None  # what the chosen candidate's kind exports beside the model (`kinds.Weighed.parts`)


def named_groups(groups: Sequence[Group | EncodedGroup], semantics: Sequence[str]) -> tuple[str, ...]:
    """The names of the groups that hold one of ``semantics`` (--classic): a packed group goes whole."""
    wanted = set(semantics)
    names = [getattr(g, "group", g).name for g in groups]
    return tuple(n for n in names if wanted & set(n.split("+")))


def predict_for(ts: TextureSet, options: TrainingOptions, cfg, asked: str, resolution: int) -> LayoutPrediction:
    """`bcfpipe.layout.predict.predict` for a loaded set: what `scan` and `plan` say of it."""
    groups = classic_groups(ts)
    return predict(Query(groups, ts.width, ts.height, ts.num_channels, ts.num_channels, asked,
                         tuple(cfg.model.resolutions), resolution, cfg.device,
                         (N_LAYERS * cfg.model.layer_channels, cfg.model.hidden), options.layout,
                         bool(options.match_bc), named_groups(groups, options.classic),
                         widths_of(options, options.layout, ts.num_channels)))


def _measure_classic(ctx: K.FitContext, with_repacks: bool, lines: list[str] | None = None) -> ClassicFit:
    """Encode BC@R (every group, every mip) and measure it per channel, then its BC7 repacks (up to
    R = 4096, when ``with_repacks``). ``lines``: where to collect what it says (for a thread beside
    the training) instead of ``ctx.log``."""
    ts, resolution, wrap = ctx.ts, ctx.resolution, ctx.wrap
    say = ctx.log if lines is None else lines.append
    t = time.perf_counter()
    if lines is None:
        say(f"BC@{resolution}: encoding every mip")
    ref = build_mip_chain(ts.data)
    use = tuple(k for k, m in enumerate(ref) if min(m.shape[:2]) >= 4) or tuple(range(len(ref)))
    groups = encode(ts, resolution, ref, wrap)
    masks = None
    if ctx.coverage is not None:  # every figure over the texels the scene reads
        from bcfpipe.scan.coverage import mask_mips

        masks = mask_mips(ctx.coverage, len(ref), wrap)
    e_bc = channel_errors(ts, groups, ref, masks)
    for g in groups:  # measured: from here on BC@R is its blocks and these errors. An 8192² set's
        g.decoded = []  # decoded mips and reference chain hold 2.7 GiB each, which training needs
    names = [g.group.name for g in groups]
    bc = C.Candidate(tuple(names), None, sum(g.size_bytes for g in groups),
                     C.combine(None, e_bc, range(ts.num_channels)), "measured", use,
                     disk_bytes=sum(disk_bytes(g) for g in groups), kind=K.BC_AT_R)
    say(f"BC@{resolution}: {bytes_text(bc.size_bytes)}, {bc.psnr:.2f} dB over all mips "
        f"({time.perf_counter() - t:.1f} s)")
    cf = ClassicFit(groups, e_bc, bc, use)
    if with_repacks and resolution <= MAX_REPACK_SIDE:
        repacked, packed = _repacks(ctx, cf, ref, masks, say)
        cf = replace(cf, repacked=repacked, packed=tuple(packed), quality=_quality_set(ctx, cf, ref, masks, say))
    return replace(cf, seconds=time.perf_counter() - t)


def _quality_set(ctx: K.FitContext, cf: ClassicFit, ref, masks, log) -> C.Candidate:
    """The BC7 quality set (`classic.bc7_quality_set`) encoded and measured exactly; BC@R itself when
    BC@R has no BC1 texture."""
    rp = bc7_quality_set([g.group for g in cf.groups])
    if rp is None:
        return replace(cf.bc, kind=K.QUALITY)
    enc, e, size = measure_repack(ctx.ts, cf.groups, cf.e_bc, rp, ctx.resolution, ref, masks, ctx.wrap)
    disk = sum(disk_bytes(g) for g in cf.groups if g.group.name not in rp.replaces) + sum(disk_bytes(g) for g in enc)
    c = C.Candidate(cf.bc.classic, None, size, C.combine(None, e, range(ctx.ts.num_channels)), "measured", cf.bc.use,
                    repack=rp.label, disk_bytes=disk, kind=K.QUALITY)
    log(f"BC7 quality set at {ctx.resolution}: {bytes_text(size)}, {c.psnr:.2f} dB over all mips")
    return c


def _in_workers(n: int, fn, *args):
    """``fn(*args)`` with this thread's encodes on ``n`` cores."""
    with workers(n):
        return fn(*args)


def _train_probe(ctx: K.FitContext) -> MaterialResult:
    """The probe: all channels at p0, no more steps than ``ctx.cap``."""
    ctx.log(f"probe: all {ctx.ts.num_channels} channels at {ctx.p0}"
            + (f", T_0 of {ctx.w0} layers" if ctx.w0 > 1 else ""))
    cfg = capped(make_config(ctx.ts, replace(ctx.options, profile=ctx.own[ctx.p0], t0_layers=ctx.w0), ctx.wrap)[1],
                 ctx.cap)
    return fit_material(ctx.ts, ctx.out / "probe", cfg, ctx.p0, progress=ctx.progress, coverage=ctx.coverage,
                        image_metrics=False)[0]


def _classic_and_probe(ctx: K.FitContext) -> tuple[ClassicFit, MaterialResult]:
    """BC@R and its repacks measured, and the probe trained: the encodes on the cores the probe's
    training leaves (its --threads), in a thread beside it, when there are such cores."""
    if max(ctx.ts.width, ctx.ts.height) > MAX_REPACK_SIDE or encode_workers() <= 1:
        cf = _measure_classic(ctx, True)
        return cf, _train_probe(ctx)
    from concurrent.futures import ThreadPoolExecutor

    lines: list[str] = []
    with ThreadPoolExecutor(1) as pool:
        ctx.log(f"BC@{ctx.resolution}: encoding every mip and its repacks beside the probe")
        # every core the job has: no core idles while the other of the two still runs
        fut = pool.submit(_in_workers, encode_workers(), _measure_classic, ctx, True, lines)
        probe = _train_probe(ctx)
        cf = fut.result()
    for line in lines:
        ctx.log(line)
    return cf, probe


def _probed(ctx: K.FitContext, cfg, pred: LayoutPrediction) -> K.FitContext:
    """``ctx`` with BC@R measured, the probe trained at ``pred``'s p0 and the profiles weighed."""
    profiles, widths = tuple(pred.profiles), tuple(pred.t0_layers)
    dims = (N_LAYERS * cfg.model.layer_channels, cfg.model.hidden)
    sizes = {(p, w): neural_bytes(widened(PROFILES[p] if p in PROFILES else cfg.model.resolutions, w),
                                  widened_inputs(dims[0], w), dims[1], ctx.ts.num_channels)
             for p in profiles for w in widths}
    ctx = replace(ctx, p0=pred.probe, w0=pred.probe_t0_layers, profiles=profiles, widths=widths, dims=dims,
                  own={p: (p if p in PROFILES else ctx.options.profile) for p in profiles})  # auto-N trains as "auto"
    cf, probe = _classic_and_probe(ctx)
    sizes[(ctx.p0, ctx.w0)] = probe.size_bytes
    return replace(ctx, classic=cf, probe=probe, sizes=sizes, probe_disk=K.model_disk_bytes(probe))


def fit_layout(ts: TextureSet, out_dir: str | Path, options: TrainingOptions, resolution: int, *,
               wrap: str = "repeat", log: Callable[[str], None] = lambda s: None,
               progress: ProgressFn | None = None, coverage: np.ndarray | None = None) -> LayoutFit:
    """Choose and train ``ts``'s layout at BC resolution ``resolution``; neural files of the probe
    and of the chosen model go under ``out_dir``/probe and ``out_dir``/neural. The groups that
    ``options.classic`` names stay classic in every candidate; with ``--layout neural`` that one
    layout is trained, at the profile asked, without a probe. ``options.match_bc`` picks the objective."""
    start = time.perf_counter()
    asked, cfg = make_config(ts, options, wrap)
    ctx = K.FitContext(ts, Path(out_dir), options, wrap, resolution, named_groups(classic_groups(ts), options.classic),
                       progress=progress, coverage=coverage, log=log)
    if options.layout == Layout.NEURAL:
        return _fixed(replace(ctx, classic=_measure_classic(ctx, False)), asked, start)
    pred = predict_for(ts, options, cfg, asked, resolution)
    if pred.probe is None:
        return _classic_only(ctx, start)
    # no training here takes more steps than --layout neural's (at the profile asked)
    ctx = _probed(replace(ctx, cap=cfg.preset), cfg, pred)
    weighed = [w for kind in K.REGISTRY for w in kind.predict(ctx)]
    cands = [w.candidate for w in weighed]
    held = [w for w in weighed if w.candidate.basis == "measured"]
    bc = ctx.classic.bc
    first = C.choose(cands, bc, ctx.match_bc, ctx.classic.quality)
    log(f"first choice: {first.chosen.label} ({first.chosen.basis})")
    trained = _train_next(ctx, first.chosen, cands, [t.candidate for t in held])
    train_s = ctx.probe.train_seconds + (trained.model.train_seconds if trained else 0.0)
    held += [trained] if trained else []
    decision = C.choose([t.candidate for t in held], bc, ctx.match_bc, ctx.classic.quality)
    model = {t.candidate.label: t for t in held}[decision.chosen.label]
    return LayoutFit(decision, first, ctx.classic.groups, model.model, model.channels, ctx.probe, train_s,
                     time.perf_counter() - start, ctx.classic.repacked, ctx.classic.seconds, model.parts)


def _classic_only(ctx: K.FitContext, start: float) -> LayoutFit:
    """No neural layout fits within BC@R's bytes (`predict` gives no probe: a tiny set's features
    alone exceed them): BC@R and its repacks, measured; nothing trains."""
    cf = _measure_classic(ctx, True)
    ctx.log(f"no probe: nothing neural fits within BC@R's {bytes_text(cf.bc.size_bytes)}")
    packed = [c for c in cf.packed if set(ctx.forced) <= set(c.classic)]
    decision = C.choose(packed, cf.bc, ctx.match_bc, cf.quality)
    return LayoutFit(decision, decision, cf.groups, None, (), None, 0.0, time.perf_counter() - start,
                     cf.repacked, cf.seconds)


def _train_next(ctx: K.FitContext, chosen: C.Candidate, cands: Sequence[C.Candidate],
                measured: Sequence[C.Candidate]) -> K.Weighed | None:
    """One more training at most: the first choice ``chosen``, if its kind trains it and it is worth
    that against the choice among ``measured``; when it needs no new model, the explorable candidate
    closest to the floor (`choose.most_promising`); None when neither needs one."""
    bc = ctx.classic.bc
    held = C.choose(measured, bc, ctx.match_bc).chosen
    if not chosen.kind.worth(ctx, chosen, held):
        chosen = held
    if not chosen.kind.trains(ctx, chosen):  # nothing new is certain: explore
        alt = C.most_promising([c for c in cands if c.kind.explorable], bc, ctx.match_bc)
        if alt is not None:
            ctx.log(f"no candidate clears the floor on its bound; training the closest: {alt.label} "
                    f"({C.deficit(alt, bc, ctx.match_bc):.1f} dB short)")
            chosen = alt
    return chosen.kind.train(ctx, chosen) if chosen.kind.trains(ctx, chosen) else None


def _repacks(ctx: K.FitContext, cf: ClassicFit, ref, masks, log) -> tuple[dict, list[C.Candidate]]:
    """Every BC7 repack of BC@R (`classic.repacks`), encoded and measured exactly:
    ({label: (repack, encoded groups)}, candidates)."""
    ts, resolution, groups = ctx.ts, ctx.resolution, cf.groups
    found, cands = {}, []
    for rp in repacks([g.group for g in groups]):
        t = time.perf_counter()
        enc, e, size = measure_repack(ts, groups, cf.e_bc, rp, resolution, ref, masks, ctx.wrap)
        for g in enc:
            g.decoded = []
        kept = tuple(g.group.name for g in groups if g.group.name not in rp.replaces)
        disk = sum(disk_bytes(g) for g in groups if g.group.name in kept) + sum(disk_bytes(g) for g in enc)
        c = C.Candidate(kept + tuple(g.name for g in rp.groups), None, size,
                        C.combine(None, e, range(ts.num_channels)), "measured", cf.bc.use, repack=rp.label,
                        disk_bytes=disk, kind=K.REPACK)
        log(f"BC@{resolution} with {rp.label}: {bytes_text(size)}, {c.psnr:.2f} dB over all mips "
            f"({time.perf_counter() - t:.1f} s)")
        found[rp.label] = (rp, enc)
        cands.append(c)
    return found, cands


def _fixed(ctx: K.FitContext, asked: str, start: float) -> LayoutFit:
    """``--classic`` with ``--layout neural``: the named groups classic, the rest at the profile asked."""
    cf, forced, classic = ctx.classic, ctx.forced, ctx.options.classic
    bc = cf.bc
    if len(forced) == len(cf.groups):
        decision = C.Decision(bc, (bc,), bc, f"--classic {','.join(classic)} names every group: shipping BC@R",
                              "quality")
        return LayoutFit(decision, decision, cf.groups, None, (), None, 0.0, time.perf_counter() - start,
                         encode_seconds=cf.seconds)
    ctx.log(f"training the channels outside {', '.join(forced)} at {asked}")
    t = K.train_outside(ctx, forced, asked, K.MIXED if forced else K.NEURAL, profile=ctx.options.profile)
    m = t.candidate
    worst = min(m.margins(bc)[k] for k in bc.use)
    kept = f"{', '.join(forced)} kept as BC textures" if forced else "no channel group of this set named"
    decision = C.Decision(bc, (bc, m), m, f"--classic {','.join(classic)}: {kept}, the rest neural at {asked} "
                          f"(worst mip {worst:+.1f} dB against BC@R)", "quality")
    return LayoutFit(decision, decision, cf.groups, t.model, t.channels, None, t.model.train_seconds,
                     time.perf_counter() - start, encode_seconds=cf.seconds)
