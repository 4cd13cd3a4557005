"""Fit one material's layout (issue 31): probe, choose, train what was chosen, measure it.

1. Encode BC@R (every classic group, every mip) and measure it per channel: exact, no training.
2. The probe: one neural model on all channels at p0, the largest profile no larger than the one
   asked for whose bytes fit within BC@R's (the smallest when none does), trained and measured
   from its exported files, per channel.
3. Candidates: every subset of classic groups × every profile up to the one asked for, with
   figures from (1) and (2) (`bcfpipe.layout.choose`: ``bound`` at p0, ``predicted`` elsewhere).
   The rule picks one; when it picks BC@R or the probe, the mixed candidate closest to qualifying
   (`choose.most_promising`) is picked for training instead.
4. If that needs a model the probe is not (fewer channels, or another profile), the model is
   trained on its channels alone and measured.
   Mip splits (`split_candidates`) are candidates of step 3 too: BC@R's own levels below a
   reference mip k, features for s >= k at the largest size that keeps the whole within BC@R's
   bytes, predicted from BC@R's errors below k and the probe's from k on (moved by the measured
   loss per halving of T_0). One that the rule picks is trained (s drawn in [k, s_max],
   ModelConfig.split) and measured instead, when it beats what is measured already; a split
   that holds the floor on its prediction goes before exploring a mixed one that does not.
   The final choice is made among measured layouts only: BC@R, the probe, and that one model.

Cost: the probe plus at most one training, each at a profile no larger than the one asked for and
with no more steps than `--layout neural` trains there (`capped`), so at most twice its training.
BC@R's bytes, hence p0, follow from block counts (`bcfpipe.layout.predict`), so BC@R and its
repacks encode in a thread beside the probe's training, over the job's cores
(`bcfpipe.texset.parallel`). Splits are not weighed when ``--classic`` fixes groups.

``--classic`` names groups that stay classic: with ``auto`` every candidate keeps them; with
``neural`` the one layout they make is trained (the other channels at the profile asked), no probe.
"""
from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from bcfpipe.config import PROFILES, TrainingOptions
from bcfpipe.formats.sizes import neural_bytes
from bcfpipe.formats.vocabulary import Layout
from bcfpipe.export.fit import MaterialResult, fit_material, make_config
from bcfpipe.layout import choose as C
from bcfpipe.layout.classic import (MAX_REPACK_SIDE, EncodedGroup, Group, Repack, channel_errors, encode,
                                    measure_repack, repacks, split_levels)
from bcfpipe.layout.classic import groups as classic_groups
from bcfpipe.layout.predict import LayoutPrediction, candidate_profiles, predict  # noqa: F401
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


def subset(ts: TextureSet, keep: Sequence[int]) -> TextureSet:
    """``ts`` restricted to the channels ``keep`` (in that order)."""
    keep = list(keep)
    return TextureSet(np.ascontiguousarray(ts.data[..., keep]), tuple(ts.channels[i] for i in keep),
                      ts.width, ts.height)


def named_groups(groups: Sequence[Group | EncodedGroup], semantics: Sequence[str]) -> tuple[str, ...]:
    """The names of the groups that hold one of ``semantics`` (--classic): a packed group goes whole."""
    wanted = set(semantics)
    names = [getattr(g, "group", g).name for g in groups]
    return tuple(n for n in names if wanted & set(n.split("+")))


def predict_for(ts: TextureSet, options: TrainingOptions, cfg, asked: str, resolution: int,
                match_bc: bool = False) -> LayoutPrediction:
    """`bcfpipe.layout.predict.predict` for a loaded set: what `scan` and `plan` say of it."""
    groups = classic_groups(ts)
    return predict(groups, ts.width, ts.height, ts.num_channels, ts.num_channels, asked,
                   cfg.model.resolutions, resolution, cfg.device, (cfg.model.n_inputs, cfg.model.hidden),
                   options.layout, match_bc, named_groups(groups, options.classic))


@dataclass
class ClassicFit:
    """BC@R encoded and measured, and its repacks."""

    groups: list[EncodedGroup]
    e_bc: np.ndarray  # (mips, channels) errors
    bc: C.Candidate
    use: tuple[int, ...]  # the reference mips the all-mip figure averages
    repacked: dict
    packed: list[C.Candidate]
    seconds: float


def _measure_classic(ts: TextureSet, resolution: int, wrap: str, coverage: np.ndarray | None, with_repacks: bool,
                     log: Callable[[str], None] | list[str] | None) -> ClassicFit:
    """Encode BC@R (every group, every mip) and measure it per channel, then its BC7 repacks (up to
    R = 4096, when ``with_repacks``). ``log``: a function, or a list that collects the lines (for a
    thread beside the training)."""
    say = log.append if isinstance(log, list) else log or (lambda s: None)
    t = time.perf_counter()
    if not isinstance(log, list):
        say(f"BC@{resolution}: encoding every mip")
    ref = build_mip_chain(ts.data)
    use = tuple(k for k, m in enumerate(ref) if min(m.shape[:2]) >= 4) or tuple(range(len(ref)))
    groups = encode(ts, resolution, ref, wrap)
    masks = None
    if coverage is not None:  # every figure over the texels the scene reads
        from bcfpipe.scan.coverage import mask_mips

        masks = mask_mips(coverage, len(ref), wrap)
    e_bc = channel_errors(ts, groups, ref, masks)
    for g in groups:  # measured: from here on BC@R is its blocks and these errors. An 8192² set's
        g.decoded = []  # decoded mips and reference chain hold 2.7 GiB each, which training needs
    names = [g.group.name for g in groups]
    bc = C.Candidate(tuple(names), None, sum(g.size_bytes for g in groups),
                     C.combine(None, e_bc, range(ts.num_channels)), "measured", use)
    say(f"BC@{resolution}: {bc.size_bytes / 2**20:.2f} MiB, {bc.psnr:.2f} dB over all mips "
        f"({time.perf_counter() - t:.1f} s)")
    repacked, packed = {}, []
    if with_repacks and resolution <= MAX_REPACK_SIDE:
        repacked, packed = _repacks(ts, groups, e_bc, bc, ref, masks, resolution, wrap, say)
    return ClassicFit(groups, e_bc, bc, use, repacked, packed, time.perf_counter() - t)


def capped(cfg, cap):
    """``cfg`` with the schedule ``cap`` (--layout neural's at the profile asked) where its own takes
    more steps: on a CPU a 2048² T_0 trains draft's 900 steps where a smaller fixed T_0 trains 2,500
    (config.FIXED_T0_PRESETS), so a probe at 1k cost 1.5× the neural build's training. Each of the
    layout's at most two trainings then costs no more steps than the neural one (docs/layout.md)."""
    if cap is None or cfg.preset.total_steps <= cap.total_steps:
        return cfg
    return cfg.with_(preset=cap)


def _in_workers(n: int, fn, *args):
    """``fn(*args)`` with this thread's encodes on ``n`` cores."""
    with workers(n):
        return fn(*args)


def fit_layout(ts: TextureSet, out_dir: str | Path, options: TrainingOptions, resolution: int, *,
               wrap: str = "repeat", match_bc: bool = False, log: Callable[[str], None] = lambda s: None,
               progress: ProgressFn | None = None, coverage: np.ndarray | None = None) -> LayoutFit:
    """Choose and train ``ts``'s layout at BC resolution ``resolution``; neural files of the probe
    and of the chosen model go under ``out_dir``/probe and ``out_dir``/neural. The groups that
    ``options.classic`` names stay classic in every candidate; with ``--layout neural`` that one
    layout is trained, at the profile asked, without a probe."""
    from bcfpipe.train.rate import _gain as rate_gain

    def _gain(p: str, preset: str) -> float:  # smoke is no rate-control preset: draft's gains stand in
        return rate_gain(p, preset if preset in ("draft", "fast", "standard", "paper") else "draft")

    start = time.perf_counter()
    out = Path(out_dir)
    asked, cfg = make_config(ts, options, wrap)
    pred = predict_for(ts, options, cfg, asked, resolution, match_bc)
    forced = named_groups(classic_groups(ts), options.classic)
    overlap = (options.layout != Layout.NEURAL and max(ts.width, ts.height) <= MAX_REPACK_SIDE
               and encode_workers() > 1)
    def classic_fit(say):
        return _measure_classic(ts, resolution, wrap, coverage, options.layout != Layout.NEURAL, say)

    if options.layout == Layout.NEURAL:
        cf = classic_fit(log)
        return _fixed(ts, out, options, wrap, cf.groups, cf.e_bc, cf.bc, forced, asked, cf.use, log, progress, coverage,
                      start, cf.seconds)
    profiles = list(pred.profiles)
    own = {p: (p if p in PROFILES else options.profile) for p in profiles}  # auto-N trains as "auto"
    dims = (cfg.model.n_inputs, cfg.model.hidden)
    size_of = {p: neural_bytes(PROFILES[p] if p in PROFILES else cfg.model.resolutions, *dims, ts.num_channels)
               for p in profiles}
    p0 = pred.probe  # the largest profile within BC@R's bytes, known from block counts before encoding

    cap = cfg.preset  # no training here takes more steps than --layout neural's (at the profile asked)

    def train_probe() -> MaterialResult:
        log(f"probe: all {ts.num_channels} channels at {p0}")
        return fit_material(ts, out / "probe", capped(make_config(ts, replace(options, profile=own[p0]), wrap)[1], cap),
                            p0, progress=progress, coverage=coverage, image_metrics=False)[0]

    if overlap:  # BC@R and its repacks encode on the cores the probe's training leaves (its --threads)
        from concurrent.futures import ThreadPoolExecutor

        lines: list[str] = []
        with ThreadPoolExecutor(1) as pool:
            log(f"BC@{resolution}: encoding every mip and its repacks beside the probe")
            # every core the job has: no core idles while the other of the two still runs
            fut = pool.submit(lambda: _in_workers(encode_workers(), classic_fit, lines))
            probe = train_probe()
            cf = fut.result()
        for line in lines:
            log(line)
    else:
        cf = classic_fit(log)
        probe = train_probe()
    groups, e_bc, bc, use, repacked, packed = cf.groups, cf.e_bc, cf.bc, cf.use, cf.repacked, cf.packed
    names = [g.group.name for g in groups]
    packed = [c for c in packed if set(forced) <= {g for g in c.classic}]
    train_s = probe.train_seconds
    e0 = probe.mse_per_channel
    size_of[p0] = probe.size_bytes

    cands = []
    for r in range(len(groups)):
        for chosen in itertools.combinations(range(len(groups)), r):
            if not set(forced) <= {names[i] for i in chosen}:
                continue
            cols = [c for i in chosen for c in groups[i].group.channels]
            classic_bytes = sum(groups[i].size_bytes for i in chosen)
            for p in profiles:
                e = e0 if p == p0 else e0 * 10 ** (-(_gain(p, options.preset) - _gain(p0, options.preset)) / 10)
                basis = "measured" if (p == p0 and not chosen) else "bound" if p == p0 else "predicted"
                cands.append(C.Candidate(tuple(names[i] for i in chosen), p, size_of[p] + classic_bytes,
                                         C.combine(e, e_bc, cols), basis, use))
    probed = [c for c in cands if c.profile == p0 and not c.classic]  # the probe itself (none when --classic)
    final_pool = [bc] + packed + probed
    models = {c.label: (probe, tuple(range(ts.num_channels))) for c in probed}
    splits: list[C.Candidate] = []
    if not forced:  # --classic keeps its groups classic at every mip: no split
        halving = max(0.0, _gain("1k", options.preset) - _gain("0.5k", options.preset))  # one halving of T_0
        splits = split_candidates(ts, groups, e_bc, e0, bc, use, resolution, dims, match_bc,
                                  probe_t0=probe.resolutions[0], halving_db=halving)
    first = C.choose(packed + cands + splits, bc, match_bc)
    log(f"first choice: {first.chosen.label} ({first.chosen.basis})")

    ch = first.chosen  # one more training at most: the first choice if it needs its own model
    held = C.choose(final_pool, bc, match_bc).chosen
    if ch.split and not (ch.size_bytes < held.size_bytes if match_bc else ch.psnr > held.psnr):
        ch = held
    if ch.profile is None or (not ch.classic and ch.profile == p0):  # nothing new is certain: explore
        alt = C.most_promising(cands, bc, match_bc)
        if alt is not None:
            log(f"no candidate clears the floor on its bound; training the closest: {alt.label} "
                f"({C.deficit(alt, bc, match_bc):.1f} dB short)")
            ch = alt
    if ch.split:
        log(f"training the features of a mip split for: {ch.label} (predicted {ch.psnr:.2f} dB over all mips)")
        res, m = _train_split(ts, out, options, wrap, groups, e_bc, ch, resolution, progress, coverage, cap)
        keep = tuple(range(ts.num_channels))
    elif ch.profile is not None and (ch.classic or ch.profile != p0):
        log(f"training the channels outside the classic groups at {ch.profile} for: {ch.label}")
        res, keep, m = _train_subset(ts, out, options, wrap, groups, e_bc, ch.classic, own[ch.profile], ch.profile,
                                     use, progress, coverage, cap)
    else:
        res = None
    if res is not None:
        train_s += res.train_seconds
        final_pool.append(m)
        models[m.label] = (res, keep)
    decision = C.choose(final_pool, bc, match_bc)
    neural, channels = models.get(decision.chosen.label, (None, ()))
    return LayoutFit(decision, first, groups, neural, channels, probe, train_s, time.perf_counter() - start, repacked,
                     cf.seconds)


def _repacks(ts, groups, e_bc, bc, ref, masks, resolution, wrap, log):
    """Every BC7 repack of BC@R (`classic.repacks`), encoded and measured exactly:
    ({label: (repack, encoded groups)}, candidates)."""
    found, cands = {}, []
    for rp in repacks([g.group for g in groups]):
        t = time.perf_counter()
        enc, e, size = measure_repack(ts, groups, e_bc, rp, resolution, ref, masks, wrap)
        for g in enc:
            g.decoded = []
        kept = tuple(g.group.name for g in groups if g.group.name not in rp.replaces)
        c = C.Candidate(kept + tuple(g.name for g in rp.groups), None, size,
                        C.combine(None, e, range(ts.num_channels)), "measured", bc.use, repack=rp.label)
        log(f"BC@{resolution} with {rp.label}: {size / 2**20:.2f} MiB, {c.psnr:.2f} dB over all mips "
            f"({time.perf_counter() - t:.1f} s)")
        found[rp.label] = (rp, enc)
        cands.append(c)
    return found, cands


def split_bytes(groups: Sequence[EncodedGroup], keep: int) -> int:
    """Bytes of BC@R's groups cut to their first ``keep`` levels (headers included)."""
    from bcfpipe.formats.dds import HEADER_BYTES

    return sum(HEADER_BYTES + sum(b.nbytes for b, _, _ in g.levels[:keep]) for g in groups)


def split_candidates(ts: TextureSet, groups: Sequence[EncodedGroup], e_bc: np.ndarray, e_probe: np.ndarray,
                     bc: C.Candidate, use: tuple[int, ...], resolution: int, dims: tuple[int, int],
                     match_bc: bool = False, probe_t0: int = 0, halving_db: float = 0.0) -> list[C.Candidate]:
    """The mip splits worth training, ``predicted``: for each reference mip k >= 1, BC@R's levels
    that serve the mips below k and features T = (t, t, t, t/2) for s >= k, t the largest power of
    two no larger than mip k's side whose bytes (with the DDS headers) keep the whole within BC@R's
    size, t >= 8. Errors: BC@R's below k; from k on the probe's (T_0 = ``probe_t0``), worse by
    ``halving_db`` for every halving from probe_t0 to t (the measured gain between profiles, as
    rate control predicts). Only those that hold the floor on that prediction, and only where BC@R
    has more than one level to cut."""
    side = max(ts.width, ts.height)
    out = []
    n_mips = e_bc.shape[0]
    for k in range(1, n_mips):
        keep = split_levels(k, resolution, side)
        if keep >= min(len(g.levels) for g in groups):
            break
        budget = bc.size_bytes - split_bytes(groups, keep)
        t = 1 << (max(1, side >> k).bit_length() - 1)
        res = None
        while t >= 8:
            r = (t, t, t, t // 2)
            size = neural_bytes(r, *dims, ts.num_channels)  # its DDS files and weight record
            if size <= budget:
                res = r
                break
            t //= 2
        if res is None:
            continue
        halvings = max(0.0, math.log2(probe_t0 / res[0])) if probe_t0 else 0.0
        err = e_probe * 10.0 ** (halvings * halving_db / 10.0)
        err[:k] = e_bc[:k]
        c = C.Candidate(bc.classic, "/".join(map(str, res)), bc.size_bytes - budget + size,
                        tuple(float(v) for v in err.mean(1)), "predicted", use, split=k, resolutions=res)
        if C.deficit(c, bc, match_bc) <= 0:
            out.append(c)
    return out


def _train_split(ts, out, options, wrap, groups, e_bc, cand: C.Candidate, resolution, progress, coverage, cap=None):
    """Train ``cand``'s features (all channels, s >= its split) and measure the split layout:
    (result, measured candidate). Below the split the layout decodes to BC@R exactly, from it on
    to the model (tests/test_split_layout.py)."""
    cfg = capped(make_config(ts, options, wrap)[1], cap)
    cfg = cfg.with_(model=replace(cfg.model, resolutions=cand.resolutions, split=cand.split))
    res, _ = fit_material(ts, out / "split", cfg, cand.profile, progress=progress, coverage=coverage,
                          image_metrics=False)
    err = res.mse_per_channel.copy()
    err[:cand.split] = e_bc[:cand.split]
    keep = split_levels(cand.split, resolution, max(ts.width, ts.height))
    return res, replace(cand, size_bytes=res.size_bytes + split_bytes(groups, keep),
                        mse_per_mip=tuple(float(v) for v in err.mean(1)), basis="measured")


def _train_subset(ts, out, options, wrap, groups, e_bc, classic, profile, name, use, progress, coverage, cap=None):
    """Train the channels outside the ``classic`` groups at ``profile`` (reported as ``name``):
    (result, channels, measured candidate)."""
    keep = [c for c in range(ts.num_channels) if not any(c in g.group.channels for g in groups if g.group.name in classic)]
    sub = subset(ts, keep)
    res, _ = fit_material(sub, out / "neural", capped(make_config(sub, replace(options, profile=profile), wrap)[1], cap),
                          name, progress=progress, coverage=coverage, image_metrics=False)
    e = e_bc.copy()
    e[:, keep] = res.mse_per_channel
    classic_bytes = sum(g.size_bytes for g in groups if g.group.name in classic)
    return res, tuple(keep), C.Candidate(tuple(classic), name, res.size_bytes + classic_bytes,
                                         tuple(float(v) for v in e.mean(1)), "measured", use)


def _fixed(ts, out, options, wrap, groups, e_bc, bc, forced, asked, use, log, progress, coverage, start,
           encode_s: float) -> LayoutFit:
    """``--classic`` with ``--layout neural``: the named groups classic, the rest at the profile asked."""
    if len(forced) == len(groups):
        decision = C.Decision(bc, (bc,), bc, f"--classic {','.join(options.classic)} names every group: shipping BC@R",
                              "quality")
        return LayoutFit(decision, decision, groups, None, (), None, 0.0, time.perf_counter() - start,
                         encode_seconds=encode_s)
    log(f"training the channels outside {', '.join(forced)} at {asked}")
    res, keep, m = _train_subset(ts, out, options, wrap, groups, e_bc, forced, options.profile, asked, use, progress,
                                 coverage)
    worst = min(m.margins(bc)[k] for k in bc.use)
    kept = f"{', '.join(forced)} kept as BC textures" if forced else "no channel group of this set named"
    decision = C.Decision(bc, (bc, m), m, f"--classic {','.join(options.classic)}: {kept}, the rest neural at {asked} "
                          f"(worst mip {worst:+.1f} dB against BC@R)", "quality")
    return LayoutFit(decision, decision, groups, res, keep, None, res.train_seconds, time.perf_counter() - start,
                     encode_seconds=encode_s)
