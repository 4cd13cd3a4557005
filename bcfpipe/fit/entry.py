"""`fit`: train, export and measure one material the way its options ask, chosen once here.

Three fits share the texture set, the options record and the output folder:

* ``layout`` (`--layout auto`, or `--classic` naming one of the set's semantics): per-channel
  classic BC textures and neural features, chosen against BC@R (`bcfpipe.layout`);
* ``rate`` (`--target-psnr`): the cheapest profile and preset predicted to reach the target
  (`bcfpipe.fit.rate`);
* ``neural``: every output from the MLP at the profile and preset asked (`bcfpipe.export.material`).

`bcfpipe train`, both build executors and `bcfpipe bench` call only `fit`.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from bcfpipe.config import TrainingOptions
from bcfpipe.export.material import MaterialResult, train_material, make_config
from bcfpipe.fit.rate import fit_to_target
from bcfpipe.formats.fit_result import FitResult
from bcfpipe.layout.decide import may_encode_beside
from bcfpipe.layout.material import layout_material
from bcfpipe.layout.predict import uses_layout
from bcfpipe.texset import heap
from bcfpipe.texset.parallel import encode_workers, start_workers
from bcfpipe.texset.texture_set import TextureSet
from bcfpipe.train.progress import ProgressFn


class FitMode(StrEnum):
    """Which fit a material's options ask for."""

    NEURAL = "neural"
    LAYOUT = "layout"
    RATE = "rate"


@dataclass(frozen=True)
class Fitted:
    """A fitted material: its measured result and, under --target-psnr, how the target went."""

    result: MaterialResult
    mode: FitMode
    target: object | None = None  # bcfpipe.fit.rate.TargetOutcome with --target-psnr

    def record(self) -> FitResult:
        """The result as its record (`formats.fit_result.FitResult`), with ``target`` under
        --target-psnr: numbers as JSON holds them."""
        d = self.result.to_dict()
        if self.target is not None:
            d["target"] = self.target.to_json()
        return FitResult.from_json(json.loads(json.dumps(d, default=float)), "result")


def fit_mode(options: TrainingOptions, semantics) -> FitMode:
    """The fit ``options`` ask for, for a set of ``semantics``."""
    if uses_layout(options, semantics):
        return FitMode.LAYOUT
    return FitMode.NEURAL if options.target_psnr is None else FitMode.RATE


def prepare(options: TrainingOptions, semantics) -> None:
    """Start, before the set of ``semantics`` is loaded, what its fit will wait for: the encode
    workers of a layout fit that may encode BC@R beside its probe (`parallel.start_workers`), while
    the loading leaves the other cores idle."""
    if fit_mode(options, sorted(set(semantics))) == FitMode.LAYOUT and may_encode_beside(options):
        start_workers(encode_workers())


def fit(ts: TextureSet, options: TrainingOptions, out: str | Path, *, wrap: str,
        coverage: np.ndarray | None = None, progress: ProgressFn | None = None,
        log: Callable[[str], None] | None = None,
        anchors: Mapping[tuple[str, str], float] | None = None) -> Fitted:
    """Fit ``ts`` as ``options`` ask into ``out``, measured from the exported files. ``coverage``:
    the texels the scene reads (training draws there, figures are over them). ``progress`` hears
    the trainings; ``log`` one line per decision, prefixed by its fit ("layout: ...", "rate control:
    training ..."). ``anchors``: measured (profile, preset) -> PSNR cells for rate control."""
    with heap.reused(ts.data.size):  # a fit's large temporaries from the heap, not fresh pages
        say = log or (lambda text: None)
        mode = fit_mode(options, sorted({c.semantic for c in ts.channels}))
        if mode == FitMode.LAYOUT:
            res = layout_material(ts, out, options, wrap, lambda text: say(f"layout: {text}"),
                                  progress=progress, coverage=coverage)
            return Fitted(res, mode)
        if mode == FitMode.NEURAL:
            name, cfg = make_config(ts, options, wrap)
            return Fitted(train_material(ts, out, cfg, name, progress, coverage=coverage)[0], mode)
        res, outcome = fit_to_target(ts, options, out, wrap=wrap, coverage=coverage, progress=progress, anchors=anchors,
                                     on_attempt=lambda text: say(f"rate control: training {text}"))
        return Fitted(res, mode, outcome)
