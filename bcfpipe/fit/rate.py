"""Rate control (`--target-psnr`): the cheapest profile and preset predicted to reach a PSNR.

Policy:

1. Candidates are the paper profiles whose T_0 fits the source (0.5k and 1k on a CPU, 2k too on
   CUDA; a source under 512 gets its own `auto` profile) times the presets that suit the device
   (draft, fast, standard; paper too on CUDA), ordered by size, then training cost: smallest first.
2. Predictions come from measured anchors plus `bcfpipe.train.gains.GAINS_DB`, the mean PSNR of each (profile, preset)
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

import numpy as np

from bcfpipe.config import PROFILES, QUALITY_PRESETS, TrainingOptions, preset_for, resolve_profile
from bcfpipe.export.material import MaterialResult, make_config, train_material
from bcfpipe.formats.sizes import feature_bytes
from bcfpipe.formats.vocabulary import T0
from bcfpipe.texset.texture_set import TextureSet
from bcfpipe.train.gains import CPU_PROFILES, GPU_PROFILES, profile_gain
from bcfpipe.train.progress import ProgressFn

__all__ = ["Setting", "Attempt", "TargetOutcome", "Step", "candidates", "predict", "next_step", "chosen_attempt",
           "fit_to_target", "anchors_from_bench", "MARGIN_DB"]

MARGIN_DB = 0.5


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


@dataclass(frozen=True)
class Step:
    """What the policy trains next, and why."""

    setting: Setting
    why: str  # "probe", "predicted", "climb" or "best effort"
    predicted: float | None
    note: str | None = None  # said in the outcome (the best effort's reason)


def _key(s: Setting) -> tuple[str, str]:
    return s.profile, s.preset


def next_step(target: float, settings: Sequence[Setting], known: Mapping[tuple[str, str], float],
              attempts: Sequence[Attempt]) -> Step | None:
    """The policy (module docstring), a pure function of what is known: the next setting to train,
    or None once the target is met, a best effort has run, or nothing is predicted to do better.
    ``known``: the anchors and every attempt's measured PSNR."""
    if not known:
        return Step(settings[0], "probe", None)
    if any(a.psnr >= target for a in attempts) or any(a.why == "best effort" for a in attempts):
        return None
    preds = predict(settings, known)
    tried = {_key(a.setting) for a in attempts}
    untried = [s for s in settings if _key(s) not in tried]
    nxt = next((s for s in untried if preds[_key(s)] >= target + MARGIN_DB), None)
    if nxt is None:
        nxt = next((s for s in untried if preds[_key(s)] >= target), None)
    if nxt is not None:
        return Step(nxt, "climb" if any(a.why != "probe" for a in attempts) else "predicted", preds[_key(nxt)])
    best = max((a.psnr for a in attempts), default=float("-inf"))
    top = max(untried, key=lambda s: preds[_key(s)], default=None)
    if top is not None and preds[_key(top)] >= best + MARGIN_DB:
        return Step(top, "best effort", preds[_key(top)],
                    f"no setting is predicted to reach {target:.2f} dB (highest prediction "
                    f"{max(preds.values()):.2f} dB): trained the best-predicted one")
    return None


def chosen_attempt(target: float, attempts: Sequence[Attempt]) -> Attempt:
    """The attempt kept: the first that meets ``target``, else the best measured."""
    return next((a for a in attempts if a.psnr >= target), None) or max(attempts, key=lambda a: a.psnr)


def fit_to_target(ts: TextureSet, options: TrainingOptions, out_dir: str | Path, *, wrap: str,
                  coverage: np.ndarray | None = None, progress: ProgressFn | None = None,
                  anchors: Mapping[tuple[str, str], float] | None = None,
                  on_attempt: Callable[[str], None] | None = None) -> tuple[MaterialResult, TargetOutcome]:
    """Train the cheapest setting predicted to reach ``options.target_psnr`` dB into ``out_dir``
    (module docstring): each attempt `train_material` at its profile and preset, in
    ``out_dir``/.attempts; the kept one's files are moved into ``out_dir``. ``anchors``: measured
    (profile, preset) -> PSNR cells (a bench report's) in place of the probe."""
    t0 = time.perf_counter()
    target = float(options.target_psnr)
    cfg = make_config(ts, options, wrap)[1]
    settings = candidates(max(ts.width, ts.height), cfg.device, cfg.t0 == T0.PCA)
    out_dir = Path(out_dir)
    work = out_dir / ".attempts"
    work.mkdir(parents=True, exist_ok=True)
    known = dict(anchors or {})
    source = "bench" if known else "probe"
    attempts: list[Attempt] = []
    results: dict[tuple[str, str], MaterialResult] = {}
    notes: list[str] = []
    predicted_max = None  # the highest prediction when the policy last weighed the candidates
    while True:
        if known and not any(a.psnr >= target or a.why == "best effort" for a in attempts):
            predicted_max = max(predict(settings, known).values())
        step = next_step(target, settings, known, attempts)
        if step is None:
            break
        if step.note:
            notes.append(step.note)
        s = step.setting
        if on_attempt:
            pred = f"; {step.predicted:.2f} dB predicted" if step.predicted is not None else ""
            on_attempt(f"{s.profile}/{s.preset} ({step.why}{pred})")
        name, c = make_config(ts, options.with_(profile=s.profile, preset=s.preset), wrap)
        res = train_material(ts, work / f"{s.profile}-{s.preset}", c, name, progress, coverage=coverage)[0]
        attempts.append(Attempt(s, step.why, step.predicted, float(res.metrics.psnr), int(res.size_bytes),
                                float(res.train_seconds)))
        results[_key(s)] = res
        known[_key(s)] = attempts[-1].psnr
    chosen = chosen_attempt(target, attempts)
    kept = work / f"{chosen.setting.profile}-{chosen.setting.preset}"
    for f in kept.iterdir():
        dest = out_dir / f.name
        if dest.is_dir():
            shutil.rmtree(dest)
        f.replace(dest)
    shutil.rmtree(work, ignore_errors=True)
    res = replace(results[_key(chosen.setting)], out_dir=out_dir)
    return res, TargetOutcome(target, chosen.psnr >= target, chosen, tuple(attempts), source, predicted_max,
                              round(time.perf_counter() - t0, 3), tuple(notes))
