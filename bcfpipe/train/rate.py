"""Rate control (`--target-psnr`): the cheapest profile and preset predicted to reach a PSNR.

Policy:

1. Candidates are the paper profiles whose T_0 fits the source (0.5k and 1k on a CPU, 2k too on
   CUDA; a source under 512 gets its own `auto` profile) times the presets that suit the device
   (draft, fast, standard; paper too on CUDA), ordered by size, then training cost: smallest first.
2. Predictions come from measured anchors plus `GAINS_DB`, the mean PSNR of each (profile, preset)
   relative to (0.5k, draft) on the committed benches (docs/bench). The anchors are the cells of a
   `bcfpipe bench` report of the same set when one is given (no training), else one probe: the
   cheapest candidate, trained for real (it is kept if it already meets the target).
3. The chosen setting is the first candidate predicted to reach target + `MARGIN_DB`. It is
   trained and measured from its exported files. If it misses, its result becomes an anchor
   (the predictions shift by the miss) and the next candidate predicted to reach the target is
   tried: "climbing", reported as such.
4. When no untried candidate is predicted to reach the target, the target is unreachable: the
   candidate with the highest prediction is trained if it is predicted to beat the best result so
   far by `MARGIN_DB` (the best the tool can do), and the best result is kept and reported.

Cost: a probe (0.5k draft: about 20 s of training on one core of a 2-core CPU for a 2048² set)
plus the chosen training, plus one training per climb.
"""
from __future__ import annotations

import shutil
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable, Mapping, Sequence

from bcfpipe.config import PROFILES, QUALITY_PRESETS, preset_for, resolve_profile
from bcfpipe.formats.sizes import feature_bytes

__all__ = ["profile_gain", "Setting", "Attempt", "TargetOutcome", "candidates", "predict", "fit_to_target", "anchors_from_bench",
           "GAINS_DB", "MARGIN_DB", "T0_LAYER_GAINS_DB", "t0_layer_gains", "PROBE_GAINS_DB", "PROBE_GAINS_MAX_DB", "probe_gains"]

MARGIN_DB = 0.5
# On a CPU, 2k does not pay for its 4x bytes and 2.4x time: on the teapot, 2k standard gave 38.54 dB
# at 7.08 MiB in 606 s, 1k standard 37.55 dB at 1.77 MiB in 256 s (docs/benchmarks.md).
CPU_PROFILES = ("0.5k", "1k")
GPU_PROFILES = ("0.5k", "1k", "2k")
# Mean PSNR over all mips relative to (0.5k, draft) on the teapot and the brick with the default
# features (bc7, a fixed T_0 of principal components; issue 52 measured them again: the table before
# held BC6H figures), `benchmarks/bench_presets.py --set S --profile P --features bc7`, each preset's
# schedule as config.PRESETS holds it (docs/benchmarks.md, "Issue 52: the gain table for bc7"):
#   teapot 34.68 / 35.65 / 35.88 (0.5k draft / fast / standard), 35.73 / 38.66 / 39.25 (1k)
#   brick  29.80 / 29.82 / 29.83, 31.48 / 31.55 / 31.59
# 2k is a candidate on CUDA only; its rows add the BC6H teapot's 2k standard over its 1k standard
# (+0.99 dB: 38.54 against 37.55, docs/benchmarks.md) to each 1k row: estimates until a GPU
# measures them.
GAINS_DB: dict[tuple[str, str], float] = {
    ("0.5k", "draft"): 0.0, ("0.5k", "fast"): 0.50, ("0.5k", "standard"): 0.62,
    ("1k", "draft"): 1.37, ("1k", "fast"): 2.87, ("1k", "standard"): 3.18,
    ("2k", "draft"): 2.36, ("2k", "fast"): 3.86, ("2k", "standard"): 4.17,
}
# What more layers of principal components in a fixed T_0 (--t0-layers, issue 52) add over one, in
# dB per reference mip, by the mip's place against T_0's level 0: the first entry for every mip
# finer than it (T_0 magnified), then level 0, 1, and the mean of every coarser one. Measured from
# exported files at 1k standard (the default preset), --layout neural, one thread,
# `benchmarks/bench_t0_widths.py --widths-only` (docs/benchmarks.md, "Issue 52: what auto ships"):
# two layers over one is the mean of the teapot (6 channels: +0.04 / +0.71 / +0.36, coarser +0.09
# … +1.5) and the water bottle (11: +0.29 / +2.92 / +1.81, coarser +0.35 … +3.1); three layers add
# the bottle's third over its second (+0.11 / -0.15 / -0.11, coarser -0.1 … -0.6) to that. A set of
# four channels or fewer has one layer only.
T0_LAYER_GAINS_DB: dict[int, tuple[float, ...]] = {
    1: (0.0, 0.0, 0.0, 0.0),
    2: (0.16, 1.81, 1.09, 0.62),
    3: (0.27, 1.66, 0.98, 0.24),
}
# What a full training at a preset gains over the default layout's probe (the same model trained for
# `layout.fit.PROBE_FRACTION` of its steps, issue 58), in dB per reference mip by its place against
# T_0's level 0, as T0_LAYER_GAINS_DB reads: finer than it, level 0, level 1, every coarser mip.
# Means over sets, from exported files, `benchmarks/bench_probe_gain.py --quality Q`
# (docs/benchmarks.md, "Issue 58: what a full training gains over the probe"):
#   draft: teapot, brick, wood, water bottle at 1k (per set, mip 0: 0.76 / 0.08 / 0.09 / 0.68;
#   mip 1: 1.44 / -0.24 / -0.09 / 2.06); standard: the teapot and the water bottle (mip 0: 0.55 /
#   0.50; mip 1: 0.19 / 2.09); fast: the teapot and the water bottle (mip 0: 1.35 / 0.60; mip 1:
#   2.33 / 2.41). paper (a GPU's) takes standard's until measured; smoke, a pipeline check, draft's.
PROBE_GAINS_DB: dict[str, tuple[float, float, float, float]] = {
    "draft": (0.41, 0.79, 0.82, 1.6),
    "fast": (0.97, 2.37, 2.52, 2.82),
    "standard": (0.53, 1.14, 1.48, 2.05),
}
# The most any of those sets gained, by the same places: a set's own gain at T_0's first levels
# ranges over 2 dB about the mean (the water bottle 2.1 dB at standard's mip 1, the teapot 0.2).
# A candidate that clears the floor only on these is the one the default layout trains when its
# mean prediction ships classic (`layout.fit`): on the bottle at 1k standard that training ships.
PROBE_GAINS_MAX_DB: dict[str, tuple[float, float, float, float]] = {
    "draft": (0.76, 2.06, 2.27, 2.34),
    "fast": (1.35, 2.41, 2.84, 3.86),
    "standard": (0.55, 2.09, 2.57, 2.12),
}
PAPER_OVER_STANDARD_DB = 1.0  # a GPU's 206k steps over `standard`'s 19.5k: a guess until measured on a GPU


def profile_gain(profile: str, preset: str) -> float:
    base = profile if (profile, "draft") in GAINS_DB else "0.5k"
    if preset == "paper":
        return GAINS_DB[(base, "standard")] + PAPER_OVER_STANDARD_DB
    return GAINS_DB[(base, preset)]


def probe_gains(preset: str, n_mips: int, t0_mip: int, most: bool = False) -> "list[float]":
    """`PROBE_GAINS_DB` of ``preset`` (``most``: `PROBE_GAINS_MAX_DB`) at each of ``n_mips``
    reference mips, T_0's level 0 serving reference mip ``t0_mip``."""
    table = PROBE_GAINS_MAX_DB if most else PROBE_GAINS_DB
    row = table.get(preset) or table["draft" if preset == "smoke" else "standard"]
    return [row[0] if k < t0_mip else row[min(1 + k - t0_mip, len(row) - 1)] for k in range(n_mips)]


def t0_layer_gains(t0_layers: int, n_mips: int, t0_mip: int) -> "list[float]":
    """`T0_LAYER_GAINS_DB` of ``t0_layers`` at each of ``n_mips`` reference mips, T_0's level 0
    serving reference mip ``t0_mip``."""
    row = T0_LAYER_GAINS_DB[t0_layers]
    return [row[0] if k < t0_mip else row[min(1 + k - t0_mip, len(row) - 1)] for k in range(n_mips)]


@dataclass(frozen=True)
class Setting:
    profile: str
    preset: str
    resolutions: tuple[int, ...]
    feature_bytes: int  # the four layers' blocks with their mips down to 4x4 (formats.sizes.feature_bytes)
    cost: float  # training samples x steps, the order of training time

    def to_json(self) -> dict:
        return asdict(self)


def candidates(source_side: int, device: str = "cpu", fixed_t0: bool = False) -> list[Setting]:
    """Every setting rate control may choose for a set whose larger side is ``source_side``
    (``fixed_t0``: a T_0 of principal components, whose draft trains longer: config.preset_for)."""
    cuda = device.startswith("cuda")
    profiles = [p for p in (GPU_PROFILES if cuda else CPU_PROFILES) if PROFILES[p][0] <= source_side] or ["auto"]
    presets = [p for p in QUALITY_PRESETS if cuda or p != "paper"]
    out = []
    for prof in profiles:
        res = resolve_profile(prof, source_side)[1]
        for pre in presets:
            p = preset_for(pre, res[0], device, fixed_t0)
            out.append(Setting(prof, pre, tuple(res), feature_bytes(res), float(p.total_steps * p.batch)))
    return sorted(out, key=lambda s: (s.feature_bytes, s.cost))


def predict(settings: Sequence[Setting], anchors: Mapping[tuple[str, str], float]) -> dict[tuple[str, str], float]:
    """Predicted PSNR of each setting: measured where anchored, else the mean over anchors of
    anchor + gain(setting) - gain(anchor)."""
    out = {}
    for s in settings:
        key = (s.profile, s.preset)
        if key in anchors:
            out[key] = anchors[key]
        elif anchors:
            out[key] = sum(v + profile_gain(*key) - profile_gain(*a) for a, v in anchors.items()) / len(anchors)
    return out


def anchors_from_bench(report: Mapping, source_names: Sequence[str]) -> dict[tuple[str, str], float]:
    """The measured cells of a `bcfpipe bench` report for the set whose sources (file names, as
    the report writes them) equal ``source_names``; {} when the report has no such set."""
    for s in report.get("sets", []):
        if sorted(s.get("sources", [])) == sorted(source_names):
            return {(c["profile"], c["preset"]): float(c["psnr"]) for c in s.get("cells", [])
                    if c.get("psnr") is not None}
    return {}


@dataclass(frozen=True)
class Attempt:
    setting: Setting
    why: str  # "probe", "predicted", "climb" or "best effort"
    predicted: float | None
    psnr: float
    size_bytes: int
    train_seconds: float

    def to_json(self) -> dict:
        return {"profile": self.setting.profile, "preset": self.setting.preset, "why": self.why,
                "predicted_psnr": self.predicted, "psnr": self.psnr, "size_bytes": self.size_bytes,
                "train_seconds": self.train_seconds}


@dataclass(frozen=True)
class TargetOutcome:
    target: float
    met: bool
    chosen: Attempt
    attempts: tuple[Attempt, ...]
    anchors: str  # "probe" or "bench"
    predicted_max: float | None = None
    seconds: float = 0.0
    notes: tuple[str, ...] = field(default_factory=tuple)

    def to_json(self) -> dict:
        return {"target_psnr": self.target, "met": self.met, "psnr": self.chosen.psnr,
                "profile": self.chosen.setting.profile, "preset": self.chosen.setting.preset,
                "anchors": self.anchors, "predicted_max": self.predicted_max, "seconds": self.seconds,
                "attempts": [a.to_json() for a in self.attempts], "notes": list(self.notes)}

    def summary(self) -> str:
        c = self.chosen
        tried = ", ".join(f"{a.setting.profile}/{a.setting.preset} {a.psnr:.2f} dB ({a.why})" for a in self.attempts)
        head = (f"target {self.target:.2f} dB met: {c.setting.profile}/{c.setting.preset} at {c.psnr:.2f} dB"
                if self.met else
                f"target {self.target:.2f} dB unreachable: best {c.setting.profile}/{c.setting.preset} at "
                f"{c.psnr:.2f} dB")
        return f"{head}; tried {tried}"


TrainFn = Callable[[Setting, Path], "object"]  # trains into the folder, returns a MaterialResult


def fit_to_target(target: float, settings: Sequence[Setting], train_one: TrainFn, out_dir: str | Path,
                  anchors: Mapping[tuple[str, str], float] | None = None,
                  on_attempt: Callable[[str], None] | None = None):
    """Train the cheapest setting predicted to reach ``target`` dB into ``out_dir`` (module
    docstring). Attempts train in ``out_dir``/.attempts; the kept one's files are moved into
    ``out_dir``. Returns (the kept MaterialResult, TargetOutcome)."""
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    work = out_dir / ".attempts"
    work.mkdir(parents=True, exist_ok=True)
    known = dict(anchors or {})
    source = "bench" if known else "probe"
    attempts: list[Attempt] = []
    results: dict[tuple[str, str], object] = {}
    notes: list[str] = []

    def run(s: Setting, why: str, predicted: float | None):
        if on_attempt:
            pred = f"; {predicted:.2f} dB predicted" if predicted is not None else ""
            on_attempt(f"{s.profile}/{s.preset} ({why}{pred})")
        res = train_one(s, work / f"{s.profile}-{s.preset}")
        a = Attempt(s, why, predicted, float(res.metrics.psnr), int(res.size_bytes), float(res.train_seconds))
        attempts.append(a)
        results[(s.profile, s.preset)] = res
        known[(s.profile, s.preset)] = a.psnr
        return a

    if not known:
        run(settings[0], "probe", None)
    met = any(a.psnr >= target for a in attempts)
    predicted_max = None
    while not met:
        preds = predict(settings, known)
        predicted_max = max(preds.values())
        untried = [s for s in settings if (s.profile, s.preset) not in results]
        nxt = next((s for s in untried if preds[(s.profile, s.preset)] >= target + MARGIN_DB), None)
        if nxt is None:
            nxt = next((s for s in untried if preds[(s.profile, s.preset)] >= target), None)
        if nxt is not None:
            climbing = any(a.why != "probe" for a in attempts)
            run(nxt, "climb" if climbing else "predicted", preds[(nxt.profile, nxt.preset)])
            met = attempts[-1].psnr >= target
            continue
        best = max((a.psnr for a in attempts), default=float("-inf"))
        top = max(untried, key=lambda s: preds[(s.profile, s.preset)], default=None)
        if top is not None and preds[(top.profile, top.preset)] >= best + MARGIN_DB:
            notes.append(f"no setting is predicted to reach {target:.2f} dB (highest prediction "
                         f"{predicted_max:.2f} dB): trained the best-predicted one")
            run(top, "best effort", preds[(top.profile, top.preset)])
            met = attempts[-1].psnr >= target
        break
    meeting = [a for a in attempts if a.psnr >= target]
    chosen = meeting[0] if meeting else max(attempts, key=lambda a: a.psnr)
    kept = work / f"{chosen.setting.profile}-{chosen.setting.preset}"
    for f in kept.iterdir():
        dest = out_dir / f.name
        if dest.is_dir():
            shutil.rmtree(dest)
        f.replace(dest)
    shutil.rmtree(work, ignore_errors=True)
    res = replace(results[(chosen.setting.profile, chosen.setting.preset)], out_dir=out_dir)
    return res, TargetOutcome(target, bool(meeting), chosen, tuple(attempts), source, predicted_max,
                              round(time.perf_counter() - t0, 3), tuple(notes))

