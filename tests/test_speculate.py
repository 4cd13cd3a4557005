"""The likeliest training beside the probe (`bcfpipe.layout.speculate`, issue 58): adopted when the
fit chooses it, it ships what the sequential fit ships, byte for byte; dropped otherwise, it leaves
nothing once waited for, also when the oracle rules out every neural candidate before a probe; a
fit that fails stops it first; with no core to spare, or a set too large for two trainings' memory,
it never starts. It starts before BC@R's full encode, whose quicktex then runs in a worker process."""
from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import pytest

from bcfpipe.config import TrainingOptions
from bcfpipe.layout import decide as D
from bcfpipe.layout import kinds as K
from bcfpipe.layout import speculate
from bcfpipe.layout.decide import decide_layout
from bcfpipe.texset import parallel

from test_classic_estimate import _smooth_or_detailed

OPTIONS = TrainingOptions(profile="tiny", preset="smoke", device="cpu", threads=1, seed=0, layout="auto")


@pytest.fixture(autouse=True)
def _smoke_speculates(monkeypatch):
    """These tests train at smoke (a second a training), where no fit speculates (`PRESETS`): the
    mechanism is what they test, and `test_no_speculation_at_draft` the presets."""
    monkeypatch.setattr(speculate, "PRESETS", (*speculate.PRESETS, "smoke"))


def _fit(tmp: Path, cores: int = 2, options: TrainingOptions = OPTIONS, resolution: int = 256):
    """The smooth 256² set's fit (the probe trains) on ``cores`` at R = ``resolution``, and what it
    logged. Below 256 the likeliest training starts before BC@R's full encode (`decide._promising`)."""
    seen: list[str] = []
    parallel.set_encode_workers(cores)
    try:
        return decide_layout(_smooth_or_detailed(False), tmp, options, resolution, log=seen.append), seen
    finally:
        parallel.set_encode_workers(None)


def _sequential(tmp: Path, monkeypatch, resolution: int = 256):
    """`_fit` with no speculation: the fit as it runs without a core to spare for it."""
    with monkeypatch.context() as m:
        m.setattr(speculate, "start", lambda ctx, bc_bytes=None: None)
        return _fit(tmp, resolution=resolution)[0]


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def _choose_the_guess(monkeypatch):
    """The fit trains `speculate.guess`'s candidate (here the mean predictions ship BC@R, and the
    smoke preset's largest gain clears nothing): what decides is not what is tested."""
    def hopeful(ctx, held):
        profile, width = speculate.guess(ctx)
        return next(w.candidate for w in K.NEURAL.predict(ctx)
                    if w.candidate.profile == profile and w.candidate.part.t0_layers == width)
    monkeypatch.setattr(D, "_hopeful", hopeful)


def test_an_adopted_training_ships_the_files_and_figures_of_the_sequential_one(tmp_path, monkeypatch):
    _choose_the_guess(monkeypatch)
    seq = _sequential(tmp_path / "seq", monkeypatch)
    fit, seen = _fit(tmp_path / "spec")
    assert any(s.startswith("meanwhile training neural tiny") for s in seen)
    assert any(s.endswith("(begun beside the probe)") for s in seen)
    assert "speculation_dropped" not in fit.costs and "train" in fit.costs
    trained = [c for c in fit.decision.candidates if c.kind is K.NEURAL and c.basis == "measured"]
    before = [c for c in seq.decision.candidates if c.kind is K.NEURAL and c.basis == "measured"]
    assert len(trained) == len(before) == 1
    assert trained[0].mse_per_mip == before[0].mse_per_mip and trained[0].size_bytes == before[0].size_bytes
    assert fit.decision.chosen.label == seq.decision.chosen.label
    mine, theirs = _files(tmp_path / "spec" / speculate.FOLDER / "neural"), _files(tmp_path / "seq" / "neural")
    assert mine.keys() == theirs.keys() and mine == theirs


@pytest.mark.parametrize("ended_first", [False, True])
def test_a_training_not_chosen_is_dropped_and_leaves_nothing(tmp_path, monkeypatch, ended_first):
    """Dropped whether it still runs when the probe chooses or (a short training on a busy
    machine) has ended: either way counted as dropped, its files gone once waited for."""
    if ended_first:
        started: list[speculate.Speculation] = []
        start, probed = speculate.start, D._probed
        monkeypatch.setattr(speculate, "start",
                            lambda ctx, bc_bytes=None: started.append(start(ctx, bc_bytes)) or started[-1])

        def probe_once_it_ended(ctx):
            started[-1].future.exception()  # waits for it
            return probed(ctx)

        monkeypatch.setattr(D, "_probed", probe_once_it_ended)
    fit, seen = _fit(tmp_path / "spec")
    seq = _sequential(tmp_path / "seq", monkeypatch)
    assert any(s.startswith("meanwhile training neural tiny") for s in seen)
    assert fit.costs["speculation_dropped"] > 0 and "train" not in fit.costs
    fit.join_aside()  # it stops at its next progress report; the fit's caller waits before removing its folder
    assert not (tmp_path / "spec" / speculate.FOLDER).exists()
    assert fit.decision.chosen.label == seq.decision.chosen.label
    assert fit.decision.chosen.mse_per_mip == seq.decision.chosen.mse_per_mip


def test_no_speculation_on_one_core_or_for_a_set_too_large_for_two_trainings(tmp_path, monkeypatch):
    fit, seen = _fit(tmp_path / "one", cores=1)
    assert fit.probe is not None and "speculation_dropped" not in fit.costs
    assert not any(s.startswith("meanwhile") for s in seen)
    monkeypatch.setattr(speculate, "MAX_VALUES", 256 * 256 - 1)
    fit, seen = _fit(tmp_path / "large")
    assert fit.probe is not None and "speculation_dropped" not in fit.costs
    assert not any(s.startswith("meanwhile") for s in seen)


def test_the_guess_is_the_widest_all_channel_model_at_the_probes_profile_within_bcs_bytes():
    classic = SimpleNamespace(bc=SimpleNamespace(size_bytes=100))
    ctx = K.FitContext(SimpleNamespace(num_channels=11), Path("."), OPTIONS, "repeat", 256, classic=classic,
                       p0="1k", profiles=("1k", "0.5k"), widths=(1, 2, 3),
                       sizes={("1k", 1): 60, ("1k", 2): 100, ("1k", 3): 140, ("0.5k", 3): 50})
    assert speculate.guess(ctx) == ("1k", 2)
    assert speculate.guess(replace(ctx, sizes={**ctx.sizes, ("1k", 1): 101, ("1k", 2): 120})) is None
    assert speculate.guess(replace(ctx, forced=("roughness",))) is None


@pytest.mark.parametrize("resolution", [256, 128])  # begun beside the probe; at the fit's start
def test_a_fit_that_fails_beside_a_speculative_training_stops_it_first(tmp_path, monkeypatch, resolution):
    """The probe fails (here: raises) while the likeliest training runs beside it: the fit's error
    reaches the caller only after that training has stopped and its files are gone."""
    started: list[speculate.Speculation] = []
    start = speculate.start
    monkeypatch.setattr(speculate, "start", lambda ctx, bc_bytes=None: started.append(start(ctx, bc_bytes)) or started[-1])

    def failing_probe(ctx):
        raise RuntimeError("the probe failed")

    monkeypatch.setattr(D, "_probed", failing_probe)
    with pytest.raises(RuntimeError, match="the probe failed"):
        _fit(tmp_path / "spec", resolution=resolution)
    (spec,) = started
    assert spec.future.done() and spec.gate.cancelled.is_set()
    # stopped at its next report, or (a smoke training of a tiny set, begun at the fit's start)
    # already done: either way ended before the error reached the caller
    assert spec.future.exception() is None or isinstance(spec.future.exception(), speculate.Cancelled)
    assert not (tmp_path / "spec" / speculate.FOLDER).exists()


def test_no_speculation_at_draft(tmp_path):
    """At draft a dropped speculation cost more than an adopted one could save (`PRESETS`): the
    quality set is estimated beside the probe instead."""
    fit, seen = _fit(tmp_path / "draft", options=replace(OPTIONS, preset="draft"))
    assert fit.probe is not None and "speculation_dropped" not in fit.costs
    assert not any(s.startswith("meanwhile") for s in seen)
    assert "draft" not in speculate.PRESETS and {"fast", "standard", "paper"} <= set(speculate.PRESETS)


def test_it_starts_before_bcs_full_encode_whose_quicktex_runs_in_a_worker_process(tmp_path, monkeypatch):
    """quicktex holds the GIL through a whole level: beside the training's thread it runs in a
    worker process, on the core the training leaves, even with one."""
    trace = tmp_path / "pools.jsonl"
    monkeypatch.setenv("BCFPIPE_TRACE_POOLS", str(trace))
    parallel.release_workers()  # a pool of this process's earlier encodes would not be traced again
    fit, seen = _fit(tmp_path / "spec", resolution=128)
    fit.join_aside()
    began = next(i for i, s in enumerate(seen) if s.startswith("meanwhile training neural tiny"))
    assert began < next(i for i, s in enumerate(seen) if s.startswith("encoded in full"))
    pools = [json.loads(line) for line in trace.read_text().splitlines()]
    kinds = [p["kind"] for p in pools]
    assert kinds.index("speculative-training") < kinds.index("encode-process-pool")
    assert {"kind": "encode-process-pool", "workers": 1, "pid": os.getpid()} in pools  # 2 cores, 1 training
    assert any(p["kind"] == "quicktex-openmp" and p["pid"] != os.getpid() for p in pools)


def _rule_out(monkeypatch):
    """The oracle rules out every neural candidate (even a perfect one) on BC@R in full."""
    real = D._ruled_out

    def ruled_out(ctx):
        with monkeypatch.context() as m:
            m.setattr(D.C, "admissible", lambda *a, **k: "below the floor")
            return real(ctx)

    monkeypatch.setattr(D, "_ruled_out", ruled_out)


def test_a_training_begun_before_the_oracle_rules_out_every_neural_candidate_is_dropped(tmp_path, monkeypatch):
    """No probe then: the training begun at the fit's start is cancelled, and the fit ships what the
    sequential one does."""
    _rule_out(monkeypatch)
    fit, seen = _fit(tmp_path / "spec", resolution=128)
    assert any(s.startswith("meanwhile training neural tiny") for s in seen)
    assert any(s.startswith("no probe: no neural candidate") for s in seen)
    assert fit.probe is None and "speculation_dropped" in fit.costs and "train" not in fit.costs
    fit.join_aside()
    assert not (tmp_path / "spec" / speculate.FOLDER).exists()
    seq = _sequential(tmp_path / "seq", monkeypatch, resolution=128)
    assert seq.probe is None and fit.decision.chosen.label == seq.decision.chosen.label
    assert fit.decision.chosen.mse_per_mip == seq.decision.chosen.mse_per_mip


def test_at_the_sets_own_side_it_starts_beside_the_probe_after_bcs_encode(tmp_path):
    """R = the set's side: BC@R ships on every set measured there, so its full encode keeps every
    core, and the training starts when the probe does."""
    fit, seen = _fit(tmp_path / "spec")
    fit.join_aside()
    began = next(i for i, s in enumerate(seen) if s.startswith("meanwhile training neural tiny"))
    assert began > next(i for i, s in enumerate(seen) if s.startswith("encoded in full"))
