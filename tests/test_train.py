"""End-to-end training on small real data, and determinism."""
from __future__ import annotations

import json

import numpy as np
import torch
import pytest

from bcfpipe.config import ModelConfig, PhaseSchedule, Preset, TrainConfig
from bcfpipe.export.material import train_material
from bcfpipe.texset.texture_set import Channel, TextureSet, TextureSpec, load_texture_set
from bcfpipe.formats.vocabulary import FeatureFormat

# a short schedule for tests: ~2 s of training per run on one core
QUICK = Preset(PhaseSchedule(120, 0.5, 5e-3, 0.98, 0.98), PhaseSchedule(240, 0.1, 5e-3, 0.99, 0.99),
               PhaseSchedule(40, 0.0, 2.5e-3, 1.0, 0.95), 2048, qat_fraction=0.5)
TINY = ModelConfig(features=FeatureFormat.BC6H, resolutions=(32, 16, 8, 4))


def _crop(ts: TextureSet, y: int, x: int, size: int) -> TextureSet:
    return TextureSet(np.ascontiguousarray(ts.data[y:y + size, x:x + size]), ts.channels, size, size)


@pytest.fixture(scope="module")
def teapot_crop(shared_scenes):
    t = shared_scenes / "usdwg_teapot" / "textures"
    ts = load_texture_set([TextureSpec.parse(f"albedo={t / 'tea_set_01_diff_2k.jpg'}:rgb"),
                           TextureSpec.parse(f"roughness={t / 'tea_set_01_arm_2k.jpg'}:g")], resolution=512)
    return _crop(ts, 192, 160, 64)  # a 64x64 crop with the painted flowers


def test_tiny_training_reaches_stated_psnr(tmp_path, teapot_crop):
    """Tiny profile on a 64x64 real crop: the exported BC6H + fp16 decoder must reach 30 dB (all mips)."""
    cfg = TrainConfig(model=TINY, preset=QUICK, preset_name="test", seed=0, device="cpu", threads=1)
    res, tm = train_material(teapot_crop, tmp_path / "m", cfg, "tiny")
    assert res.metrics.psnr >= 30.0, res.metrics.psnr_per_mip
    # quantization loss. This 400-step run spreads by about +-0.6 dB over seeds (float gradients
    # differ in the last bits between decoders); the 0.5 dB acceptance figure is measured on the
    # teapot presets (docs/benchmarks.md). A broken quantization costs several dB.
    assert res.float_metrics.psnr - res.metrics.psnr <= 1.0
    d = res.to_dict()
    assert {"psnr", "ssim", "flip", "size_bytes", "train_seconds"} <= d.keys()
    json.dumps(d)
    assert res.size_bytes == sum(p.stat().st_size for p in (tmp_path / "m").iterdir() if p.suffix in (".dds", ".bin"))


def test_training_is_deterministic_on_cpu(tmp_path):
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:32, 0:32] / 32.0
    data = np.stack([0.5 + 0.4 * np.sin(6 * xx), 0.5 + 0.4 * np.cos(5 * yy), rng.uniform(0, 1, (32, 32))], -1)
    ch = tuple(Channel("albedo", c, "color", "gen", i) for i, c in enumerate("rgb"))
    ts = TextureSet(data.astype(np.float32), ch, 32, 32)
    quick = Preset(PhaseSchedule(30, 0.5, 5e-3, 0.99, 0.99), PhaseSchedule(30, 0.1, 5e-3, 0.99, 0.99),
                   PhaseSchedule(10, 0.0, 2e-3, 1.0, 0.99), 512)
    cfg = TrainConfig(model=ModelConfig(features=FeatureFormat.BC6H, resolutions=(16, 8, 8, 4)), preset=quick, seed=3, device="cpu", threads=1)
    outs = []
    for run in range(2):
        train_material(ts, tmp_path / str(run), cfg, "t")
        outs.append({p.name: p.read_bytes() for p in (tmp_path / str(run)).iterdir() if p.suffix in (".dds", ".bin")})
    assert outs[0] == outs[1]
    cfg2 = cfg.with_(seed=4)
    train_material(ts, tmp_path / "other", cfg2, "t")
    assert (tmp_path / "other" / "weights.bin").read_bytes() != outs[0]["weights.bin"]


def test_stratified_scale_power_favours_fine_lods():
    """s = s_max * u**power with u stratified: power 1 is uniform over [0, s_max]; power 2 puts
    sqrt(1/4) = half of the steps below s_max / 4, and every value stays inside [0, s_max]."""
    import torch

    from bcfpipe.train.trainer import StratifiedScale

    for power, share in ((1.0, 0.25), (2.0, 0.5)):
        nxt = StratifiedScale(11.0, torch.Generator().manual_seed(0), power=power)
        s = np.array([nxt() for _ in range(16 * 200)])
        assert s.min() >= 0 and s.max() <= 11.0
        assert abs(np.mean(s < 11.0 / 4) - share) < 0.02


@pytest.mark.parametrize("power, s_min", [(1.0, 0.0), (2.0, 0.0), (2.0, 3.0)])
def test_stratified_scale_share_is_what_it_draws(power, s_min):
    """`StratifiedScale.share` (what the centre targets plan their levels by) is the share of the
    scales it draws below s, per level to 0.02."""
    import torch

    from bcfpipe.train.trainer import StratifiedScale

    nxt = StratifiedScale(11.0, torch.Generator().manual_seed(1), power=power, s_min=s_min)
    s = np.array([nxt() for _ in range(16 * 300)])
    for k in range(12):
        assert abs(np.mean(np.floor(s) == k) - (nxt.share(k + 1) - nxt.share(k))) < 0.02, k


class _FakeClock:
    """A clock that moves ``dt`` seconds each time it is read: a training of slow steps."""

    def __init__(self, dt: float):
        self.now, self.dt = 1000.0, dt

    def __call__(self) -> float:
        self.now += self.dt
        return self.now


def test_progress_comes_on_time_and_changes_nothing():
    """With steps of 0.25 s (a fake clock) and no step-based reports, every phase reports at
    least every second; the phases without steps (encode, quantize) report as they start. The
    trained material is bit for bit the one trained without progress, and the loss history
    (step-based) is unchanged."""
    from bcfpipe.train.pace import Pace
    from bcfpipe.train.trainer import train

    data = np.random.default_rng(1).uniform(0, 1, (32, 32, 3)).astype(np.float32)
    ts = TextureSet(data, tuple(Channel("albedo", c, "color", "gen", i) for i, c in enumerate("rgb")), 32, 32)
    quick = Preset(PhaseSchedule(30, 0.5, 5e-3, 0.99, 0.99), PhaseSchedule(30, 0.1, 5e-3, 0.99, 0.99),
                   PhaseSchedule(10, 0.0, 2e-3, 1.0, 0.99), 256)
    cfg = TrainConfig(model=ModelConfig(features=FeatureFormat.BC6H, resolutions=(16, 8, 8, 4)), preset=quick, seed=3, device="cpu", threads=1)
    clock = _FakeClock(0.25)
    seen = []
    tm = train(ts, cfg, lambda p: seen.append((clock.now, p)), pace=Pace(every=10**6, seconds=1.0, clock=clock))
    plain = train(ts, cfg, pace=Pace(every=10**6))
    assert [p.phase for _, p in seen if p.phase in ("encode", "quantize") and p.step == 0] == ["encode", "quantize"]
    phases = [p.phase for _, p in seen]
    assert sorted(set(phases), key=phases.index) == ["warmup", "encode", "constrained", "quantize", "finetune"]
    gaps = np.diff([t for t, _ in seen])
    assert gaps.max() <= 1.0 + 0.25 + 1e-9, gaps  # due after 1 s, noticed at the end of that step
    assert all(p.step - q.step <= 5 for (_, q), (_, p) in zip(seen, seen[1:])
               if p.phase == q.phase and p.phase != "encode")
    assert len([p for _, p in seen if p.phase == "warmup"]) >= 30 // 5
    assert tm.history == [(ph, n, tm.history[i][2]) for i, (ph, n) in
                          enumerate([("warmup", 30), ("constrained", 30), ("finetune", 10)])]
    assert [h[:2] for h in tm.history] == [h[:2] for h in plain.history]
    assert all(np.array_equal(a, b) for a, b in zip(tm.mlp.arrays(), plain.mlp.arrays()))
    for la, lb in zip(tm.layers, plain.layers):
        for a, b in zip(la, lb):
            assert np.array_equal(a.endpoints, b.endpoints) and np.array_equal(a.indices, b.indices)
            assert (a.partition is None) == (b.partition is None)
            assert a.partition is None or np.array_equal(a.partition, b.partition)


def test_train_reporter_prints_through_a_long_call():
    """`bcfpipe train`'s plain lines: the latest report again, its elapsed time brought up to
    date, once nothing was printed for LINE_SECONDS (a fake clock; the Ticker calls `tick`)."""
    import io
    import math

    from rich.console import Console

    from bcfpipe.cli.train import _Reporter
    from bcfpipe.train.pace import LINE_SECONDS
    from bcfpipe.train.progress import Progress

    now = [50.0]
    buf = io.StringIO()
    rep = _Reporter(False, Console(file=buf, width=200), clock=lambda: now[0])
    rep.tick()
    now[0] += LINE_SECONDS
    rep.tick()
    assert buf.getvalue().split() == ["starting", "elapsed", f"{LINE_SECONDS:.0f}s"]
    rep(Progress("encode", 0, 14, math.nan, math.nan, 3.0, 40.0))  # within 5 s of a line: not printed
    now[0] += LINE_SECONDS - 0.5
    rep.tick()
    assert len(buf.getvalue().splitlines()) == 1
    now[0] += 0.5
    rep.tick()
    assert len(buf.getvalue().splitlines()) == 2
    last = buf.getvalue().splitlines()[-1].split()
    assert last[:2] == ["encode", "0/14"] and last[3] == f"{3 + LINE_SECONDS:.0f}s"


@pytest.mark.parametrize("hdr", [False, True])
def test_float_model_measured_chunk_by_chunk_equals_the_held_mips(hdr):
    """The float model's PSNR, accumulated chunk by chunk against the training reference, equals
    compute_metrics on the decoded mips held whole (as before, when an 8K set held 2.7 GiB more);
    with an HDR channel both measure in its log domain."""
    import torch

    from bcfpipe.model import neural as M
    from bcfpipe.model.features import Layers
    from bcfpipe.texset import encoding
    from bcfpipe.texset.metrics import compute_metrics, metrics_from_mse
    from bcfpipe.texset.reference import ReferencePyramid
    from bcfpipe.texset.texture_set import build_mip_chain
    from bcfpipe.train.trainer import evaluate_levels, float_model_mse

    rng = np.random.default_rng(0)
    data = rng.random((64, 32, 4)).astype(np.float32)
    data[..., 3] **= 4  # HDR-like: mostly dark, a few bright texels
    chans = [Channel("albedo", c, "color", "a.png", i) for i, c in enumerate("rgb")]
    chans.append(Channel("emission", "r", "generic", "e.exr", 0, log_gain=6.0) if hdr
                 else Channel("roughness", "r", "generic", "r.png", 0))
    ts = TextureSet(data, tuple(chans), 32, 64)
    mc = TINY
    gen = torch.Generator().manual_seed(1)
    free = M.init_free(mc, gen, "cpu")
    mlp = M.init_mlp(mc.n_inputs, mc.hidden, 4, gen, "cpu", torch.full((4,), 0.5))
    biases = M.lod_biases(mc.resolutions, 32, 64)
    kinds = tuple(c.kind for c in chans)
    gains = encoding.gains(ts.channels)
    ref_mips = build_mip_chain(ts.data)
    ref = ReferencePyramid.from_mips(encoding.encode_levels(ref_mips, gains))
    fn = M.free_level_fn(Layers.of(free), mc)
    got = metrics_from_mse(float_model_mse(fn, mlp, mc, kinds, biases, ref), chans, [m.shape[:2] for m in ref_mips])
    held = [np.empty((h * w, 4), np.float32) for h, w in (m.shape[:2] for m in ref_mips)]
    for k, a, y in evaluate_levels(fn, mlp, mc, kinds, biases, [m.shape[:2] for m in ref_mips], chunk=97):
        held[k][a:a + len(y)] = y.numpy()
    held = encoding.decode_levels([h.reshape(m.shape) for h, m in zip(held, ref_mips)], gains)
    want = compute_metrics(ref_mips, held, chans, ssim=False, flip=False)
    np.testing.assert_allclose(got.psnr_per_mip, want.psnr_per_mip, atol=1e-4)
    assert abs(got.psnr - want.psnr) < 1e-4 and got.mips_in_mean == want.mips_in_mean
    assert got.psnr_per_group.keys() == want.psnr_per_group.keys()
    np.testing.assert_allclose(list(got.psnr_per_group.values()), list(want.psnr_per_group.values()), atol=1e-4)


def test_a_training_sets_its_threads_only_while_it_trains():
    """`train` runs on ``cfg.threads`` torch threads and leaves the count as it found it: a count
    left at 1 slowed every later measure in the process (FLIP's OpenMP halved, issue 58)."""
    import torch

    from bcfpipe.train.trainer import train

    rng = np.random.default_rng(1)
    ch = tuple(Channel("albedo", c, "color", "gen", i) for i, c in enumerate("rgb"))
    ts = TextureSet(rng.uniform(0, 1, (16, 16, 3)).astype(np.float32), ch, 16, 16)
    quick = Preset(PhaseSchedule(4, 0.5, 5e-3, 0.99, 0.99), PhaseSchedule(4, 0.1, 5e-3, 0.99, 0.99),
                   PhaseSchedule(2, 0.0, 2e-3, 1.0, 0.99), 64)
    cfg = TrainConfig(model=ModelConfig(features=FeatureFormat.BC6H, resolutions=(8, 4, 4, 4)), preset=quick, seed=0,
                      device="cpu", threads=1)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    seen = []
    try:
        train(ts, cfg, progress=lambda *a, **k: seen.append(torch.get_num_threads()))
        assert seen and set(seen) == {1}
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_device_name_is_torchs_name_for_the_device_a_run_trains_on():
    """`train.devices.device_name`, which names the device without importing torch on a CPU build,
    names the one torch would resolve; CUDA asked for where torch has none is a one-line error."""
    from bcfpipe.train.devices import device_name
    from bcfpipe.train.trainer import resolve_device

    assert device_name("cpu") == "cpu"
    assert device_name("auto") == str(resolve_device("auto"))
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="no CUDA device"):
            device_name("cuda")
