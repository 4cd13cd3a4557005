"""BC@R, its BC7 repacks and the BC7 quality set as a layout fit weighs them (issue 58): estimated
from a sample of their blocks first (`bcfpipe.layout.estimate`), then encoded in full, once, only
where a decision needs it: the candidate that ships, and BC@R when a neural part is weighed
against its floor.

Sizes are exact from the start (BC blocks have fixed sizes); errors are ``estimated`` until every
group a candidate holds is encoded in full, then ``measured``. A group encoded in full keeps its
blocks for the export and replaces its estimate in every candidate that holds it.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np

from bcfpipe.config import DEFAULT_ENCODE, EncodePreset
from bcfpipe.formats.display import bytes_text
from bcfpipe.layout import choose as C
from bcfpipe.layout.classic import (MAX_REPACK_SIDE, DiskBytes, EncodedGroup, Group, Repack, bc7_quality_set,
                                    channel_errors, disk_bytes_aside, encode_group, planned, repacks)
from bcfpipe.layout.classic import groups as classic_groups
from bcfpipe.layout.estimate import FULL_BLOCKS, estimate_errors
from bcfpipe.texset.chain import Reference
from bcfpipe.texset.texture_set import TextureSet
from bcfpipe.train.progress import Progress

QUALITY_LABEL = "BC7 quality set"
# Blocks per level the quality set's estimate encodes (`estimate.draw`'s budget): no decision reads it.
# On the four 2048² sets at draft within 0.21 dB of a full encode per mip, in 0.5-1.4 s on two cores;
# 16384 blocks (the candidates' budget): within 0.07 dB, in 1.2-2.9 s (docs/benchmarks.md)
QUALITY_BLOCKS = 4096


@dataclass(frozen=True)
class ClassicKinds:
    """The kinds of a classic fit's candidates (`bcfpipe.layout.kinds.CLASSIC`), given by the caller:
    this module sits below the kinds, which read what it fits."""

    bc: C.CandidateKind  # BC@R
    repack: C.CandidateKind  # BC@R with groups repacked as BC7
    quality: C.CandidateKind  # the BC7 quality set


@dataclass(frozen=True)
class ClassicFit:
    """BC@R and its repacks, each group estimated or encoded in full, with its candidates."""

    groups: list[EncodedGroup]  # BC@R's, in pack order (encoded or planned)
    e_bc: np.ndarray  # (mips, channels) errors of BC@R's groups, exact for the encoded ones
    bc: C.Candidate
    use: tuple[int, ...]  # the reference mips the all-mip figure averages
    repacked: dict[str, tuple[Repack, list[EncodedGroup]]] = field(default_factory=dict)  # by Repack.label
    packed: tuple[C.Candidate, ...] = ()  # the repacks' candidates
    seconds: float = 0.0  # encoding and measuring, estimates included
    quality: C.Candidate | None = None  # the BC7 quality set (reported against, not weighed)
    rp_errors: dict[str, np.ndarray] = field(default_factory=dict)  # a repack's own groups' errors, by label
    estimate_seconds: float = 0.0
    sampled: float = 1.0  # the share of BC@R's texels its estimate encoded
    kinds: ClassicKinds | None = None  # its candidates' (`ClassicWork.kinds`)

    @property
    def measured(self) -> bool:
        """Whether BC@R is encoded in full (its figures exact)."""
        return all(g.encoded for g in self.groups)


@dataclass
class ClassicWork:
    """Where classic encodes happen: the set, R, its reference and how to report."""

    ts: TextureSet
    resolution: int
    reference: Reference
    wrap: object
    kinds: ClassicKinds  # what its candidates are (`bcfpipe.layout.kinds.CLASSIC`)
    log: Callable[[str], None] = lambda s: None
    seconds: float = 0.0
    progress: Callable | None = None  # hears each full encode as phase ``bc-encode``, with an ETA
    enc: EncodePreset = DEFAULT_ENCODE  # the quality preset's (`config.ENCODE_PRESETS`)

    def report(self, done: int, total: int, start: float) -> None:
        """``done`` of ``total`` texels encoded since ``start``: the ETA at the rate so far."""
        if self.progress is None:
            return
        el = time.perf_counter() - start
        eta = el / done * (total - done) if done else float("nan")
        self.progress(Progress("bc-encode", done * 100 // max(1, total), 100, float("nan"), float("nan"), el, eta))


def _candidate(names: Sequence[str], size: int, e: np.ndarray, measured: bool, use, kind, repack: str = "",
               disk: DiskBytes | None = None) -> C.Candidate:
    return C.Candidate(tuple(names), None, size, C.combine(None, e, range(e.shape[1])),
                       "measured" if measured else "estimated", use, kind.Part(repack) if repack else None,
                       disk_bytes=disk, kind=kind)


def _cols(groups: Sequence[Group]) -> list[int]:
    return [c for g in groups for c in g.channels]


def repackable(work: ClassicWork) -> bool:
    """Whether any BC7 repack can take BC@R's place at R (else BC@R ships or is the floor)."""
    return work.resolution <= MAX_REPACK_SIDE and bool(repacks(classic_groups(work.ts)))


def estimated(work: ClassicWork, with_repacks: bool = True, whole_bc: bool | None = None,
              quality: bool = True, budget: int = FULL_BLOCKS) -> ClassicFit:
    """BC@R, its repacks and the quality set, every error estimated from a sample of blocks. With
    ``whole_bc`` (None: when no repack can take BC@R's place), BC@R is encoded in full instead
    (`measure`): it then ships or is the floor a neural part is held to, so its estimate would
    be thrown away. Without ``quality`` the quality set waits for `quality_errors` and
    `with_quality` (no decision reads it: it can be estimated where a core is idle). ``budget``:
    blocks per level of BC@R's sample (`estimate.draw`; the probe's gate draws fewer)."""
    t = time.perf_counter()
    ts, r, ref = work.ts, work.resolution, work.reference
    groups = [planned(ts, g, r) for g in classic_groups(ts)]
    found = list(repacks([g.group for g in groups])) if with_repacks and r <= MAX_REPACK_SIDE else []
    whole = not found if whole_bc is None else whole_bc
    if whole:
        e_bc, frac = np.zeros((len(ref.mips), ts.num_channels)), 1.0
    else:
        e_bc, frac = estimate_errors(ts, [g.group for g in groups], r, ref.mips, ref.masks, work.wrap,
                                     budget=budget, enc=work.enc)
    use = tuple(k for k, m in enumerate(ref.mips) if min(m.shape[:2]) >= 4) or tuple(range(len(ref.mips)))
    cf = ClassicFit(groups, e_bc, None, use, sampled=frac, kinds=work.kinds)
    rp_errors, repacked = {}, {}
    for rp in found:
        e, _ = estimate_errors(ts, rp.groups, r, ref.mips, ref.masks, work.wrap, enc=work.enc)
        rp_errors[rp.label] = e
        repacked[rp.label] = (rp, [planned(ts, g, r) for g in rp.groups])
    cf = replace(cf, repacked=repacked, rp_errors=rp_errors)
    if with_repacks and quality:
        cf = with_quality(work, cf, quality_errors(work, cf))
    cf = replace(cf, estimate_seconds=time.perf_counter() - t)
    if whole:
        return measure(work, cf)
    cf = refresh(cf)
    work.log(f"BC@{r}: {bytes_text(cf.bc.size_bytes)}, {cf.bc.psnr:.2f} dB over all mips, estimated from "
             f"{frac:.0%} of its texels ({time.perf_counter() - t:.1f} s with {len(found)} repack(s))")
    return cf


def _quality_set(groups: Sequence[EncodedGroup], r: int) -> Repack | None:
    return bc7_quality_set([g.group for g in groups]) if r <= MAX_REPACK_SIDE else None


def quality_errors(work: ClassicWork, cf: ClassicFit) -> tuple[Repack, np.ndarray] | None:
    """The BC7 quality set of ``cf``'s groups and its own groups' errors, estimated as `estimated`
    estimates them (None: no quality set at R)."""
    q = _quality_set(cf.groups, work.resolution)
    if q is None:
        return None
    ref = work.reference
    return q, estimate_errors(work.ts, q.groups, work.resolution, ref.mips, ref.masks, work.wrap,
                              budget=QUALITY_BLOCKS, enc=work.enc)[0]


def with_quality(work: ClassicWork, cf: ClassicFit, found: tuple[Repack, np.ndarray] | None) -> ClassicFit:
    """``cf`` (`estimated` without its quality set) with the quality set `quality_errors` found."""
    if found is None or found[0].label in cf.repacked:
        return cf
    q, e = found
    return refresh(replace(cf, repacked={**cf.repacked, q.label: (q, [planned(work.ts, g, work.resolution)
                                                                      for g in q.groups])},
                           rp_errors={**cf.rp_errors, q.label: e}))


def refresh(cf: ClassicFit) -> ClassicFit:
    """``cf``'s candidates made again from its groups and errors (after a group was encoded)."""
    K = cf.kinds
    names = [g.group.name for g in cf.groups]
    bc = _candidate(names, sum(g.size_bytes for g in cf.groups), cf.e_bc, cf.measured, cf.use, K.bc,
                    disk=DiskBytes(tuple(cf.groups)) if cf.measured else None)
    packed, quality = [], None
    for label, (rp, enc) in cf.repacked.items():
        kept = [g for g in cf.groups if g.group.name not in rp.replaces]
        e = cf.e_bc.copy()
        cols = _cols(rp.groups)
        e[:, cols] = cf.rp_errors[label][:, cols]
        done = all(g.encoded for g in kept + enc)
        size = sum(g.size_bytes for g in kept) + sum(g.size_bytes for g in enc)
        disk = DiskBytes(tuple(kept + enc)) if done else None
        if label == QUALITY_LABEL:
            quality = _candidate(names, size, e, done, cf.use, K.quality, label, disk)
            continue
        kept_names = tuple(g.group.name for g in kept)
        packed.append(_candidate(kept_names + tuple(g.name for g in rp.groups), size, e, done, cf.use,
                                 K.repack, label, disk))
    if quality is None:
        quality = replace(bc, kind=K.quality)
    return replace(cf, bc=bc, packed=tuple(packed), quality=quality)


def measure(work: ClassicWork, cf: ClassicFit, c: C.Candidate | None = None,
            only: Sequence[str] | None = None) -> ClassicFit:
    """``cf`` with every group of ``c`` (a classic candidate: BC@R or a repack; None: BC@R) encoded
    in full and measured exactly, once: what it ships, or the floor a neural part is held to.
    ``only``: just those of BC@R's groups (a mixed layout's classic part)."""
    t = time.perf_counter()
    ts, r, ref = work.ts, work.resolution, work.reference
    rp = cf.repacked[c.part.repack][0] if c is not None and c.part else None
    e_bc = cf.e_bc.copy()
    groups = list(cf.groups)
    todo = [i for i, g in enumerate(groups) if not g.encoded and not (rp is not None and g.group.name in rp.replaces)
            and (only is None or g.group.name in only)]
    work_of = [_texels(groups[i]) for i in todo] + ([_texels(planned(ts, g, r)) for g in rp.groups] if rp else [])
    total, done_texels = sum(work_of), 0
    done = []
    for n, i in enumerate(todo):
        g = groups[i]
        work.report(done_texels, total, t)
        groups[i] = encode_group(ts, g.group, r, ref.mips, work.wrap, work.enc)
        disk_bytes_aside(groups[i])
        done_texels += work_of[n]
        cols = list(g.group.channels)
        e_bc[:, cols] = channel_errors(ts, [groups[i]], ref.mips, ref.masks)[:, cols]
        _empty(groups[i])
        done.append(g.group.name)
    repacked, rp_errors = dict(cf.repacked), dict(cf.rp_errors)
    if rp is not None:
        enc = []
        for n, g in enumerate(rp.groups):
            work.report(done_texels, total, t)
            enc.append(encode_group(ts, g, r, ref.mips, work.wrap, work.enc))
            disk_bytes_aside(enc[-1])
            done_texels += work_of[len(todo) + n]
        e = channel_errors(ts, enc, ref.mips, ref.masks)
        for g in enc:
            _empty(g)
        repacked[rp.label], rp_errors[rp.label] = (rp, enc), e
        done.append(rp.label)
    work.report(total, total, t)
    out = refresh(replace(cf, groups=groups, e_bc=e_bc, repacked=repacked, rp_errors=rp_errors))
    s = time.perf_counter() - t
    work.seconds += s
    if done:
        what = out.bc if c is None or not c.part else next(p for p in (*out.packed, out.quality) if p.part == c.part)
        work.log(f"encoded in full: {', '.join(done)} ({s:.1f} s); {what.label}: {what.psnr:.2f} dB over all mips")
    return replace(out, seconds=cf.seconds + s)


def _texels(g: EncodedGroup) -> int:
    """Texels times stored channels of a group's levels: what its encode costs, roughly."""
    return sum(w * h for w, h in g.planned) * len(g.group.channels)


def _empty(g: EncodedGroup) -> None:
    """Measured: from here on a group is its blocks (an 8192² set's decoded mips hold 2.7 GiB), except
    a slope normal's level 0, which the angular error reads."""
    g.decoded = []
