"""BC@R's full encode beside the layout's probe (`bcfpipe.layout.decide._gated`, issue 58): where no
repack can take BC@R's place, at a preset where no training speculates, with a core to spare, BC@R
is encoded in full on a background thread (quicktex in worker processes) while the probe trains,
unless the oracle on BC@R's sampled estimate rules out every neural candidate. What ships is what
the sequential fit ships, file for file; a probe that BC@R's measure then rules out is dropped."""
from __future__ import annotations

import json
import os
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from bcfpipe.config import TrainingOptions
from bcfpipe.layout import decide as D
from bcfpipe.layout.decide import decide_layout
from bcfpipe.layout.export import decision_json
from bcfpipe.texset import parallel

from test_classic_estimate import _smooth_or_detailed

OPTIONS = TrainingOptions(profile="tiny", preset="smoke", device="cpu", threads=1, seed=0, layout="auto")
BESIDE = "BC@R encoded in full meanwhile"


def _fit(tmp: Path, cores: int = 2):
    """The smooth 256² roughness set's fit (one BC4 group: no repack) on ``cores``, and its log."""
    seen: list[str] = []
    parallel.set_encode_workers(cores)
    try:
        return decide_layout(_smooth_or_detailed(False), tmp, OPTIONS, 256, log=seen.append), seen
    finally:
        parallel.set_encode_workers(None)


def _sequential(tmp: Path, monkeypatch):
    """The fit as it runs without the encode beside the probe: BC@R in full first."""
    with monkeypatch.context() as m:
        m.setattr(D, "_beside_bc", lambda ctx, work: False)
        return _fit(tmp)


def _same(fit, seq) -> None:
    a, b = fit.decision, seq.decision
    assert a.chosen.label == b.chosen.label and a.chosen.mse_per_mip == b.chosen.mse_per_mip
    assert [(c.label, c.basis, c.mse_per_mip) for c in a.candidates] == \
           [(c.label, c.basis, c.mse_per_mip) for c in b.candidates]
    assert decision_json(fit.resolved()) == decision_json(seq.resolved())


def test_the_probe_beside_bcs_encode_ships_what_the_sequential_fit_ships(tmp_path, monkeypatch):
    fit, seen = _fit(tmp_path / "beside")
    seq, seq_seen = _sequential(tmp_path / "seq", monkeypatch)
    assert BESIDE in " ".join(seen) and BESIDE not in " ".join(seq_seen)
    began = next(i for i, s in enumerate(seen) if s.startswith("probe:"))
    assert began < next(i for i, s in enumerate(seen) if s.startswith("encoded in full"))  # logged once joined
    assert fit.probe is not None and seq.probe is not None
    assert np.array_equal(fit.probe.mse_per_channel, seq.probe.mse_per_channel)
    assert "probe" in fit.costs and "estimate" in fit.costs
    _same(fit, seq)


def _ruled_out_when(monkeypatch, measured: bool):
    """The oracle rules out every neural candidate on BC@R in full (``measured``) or on its sampled
    estimate only (not ``measured``), as `decide._ruled_out` would with those figures."""
    real = D._ruled_out

    def ruled_out(ctx):
        if ctx.classic.measured == measured:
            with monkeypatch.context() as m:
                m.setattr(D.C, "admissible", lambda *a, **k: "below the floor")
                return real(ctx)
        return None

    monkeypatch.setattr(D, "_ruled_out", ruled_out)


def test_a_gate_that_rules_the_probe_out_encodes_bc_first(tmp_path, monkeypatch):
    """Ruled out on the estimate, ruled in on BC@R in full: the probe trains after the encode, as
    the sequential fit's does, and ships the same."""
    _ruled_out_when(monkeypatch, measured=False)
    fit, seen = _fit(tmp_path / "gated")
    assert BESIDE not in " ".join(seen)
    encoded = next(i for i, s in enumerate(seen) if s.startswith("encoded in full"))
    assert encoded < next(i for i, s in enumerate(seen) if s.startswith("probe:"))
    seq, _ = _sequential(tmp_path / "seq", monkeypatch)
    assert fit.probe is not None
    _same(fit, seq)


def test_a_probe_that_bcs_measure_rules_out_is_dropped(tmp_path, monkeypatch):
    """Ruled in on the estimate, out on BC@R in full: the probe has trained beside the encode, and
    is dropped; the fit ships what the sequential one does, which never probed."""
    _ruled_out_when(monkeypatch, measured=True)
    fit, seen = _fit(tmp_path / "dropped")
    assert BESIDE in " ".join(seen) and any(s.startswith("probe:") for s in seen)
    assert fit.probe is None and fit.costs["probe_dropped"] > 0 and "probe" not in fit.costs
    seq, _ = _sequential(tmp_path / "seq", monkeypatch)
    assert seq.probe is None
    _same(fit, seq)


def test_not_on_one_core_nor_where_a_repack_may_ship(tmp_path, monkeypatch):
    fit, seen = _fit(tmp_path / "one", cores=1)
    assert fit.probe is not None and BESIDE not in " ".join(seen)
    monkeypatch.setattr(D, "repackable", lambda work: True)
    fit, seen = _fit(tmp_path / "repack")
    assert BESIDE not in " ".join(seen)


def test_the_encode_runs_in_the_background_with_its_quicktex_in_worker_processes(tmp_path, monkeypatch):
    trace = tmp_path / "pools.jsonl"
    monkeypatch.setenv("BCFPIPE_TRACE_POOLS", str(trace))
    parallel.release_workers()  # a pool of this process's earlier encodes would not be traced again
    _fit(tmp_path / "beside")
    pools = [json.loads(line) for line in trace.read_text().splitlines()]
    assert {"kind": "bc-encode-beside-probe", "workers": 1, "pid": os.getpid()} in pools
    assert {"kind": "encode-process-pool", "workers": 2, "pid": os.getpid()} in pools
    assert any(p["kind"] == "quicktex-openmp" and p["pid"] != os.getpid() for p in pools)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a thread's own nice value is Linux's")
def test_background_lowers_the_calling_threads_priority_only():
    seen = {}

    def run():
        parallel.background()
        seen["own"] = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    before = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    t = threading.Thread(target=run)
    t.start()
    t.join()
    assert seen["own"] == max(before, parallel.BACKGROUND_NICE)
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == before


def test_encode_workers_start_without_the_main_scripts_imports(monkeypatch):
    """Spawned workers import the module ``__main__`` names unless told not to: one they cannot
    find breaks the pool (and the CLI's takes 0.6 s in each worker). The pool starts its workers
    with ``__main__`` bare, then puts it back."""
    main = sys.modules["__main__"]
    monkeypatch.setattr(main, "__file__", "/nonexistent/bcfpipe-main.py", raising=False)
    parallel.release_workers()
    px = np.random.default_rng(0).integers(0, 255, (64, 64, 4), dtype=np.uint8)
    try:
        with parallel.workers(2, beside=True):
            got = parallel.quicktex_level("bc1 level 13", px, 8)
    finally:
        parallel.release_workers()
    assert main.__file__ == "/nonexistent/bcfpipe-main.py"
    assert np.array_equal(got, parallel.quicktex_level("bc1 level 13", px, 8))


def test_a_probe_that_fails_stops_the_encode_beside_it_first(tmp_path, monkeypatch):
    def fail(ctx):
        raise RuntimeError("the probe failed")

    monkeypatch.setattr(D, "_probed", fail)
    with pytest.raises(RuntimeError, match="the probe failed"):
        _fit(tmp_path / "failed")
    assert not [t for t in threading.enumerate() if t.name.startswith("bcfpipe-bc-encode")]


def test_the_probe_encodes_its_t0_with_the_alpha_modes_profile(tmp_path, monkeypatch):
    """The probe, which never ships, encodes its T_0 of principal components with `D.PROBE_T0_BC7`;
    what a training ships keeps `basic` (`TrainConfig.t0_bc7`'s default)."""
    from bcfpipe.config import TrainConfig

    seen = []
    train = D.train_material

    def probe(ts, out, cfg, *a, **k):
        seen.append(cfg.t0_bc7)
        return train(ts, out, cfg, *a, **k)

    monkeypatch.setattr(D, "train_material", probe)
    fit, _ = _fit(tmp_path / "m")
    assert fit.probe is not None and seen[0] == D.PROBE_T0_BC7 == "alpha_modes"
    assert TrainConfig().t0_bc7 == "basic"


def test_prepare_starts_the_encode_workers_where_the_fit_may_encode_beside(monkeypatch):
    """`fit.prepare`, before a set loads: the encode workers of a layout fit at a preset that does
    not speculate, with a core beyond the probe's; none for `--layout neural`, a speculating preset,
    or one core."""
    from dataclasses import replace

    from bcfpipe.fit import entry

    started: list[int] = []
    monkeypatch.setattr(entry, "start_workers", started.append)
    draft = replace(OPTIONS, preset="draft")
    cases = [(draft, 2, [2]), (replace(draft, layout="neural"), 2, []), (replace(draft, preset="standard"), 2, []),
             (draft, 1, [])]
    for options, cores, want in cases:
        started.clear()
        parallel.set_encode_workers(cores)
        try:
            entry.prepare(options, ["albedo", "roughness"])
        finally:
            parallel.set_encode_workers(None)
        assert started == want, (options.layout, options.preset, cores)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="background priority is Linux's nice value")
def test_workers_started_ahead_run_at_background_priority_and_are_the_pool_used():
    parallel.release_workers()
    try:
        parallel.start_workers(2).join()
        pool = parallel._process_pool(2)
        pids = list(pool._processes)
        assert len(pids) == 2
        assert all(os.getpriority(os.PRIO_PROCESS, pid) >= parallel.BACKGROUND_NICE for pid in pids)
        assert parallel._process_pool(2) is pool
    finally:
        parallel.release_workers()
