"""Decide one material's layout (issues 31, 58): estimate the classic candidates, probe, weigh every
kind's candidates, train the one chosen at most, choose among what can ship, measured.

1. BC@R (every classic group, every mip), its BC7 repacks and the BC7 quality set, estimated from a
   sample of their blocks by the encoders that ship them (`bcfpipe.layout.classic_fit`,
   `bcfpipe.layout.estimate`): sizes exact, errors per mip within 0.16 dB of a full encode on the
   sets measured (docs/benchmarks.md), at 16 % of its texels on a 2048² set. Where no repack can
   take BC@R's place it is encoded in full instead: it ships or is the floor. Where a probe is
   planned and no training speculates, on a background thread beside the probe (`_gated`: the
   oracle on a smaller sample of BC@R gates the probe's start); elsewhere at once. No decision
   reads the quality set, so it is estimated on a thread beside the rest of the fit, with the
   cores the job may use beyond the fit's (`_quality_aside`; after BC@R's encode on its thread,
   where that runs beside the probe), and waited for by layout.json.
2. The probe: one neural model on all channels at p0, the largest profile no larger than the one
   asked for whose bytes fit within BC@R's (the smallest when none does: it measures the neural
   part of a mip split or a mixed layout), with a T_0 of one layer of principal components (or
   --t0-layers), trained for `PROBE_FRACTION` of the steps the preset asked takes and measured
   from its exported files, per channel; it never ships. What the same model trained in full
   holds is predicted from it with the measured per-mip gain of a full training over the probe
   (`bcfpipe.train.gains.PROBE_GAINS_DB`). No probe, and no training, when not even the smallest
   features fit within BC@R's bytes (`predict`), or when no candidate with a neural part could
   clear the floor even if it held all its T_0 can (`_ruled_out`: at the mips finer than T_0 the
   oracle, the reference's T_0-sized mip magnified, holds every prediction): BC@R and its repacks
   are then all that can ship.
3. Candidates: every kind of `bcfpipe.layout.kinds.REGISTRY` generates its own from (1) and (2)
   (BC@R, its repacks, neural at a profile and T_0 width, mixed: classic groups + neural, mip
   splits), with ``estimated`` or ``predicted`` figures (`bcfpipe.layout.choose`). The rule picks
   one. The BC7 quality set is reported against, never weighed.
4. One training at most, at the preset asked: the first choice, when it has a neural part (a mip
   split only when its prediction beats the classic choice, `Kind.worth`), through its kind. The
   BC@R groups it ships beside are encoded in full before it. When the first choice is classic, the
   candidate the rule would choose with the largest gain a full training made over the probe on
   any measured set (`_hopeful`, `gains.PROBE_GAINS_MAX_DB`) is trained instead, if it has a neural
   part; else nothing is. With a core to spare, where a probe is planned, the likeliest of these
   (`speculate.guess`: all channels at the probe's profile, the widest T_0 within BC@R's bytes)
   starts training on it (`bcfpipe.layout.speculate`): where R is below the set's side before
   step 1, beside BC@R's full encode (on the cores it leaves), the oracle and the probe
   (`_promising`); elsewhere when the probe starts. It is adopted when it is the one chosen, and
   dropped otherwise, or when the oracle rules out every neural candidate.
5. The final choice among the trained model and the classic candidates: a classic candidate that
   its estimate puts first is encoded in full and measured, and the choice made again, until the
   one chosen is measured (`_settle`). What ships is encoded once, at the shipping preset, and
   its measured figures are what layout.json reports; `bcfpipe.layout.export.export_layout`
   writes it as its kind does.

Cost: the estimates, the probe, and at most one training no larger than `--layout neural`'s
(`capped`), with BC@R encoded in full only when what ships is held to its floor by less than
`FLOOR_GUARD_DB` on BC@R's estimate; beside them, on a spare core from the fit's start, the
likeliest training, which is that one training when adopted. What each part took goes to the report's ``phase_seconds``
(``layout_estimate``, ``layout_probe``, ``layout_train``, ``layout_classic_encode``,
``layout_estimate_aside`` and ``layout_speculation_dropped``, beside the others), not to
layout.json, which a build writes byte for byte the same every time.
Splits are not weighed when ``--classic`` fixes groups.

``--classic`` names groups that stay classic: with ``auto`` every candidate keeps them; with
``neural`` the one layout they make is trained (the other channels at the profile asked), no probe.
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from bcfpipe.config import DEFAULT_ENCODE, ENCODE_PRESETS, N_LAYERS, PROFILES, TrainingOptions, shortened
from bcfpipe.export.material import PROBE, MaterialResult, train_material, make_config
from bcfpipe.formats.display import bytes_text
from bcfpipe.formats.sizes import neural_bytes, widened, widened_inputs
from bcfpipe.formats.vocabulary import Layout
from bcfpipe.layout import choose as C
from bcfpipe.layout import kinds as K
from bcfpipe.layout import speculate
from bcfpipe.layout.classic import groups as classic_groups
from bcfpipe.layout.classic import Repack, named_groups
from bcfpipe.layout.classic_fit import ClassicWork, estimated, measure, quality_errors, repackable, with_quality
from bcfpipe.layout.kinds import capped
from bcfpipe.layout.oracle import PerfectProbe
from bcfpipe.layout.predict import LayoutPrediction, Query, predict, widths_of
from bcfpipe.layout.result import LayoutFit
from bcfpipe.pooltrace import trace_pool
from bcfpipe.texset.parallel import background, encode_workers, workers
from bcfpipe.texset.chain import Reference
from bcfpipe.texset.texture_set import TextureSet
from bcfpipe.train.progress import ProgressFn

QualityFound = tuple["tuple[Repack, np.ndarray] | None", float]  # `classic_fit.quality_errors`' result, its seconds
PROBE_FRACTION = 0.15  # of the steps --layout neural trains: the probe's share of one training
PROBE_T0_BC7 = "alpha_modes"  # the probe's T_0 in BC7's modes with alpha: half the encode (`baselines.BC7_PROFILES`)
FLOOR_GUARD_DB = 0.25  # a choice held to BC@R's floor by less than this on BC@R's estimate measures BC@R
# Blocks per level of the sampled BC@R whose oracle gates the probe beside BC@R's full encode
# (`_gated`): the bottle's within 0.6 dB of the full encode per mip, 0.7 s on two cores (16384: 2.2 s)
GATE_BLOCKS = 1024


def predict_for(ts: TextureSet, options: TrainingOptions, cfg, asked: str, resolution: int) -> LayoutPrediction:
    """`bcfpipe.layout.predict.predict` for a loaded set: what `scan` and `plan` say of it."""
    groups = classic_groups(ts)
    return predict(Query(groups, ts.width, ts.height, ts.num_channels, ts.num_channels, asked,
                         tuple(cfg.model.resolutions), resolution, cfg.device,
                         (N_LAYERS * cfg.model.layer_channels, cfg.model.hidden), options.layout,
                         bool(options.match_bc), named_groups(groups, options.classic),
                         widths_of(options, options.layout, ts.num_channels)))


def _work(ctx: K.FitContext) -> ClassicWork:
    return ClassicWork(ctx.ts, ctx.resolution, ctx.reference, ctx.wrap, K.CLASSIC, ctx.log, progress=ctx.progress,
                       enc=ENCODE_PRESETS.get(ctx.options.preset, DEFAULT_ENCODE))


def _train_probe(ctx: K.FitContext) -> MaterialResult:
    """The probe: all channels at p0, a `PROBE_FRACTION` of the steps ``ctx.cap`` (--layout neural's)
    takes, so that it costs a fraction of one training, without the float model's figures. What
    a full training of the same model holds is predicted from it (`kinds.FitContext.neural_errors`);
    it never ships."""
    ctx.log(f"probe: all {ctx.ts.num_channels} channels at {ctx.p0}"
            + (f", T_0 of {ctx.w0} layers" if ctx.w0 > 1 else "") + f", {PROBE_FRACTION:.0%} of the steps")
    cfg = make_config(ctx.ts, replace(ctx.options, profile=ctx.own[ctx.p0], t0_layers=ctx.w0), ctx.wrap)[1]
    cfg = capped(cfg, ctx.cap)
    cfg = cfg.with_(preset=shortened(cfg.preset, PROBE_FRACTION), t0_bc7=PROBE_T0_BC7)
    return train_material(ctx.ts, ctx.out / "probe", cfg, ctx.p0, progress=ctx.progress, coverage=ctx.coverage,
                        measure=PROBE, reference=ctx.reference)[0]


def _sized(ctx: K.FitContext, cfg, pred: LayoutPrediction) -> K.FitContext:
    """``ctx`` with ``pred``'s p0, the profiles and T_0 widths weighed, and their bytes."""
    profiles, widths = tuple(pred.profiles), tuple(pred.t0_layers)
    dims = (N_LAYERS * cfg.model.layer_channels, cfg.model.hidden)
    sizes = {(p, w): neural_bytes(widened(PROFILES[p] if p in PROFILES else cfg.model.resolutions, w),
                                  widened_inputs(dims[0], w), dims[1], ctx.ts.num_channels)
             for p in profiles for w in widths}
    return replace(ctx, p0=pred.probe, w0=pred.probe_t0_layers, profiles=profiles, widths=widths, dims=dims,
                   sizes=sizes, own={p: (p if p in PROFILES else ctx.options.profile) for p in profiles})  # auto-N trains as "auto"


def _ruled_out(ctx: K.FitContext) -> list[K.Weighed] | None:
    """When no candidate with a neural part can clear the floor even if its model held all its T_0
    can (`oracle.PerfectProbe`), the probe would only confirm it and is not trained: then what the
    kinds weigh that is measured already; else None."""
    res = make_config(ctx.ts, replace(ctx.options, profile=ctx.own[ctx.p0], t0_layers=ctx.w0), ctx.wrap)[1]
    perfect = replace(ctx, probe=PerfectProbe(np.zeros_like(ctx.classic.e_bc), tuple(res.model.resolutions)))
    weighed = [w for kind in K.REGISTRY for w in kind.predict(perfect)]
    if any(C.admissible(w.candidate, ctx.classic.bc, ctx.match_bc) is None
           for w in weighed if w.candidate.profile is not None):
        return None
    return [w for w in weighed if w.candidate.basis == "measured"]


def _probed(ctx: K.FitContext) -> K.FitContext:
    """``ctx`` with the probe trained at its p0."""
    t = time.perf_counter()
    probe = _train_probe(ctx)
    ctx.costs["probe"] = time.perf_counter() - t
    return replace(ctx, probe=probe)


def _quality_aside(ctx: K.FitContext, work: ClassicWork, spare: int | None = None) -> Callable[[], QualityFound]:
    """The BC7 quality set's errors (`classic_fit.quality_errors`), which no decision reads: estimated
    on a thread beside the rest of the fit (the probe, which trains on its ``--threads``, one core by
    default; the oracle, the full encodes, the final measure), on the cores the job may use beyond
    the fit's, or on ``spare`` of them (after a probe that a speculative training ran beside, on
    the probe's core); with none to spare, here, before the rest. Returns what waits for them."""
    spare = speculate.spare_cores(ctx) if spare is None else spare
    if spare < 1:
        t = time.perf_counter()
        found = quality_errors(work, ctx.classic)
        ctx.costs["estimate"] = ctx.costs.get("estimate", 0.0) + time.perf_counter() - t
        return lambda: (found, 0.0)
    cf = ctx.classic

    def aside() -> QualityFound:
        t = time.perf_counter()
        with workers(spare):
            return quality_errors(work, cf), time.perf_counter() - t

    trace_pool("quality-estimate-aside", 1)
    pool = ThreadPoolExecutor(1, thread_name_prefix="bcfpipe-quality-estimate")
    later = pool.submit(aside)
    pool.shutdown(wait=False)  # the thread ends with its one task
    return later.result


def decide_layout(ts: TextureSet, out_dir: str | Path, options: TrainingOptions, resolution: int, *,
               wrap: str = "repeat", log: Callable[[str], None] = lambda s: None,
               progress: ProgressFn | None = None, reference: Reference | None = None) -> LayoutFit:
    """Choose and train ``ts``'s layout at BC resolution ``resolution``; neural files of the probe
    and of the chosen model go under ``out_dir``/probe and ``out_dir``/neural. The groups that
    ``options.classic`` names stay classic in every candidate; with ``--layout neural`` that one
    layout is trained, at the profile asked, without a probe. ``options.match_bc`` picks the objective.
    ``reference``: ``ts``'s chain and, with the coverage mask of the texels the scene reads, its masks
    (`Reference.of`): every figure is then over those texels and training draws there. Built here
    (no coverage) when None; shared by every encode, training and measure of the fit."""
    start = time.perf_counter()
    reference = reference if reference is not None else Reference.of(ts, None, wrap)
    coverage = reference.coverage
    asked, cfg = make_config(ts, options, wrap)
    ctx = K.FitContext(ts, Path(out_dir), options, wrap, resolution, named_groups(classic_groups(ts), options.classic),
                       progress=progress, coverage=coverage, log=log, reference=reference, costs={})
    work = _work(ctx)
    if options.layout == Layout.NEURAL:  # BC@R in full: what the neural layout is reported against
        cf = estimated(work, with_repacks=False)  # BC@R encoded in full: no repack weighed
        return _fixed(replace(ctx, classic=cf), asked, start)
    pred = predict_for(ts, options, cfg, asked, resolution)
    # no training here takes more steps than --layout neural's (at the profile asked)
    sized = _sized(replace(ctx, cap=cfg.preset), cfg, pred) if pred.probe is not None else None
    # where a probe is planned below the set's side, the likeliest training at once on a spare core;
    # elsewhere when the probe starts (below), beside it
    spec = speculate.start(sized, pred.bc_bytes) if sized is not None and _promising(sized) else None
    early = sized is not None and spec is None and _beside_bc(sized, work)
    try:
        # BC@R in full beside the probe, unless the oracle on its estimate rules the probe out; or first
        ctx, quality = _gated(sized, work) if early else _estimated(sized or ctx, work, spec)
        if pred.probe is None:
            quality = quality if quality is not None else _quality_aside(ctx, work)
            log(f"no probe: nothing neural fits within BC@R's {bytes_text(ctx.classic.bc.size_bytes)}")
            return _settle(ctx, work, [], None, start, quality)
        if (measured := _ruled_out(ctx)) is not None:
            if spec is not None:
                ctx.costs["speculation_dropped"] = spec.cancel()
            if ctx.probe is not None:  # trained beside BC@R's encode, whose measure rules out what it would weigh
                ctx.costs["probe_dropped"] = ctx.costs.pop("probe")
                ctx = replace(ctx, probe=None)
            quality = quality if quality is not None else _quality_aside(ctx, work)
            log("no probe: no neural candidate can clear the floor at the mips finer than its T_0, where the "
                "reference's T_0-sized mip magnified (the oracle) holds it")
            fit = _settle(ctx, work, measured, None, start, quality)
        else:
            spec = spec if spec is not None or quality is not None else speculate.start(ctx)  # beside the probe
            if quality is None and spec is None:
                quality = _quality_aside(ctx, work)
            fit = _probe_and_train(ctx, work, spec, quality, start)
    except BaseException:  # failed or interrupted: no training left running
        if spec is not None:
            spec.cancel()
            spec.join(ctx.out)
        raise
    return replace(fit, aside=(lambda: spec.join(ctx.out)) if spec is not None else None)


def _estimated(ctx: K.FitContext, work: ClassicWork, spec: speculate.Speculation | None
               ) -> tuple[K.FitContext, Callable[[], QualityFound] | None]:
    """Step 1 before the rest: ``ctx`` with BC@R and its repacks estimated (BC@R encoded in full where
    no repack can take its place), on the cores ``spec``'s training leaves; and the quality set
    aside at once, unless a training may take the spare core beside the probe (then None)."""
    t, encoding = time.perf_counter(), work.seconds
    with speculate.beside(spec, ctx):
        ctx = replace(ctx, classic=estimated(work, with_repacks=True, quality=False))
    ctx.costs["estimate"] = time.perf_counter() - t - (work.seconds - encoding)  # BC@R in full counts as encode
    return ctx, None if speculate.possible(ctx) else _quality_aside(ctx, work)


def _promising(ctx: K.FitContext) -> bool:
    """Whether the likeliest training starts before BC@R's full encode, which it holds to the cores
    it leaves, rather than beside the probe, which leaves a core idle: where it may speculate
    (`speculate.possible`) and R is below the set's side. At R = the side BC@R ships on every set
    measured, and a training started there, dropped, only slowed BC@R's encode: on the water bottle
    at standard 35.6 s on two cores became 60.0 s on one (the run 94.2 -> 121.5 s), the teapot's
    38.5 s 70.8 s. At R = 1024 the bottle ships its neural part, and its BC@R, 10-12 s on two
    cores, runs beside the training. (Ruling the start out first by the oracle on a sampled BC@R,
    as step 2 does on the full one, cost the bottle 5.7 s at R = 1024, about what it saves.)"""
    return speculate.possible(ctx) and ctx.resolution < max(ctx.ts.width, ctx.ts.height)


def may_encode_beside(options: TrainingOptions) -> bool:
    """Whether a fit with ``options`` may encode BC@R beside its probe (`_beside_bc`), as far as the
    options tell before the set is loaded: at a preset where no training speculates, with a core
    beyond the probe's."""
    return options.preset not in speculate.PRESETS and encode_workers() - (options.threads or 1) >= 1


def _beside_bc(ctx: K.FitContext, work: ClassicWork) -> bool:
    """Whether BC@R's full encode runs beside the probe rather than before it: where no repack can
    take BC@R's place (it ships or is the floor: `classic_fit.repackable`), so that it is encoded
    in full whatever the probe finds; where no training speculates (`speculate.possible`: at draft
    and smoke) and the job has a core beyond the probe's; on a set small enough for the probe's
    training and BC@R's decoded chain at once (`speculate.MAX_VALUES`)."""
    return (not speculate.possible(ctx) and speculate.spare_cores(ctx) >= 1
            and ctx.ts.data.size <= speculate.MAX_VALUES and not repackable(work))


def _gated(ctx: K.FitContext, work: ClassicWork) -> tuple[K.FitContext, Callable[[], QualityFound]]:
    """BC@R encoded in full and measured, then the quality set estimated, on a thread that yields the
    cores to this one (`parallel.background`), on every core the job may use (quicktex in worker
    processes: `parallel.workers`' ``beside``); meanwhile on this thread BC@R estimated from
    `GATE_BLOCKS` blocks per level and, unless the oracle on that estimate rules out every neural
    candidate (`_ruled_out`), the probe. Returns ``ctx`` with BC@R measured and the probe (or None),
    and what waits for the quality set. The estimate only gates the probe's start: the fit weighs
    the measured BC@R. A fit that fails stops the encode at its next group, and waits for it."""
    cores = encode_workers()
    shown, cancelled = threading.Event(), threading.Event()
    lines: list[str] = []

    def report(p) -> None:
        if cancelled.is_set():
            raise speculate.Cancelled()
        if shown.is_set() and work.progress is not None:
            work.progress(p)

    quiet = replace(work, progress=report, log=lines.append, seconds=0.0)
    encoded: Future = Future()

    def encode() -> QualityFound:
        background()  # the probe first: the fit waits for it
        with workers(cores, beside=True):
            try:
                encoded.set_result(estimated(quiet, whole_bc=True, quality=False))
            except BaseException as e:  # noqa: BLE001 - raised again on the fit's thread
                encoded.set_exception(e)
                raise
            if cancelled.is_set():
                raise speculate.Cancelled()
            t = time.perf_counter()
            return quality_errors(quiet, encoded.result()), time.perf_counter() - t

    trace_pool("bc-encode-beside-probe", 1)
    pool = ThreadPoolExecutor(1, thread_name_prefix="bcfpipe-bc-encode")
    later = pool.submit(encode)
    pool.shutdown(wait=False)
    try:
        t = time.perf_counter()
        ctx = replace(ctx, classic=estimated(work, whole_bc=False, quality=False, budget=GATE_BLOCKS))
        ctx.costs["estimate"] = time.perf_counter() - t
        if _ruled_out(ctx) is None:
            ctx.log("BC@R encoded in full meanwhile, on the cores the probe leaves")
            ctx = _probed(ctx)
        shown.set()
        cf = encoded.result()
    except BaseException:
        cancelled.set()
        later.exception()  # it stops at its next group
        raise
    work.seconds += quiet.seconds
    for line in lines:
        ctx.log(line)
    return replace(ctx, classic=cf), later.result


def _probe_and_train(ctx: K.FitContext, work: ClassicWork, spec: speculate.Speculation | None,
                     quality: Callable[[], QualityFound] | None, start: float) -> LayoutFit:
    """Steps 2-5 where a probe runs: the probe, the first choice, its one training (``spec``'s,
    adopted, or dropped for another) and the final choice."""
    ctx = ctx if ctx.probe is not None else _probed(ctx)
    if quality is None:  # the spare cores train: the quality set now, on the probe's
        quality = _quality_aside(ctx, work, spare=ctx.options.threads or 1)
    weighed = [w for kind in K.REGISTRY for w in kind.predict(ctx)]
    cands = [w.candidate for w in weighed]
    first = C.choose(cands, ctx.classic.bc, ctx.match_bc, ctx.classic.quality)
    ctx.log(f"first choice: {first.chosen.label} ({first.chosen.basis})")
    chosen = first.chosen if first.chosen.profile is not None else _hopeful(ctx, first.chosen)
    ctx, trained = _train_next(ctx, work, chosen, cands, spec)
    if spec is not None and spec.pending:  # nothing trains: dropped, running or (a short one) done
        ctx.costs["speculation_dropped"] = spec.cancel()
    ready = [w for w in weighed if w.candidate.basis == "measured"] + ([trained] if trained else [])
    return _settle(ctx, work, ready, first, start, quality)


def _hopeful(ctx: K.FitContext, held: C.Candidate) -> C.Candidate:
    """When the mean predictions ship ``held``, a classic candidate: the candidate the rule would
    choose if its full training gained over the probe the most any measured set did
    (`gains.PROBE_GAINS_MAX_DB`), when that one has a neural part; else ``held``. Its own training
    confirms it or not."""
    cands = [w.candidate for kind in K.REGISTRY for w in kind.predict(replace(ctx, most=True))]
    best = C.choose(cands, ctx.classic.bc, ctx.match_bc).chosen
    if best.profile is None:
        return held
    ctx.log(f"{best.label} clears the floor only with the largest gain measured on any set: training it")
    return best


def _settle(ctx: K.FitContext, work: ClassicWork, ready: list[K.Weighed], first: C.Decision | None,
            start: float, quality: Callable[[], QualityFound]) -> LayoutFit:
    """The final choice among what can ship: what is measured (``ready``: the trained model, if
    any, and any kind's measured candidates) and the classic candidates.
    A classic candidate that an estimate puts first is encoded in full and measured, and the choice
    made again, until the one chosen is measured; BC@R is measured too when what ships is held to
    its floor by less than `FLOOR_GUARD_DB` (an estimate's error must not decide it)."""
    while True:
        cf = ctx.classic
        pool = [t.candidate for t in ready] + [c for c in cf.packed if set(ctx.forced) <= set(c.classic)]
        decision = C.choose(pool, cf.bc, ctx.match_bc, cf.quality)
        c = decision.chosen
        if c.basis != "measured":  # a classic candidate on its estimate: encode it, weigh again
            ctx = replace(ctx, classic=measure(work, cf, c))
            continue
        if not cf.measured and c.label != cf.bc.label and _near_floor(c, cf.bc, ctx.match_bc):
            ctx.log(f"{c.label} is within {FLOOR_GUARD_DB:g} dB of BC@R's floor on its estimate: measuring BC@R")
            ctx = replace(ctx, classic=measure(work, cf))
            continue
        break
    held = {t.candidate.label: t for t in ready}
    model = held.get(c.label, K.Weighed(c))
    ctx.costs["classic_encode"] = work.seconds
    train_s = sum(t.model.train_seconds for t in ready if t.model is not None)
    probe = ctx.probe

    def quality_set() -> tuple[C.Candidate, float]:
        found, seconds = quality()
        return with_quality(work, cf, found).quality, seconds

    return LayoutFit(decision, first or decision, cf.groups, model.model, model.channels, probe,
                     train_s + (probe.train_seconds if probe else 0.0), time.perf_counter() - start, cf.repacked,
                     work.seconds + ctx.costs.get("estimate", 0.0), model.parts,
                     costs={k: round(v, 1) for k, v in ctx.costs.items()}, quality_later=quality_set)


def _near_floor(c: C.Candidate, bc: C.Candidate, match_bc: bool) -> bool:
    """Whether ``c``'s worst mip is within `FLOOR_GUARD_DB` of its floor against ``bc``, BC@R on its
    estimate."""
    return -C.deficit(c, bc, match_bc) < FLOOR_GUARD_DB


def _train_next(ctx: K.FitContext, work: ClassicWork, chosen: C.Candidate, cands: Sequence[C.Candidate],
                spec: speculate.Speculation | None = None) -> tuple[K.FitContext, K.Weighed | None]:
    """The one training of the fit, at the preset asked, at most: ``chosen`` (the first choice, or
    `_hopeful`'s), if it has a neural part and its kind finds it worth that against the classic
    candidates; else none.
    The BC@R groups the model ships beside are encoded in full first (a split's: all); BC@R itself
    is measured later only if the model is chosen near its floor (`_settle`)."""
    classic = [c for c in cands if c.profile is None]
    held = C.choose(classic, ctx.classic.bc, ctx.match_bc).chosen
    if chosen.profile is None:
        ctx.log("no neural candidate clears the floor on its prediction: no training")
        return ctx, None
    if not chosen.kind.worth(ctx, chosen, held):
        ctx.log(f"{chosen.label} does not beat {held.label} on its prediction: no training")
        return ctx, None
    if spec is not None and spec.matches(chosen):
        ctx.log(f"training the channels outside the classic groups at {chosen.profile} for: {chosen.label} "
                f"(begun beside the probe)")
        trained = spec.adopt(ctx)
        ctx.costs["train"] = time.perf_counter() - spec.start
        return ctx, trained
    if spec is not None:
        ctx.costs["speculation_dropped"] = spec.cancel()  # it stops while this one trains
    need = None if chosen.kind is K.SPLIT else chosen.classic  # what the model ships beside
    if need is None or need:
        ctx = replace(ctx, classic=measure(work, ctx.classic, only=need))
    t = time.perf_counter()
    trained = chosen.kind.train(ctx, chosen)
    ctx.costs["train"] = time.perf_counter() - t
    return ctx, trained


def _fixed(ctx: K.FitContext, asked: str, start: float) -> LayoutFit:
    """``--layout neural``, with ``--classic`` or without: the named groups classic, the rest at the
    profile asked."""
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
