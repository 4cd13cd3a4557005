"""The fused training kernel (issue 30) against the torch path it stands for: features bit-identical,
gradients equal to float rounding, in every phase and format, on random and on real blocks."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("numba")

from bcfpipe.config import ModelConfig, PRESETS, TrainConfig  # noqa: E402
from bcfpipe.formats.vocabulary import FeatureFormat, Kernel  # noqa: E402
from bcfpipe.model import neural as M  # noqa: E402
from bcfpipe.model.features import Layers, codec_of  # noqa: E402
from bcfpipe.train.fused.step import FusedStep  # noqa: E402

TEXTURES = Path(__file__).resolve().parent.parent / "samples" / "textures"
SCALES = (0.0, 0.3, 1.7, 3.0, 5.5, 7.9, 11.0)
BACKENDS = ("native", "numba")  # step.cpp (vectorised) and kernel.py: the same contract


def _image(size: int, channels: int) -> np.ndarray:
    """A real texture (the sample bricks), resized to ``size``, as (size, size, channels) in [0, 1]."""
    from bcfpipe.formats.images import read

    img = read(TEXTURES / "bricks_albedo.png").pixels.astype(np.float32)
    img = img[..., :3] / max(float(img.max()), 1.0)
    t = torch.nn.functional.interpolate(torch.as_tensor(img).permute(2, 0, 1)[None], size=(size, size), mode="area")[0]
    t = torch.cat([t, t[:1].flip(-1)])[:channels]  # a fourth, different channel for BC7
    return t.permute(1, 2, 0).numpy()


def _box_pyramid(size: int, channels: int):
    """`_image`'s box-filtered mip chain as a reference pyramid."""
    from bcfpipe.texset.reference import ReferencePyramid

    mips = [_image(size, channels)]
    while mips[-1].shape[0] > 1:
        m = mips[-1]
        mips.append(0.25 * (m[0::2, 0::2] + m[1::2, 0::2] + m[0::2, 1::2] + m[1::2, 1::2]))
    return ReferencePyramid.from_mips(mips)


def _model(fmt: str, phase: str, real: bool, signed: bool = False, wrap: str = "repeat", seed: int = 0,
           fixed_t0: bool = False):
    """A small material in ``phase`` (free / blocks): its config, levels, level fn, MLP, biases.
    ``fixed_t0``: T_0 replaced by fixed levels (--t0 pca), ISPC's BC7 blocks of a real image, any mode."""
    mc = ModelConfig(resolutions=(64, 32, 16, 8), features=FeatureFormat(fmt), signed=signed, wrap=wrap)
    gen = torch.Generator().manual_seed(seed)
    free = M.init_free(mc, gen, "cpu")
    codec = codec_of(mc)
    lo, hi = codec.param_range(mc)
    with torch.no_grad():
        for mips in free:
            for p in mips:
                p.uniform_(lo - 3, hi + 3, generator=gen)  # some outside the range: the clamps' gradients
    mlp = M.init_mlp(mc.n_inputs, 16, 5, gen, "cpu", torch.rand(5, generator=gen))
    with torch.no_grad():
        mlp["w2"].uniform_(-1, 1, generator=gen)
    biases = M.lod_biases(mc.resolutions, 128, 128)
    if phase == "free":
        free = _fix_t0(free) if fixed_t0 else Layers.of(free)
        return mc, free, (lambda q: M.free_level_fn(free, mc)), mlp, biases, gen
    levels = []
    with torch.no_grad():
        for mips in free:
            layer = []
            for p in mips:
                r = p.shape[-1]
                texels = _image(r, codec.channels) if real else codec.value(p.clamp(lo, hi), mc).permute(1, 2, 0).numpy()
                if real and fmt == "bc6h":
                    texels = texels * 1.5  # BC6H features span about [0, 1.7]
                b = codec.encode(np.ascontiguousarray(texels), mc, "cpu")
                if not real:  # move off the encoder's exact values: continuous endpoints and indices
                    b.endpoints.add_(torch.rand(b.endpoints.shape, generator=gen) * 2 - 1)
                    b.x.add_(torch.rand(b.x.shape, generator=gen) * 0.2 - 0.1)
                layer.append(b)
            levels.append(layer)
    levels = _fix_t0(levels) if fixed_t0 else Layers.of(levels)
    return mc, levels, (lambda q: M.block_level_fn(levels, mc, q)), mlp, biases, gen


def _params(levels):
    return [t for b in levels.trained_levels() for t in ((b.endpoints, b.x) if hasattr(b, "x") else (b,))]


def _fix_t0(levels):
    """T_0's levels replaced by fixed ones (--t0 pca): ISPC's BC7 blocks of a real image, any mode."""
    from bcfpipe.train.fixed_t0 import encoded_levels

    return Layers.of(levels, {0: encoded_levels([_image(64 >> k, 4) for k in range(len(levels[0]))])})


# (format, phase, real blocks, quantization-aware): the warm-up has no quantization-aware decoding
CASES = [("bc6h", "free", False, False), ("bc7", "free", False, False)] + [
    (fmt, "blocks", real, q) for fmt in ("bc6h", "bc7") for real in (False, True) for q in (False, True)]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("fmt,phase,real,quantized", CASES)
def test_features_are_bit_identical_to_the_torch_path(fmt, phase, real, quantized, backend):
    mc, levels, level_fn, mlp, biases, gen = _model(fmt, phase, real)
    fs = FusedStep(mc, biases, mlp, levels, lambda: quantized, backend=backend)
    for s in SCALES:
        uv = torch.rand((2048, 2), generator=gen) * 3 - 1
        with torch.no_grad():
            ref = M.sample_features(level_fn(quantized), mc.mip_counts, biases, uv, s, mc.wrap)
        got = fs.features(uv, s)
        assert torch.equal(got.view(torch.int32), ref.view(torch.int32)), f"s={s}"


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("fmt,signed,wrap", [("bc6h", True, "repeat"), ("bc6h", False, "clamp"), ("bc7", False, "clamp"),
                                             ("bc7", False, "mirror"), ("bc7", False, ("clamp", "repeat")),
                                             ("bc6h", False, ("clamp", "mirror")), ("bc7", False, ("mirror", "repeat"))])
def test_features_signed_and_clamped(fmt, signed, wrap, backend):
    for phase in ("free", "blocks"):
        mc, levels, level_fn, mlp, biases, gen = _model(fmt, phase, False, signed=signed, wrap=wrap)
        fs = FusedStep(mc, biases, mlp, levels, backend=backend)
        for s in SCALES:
            uv = torch.rand((1024, 2), generator=gen) * 3 - 1
            with torch.no_grad():
                ref = M.sample_features(level_fn(False), mc.mip_counts, biases, uv, s, mc.wrap)
            assert torch.equal(fs.features(uv, s).view(torch.int32), ref.view(torch.int32)), f"{phase} s={s}"


def _torch_step(mc, level_fn, mlp, biases, params, uv, target, weight, s):
    for p in params:
        p.grad = None
    pred = M.mlp_raw(mlp, M.sample_features(level_fn, mc.mip_counts, biases, uv, s, mc.wrap)) * mlp["out_scale"] \
        + mlp["out_bias"]
    if weight is None:
        loss = torch.mean((pred - target) ** 2)
    else:
        loss = torch.mean(weight[:, None] * (pred - target) ** 2) / weight.mean().clamp_min(1e-6)
    loss.backward()
    return float(loss.detach()), {id(p): (None if p.grad is None else p.grad.clone()) for p in params}


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("weighted", [False, True])
@pytest.mark.parametrize("fmt,phase,real,quantized", CASES)
def test_loss_and_gradients_match_the_torch_path(fmt, phase, real, quantized, weighted, backend):
    mc, levels, level_fn, mlp, biases, gen = _model(fmt, phase, real)
    fs = FusedStep(mc, biases, mlp, levels, lambda: quantized, backend=backend)
    params = _params(levels) + [mlp[k] for k in ("w1", "b1", "w2", "b2")]
    for s in (0.0, 1.7, 5.5, 11.0):
        uv = torch.rand((2048, 2), generator=gen) * 3 - 1
        target = torch.rand((2048, 5), generator=gen)
        weight = (torch.rand(2048, generator=gen) > 0.3).float() if weighted else None
        loss, ref = _torch_step(mc, level_fn(quantized), mlp, biases, params, uv, target, weight, s)
        for p in params:
            p.grad = None
        got = fs(uv, target, weight, s)
        assert got == pytest.approx(loss, rel=1e-5)
        for p in params:
            r = ref[id(p)]
            if r is None:  # a level the step does not sample gets no gradient, as with autograd
                assert p.grad is None
                continue
            scale = max(float(r.abs().max()), 1e-30)
            assert float((p.grad - r).abs().max()) <= 1e-5 * scale, f"s={s} {tuple(p.shape)}"


@pytest.mark.parametrize("backend", BACKENDS)
def test_chunks_give_the_same_gradients_every_run_and_agree_with_one(backend):
    mc, levels, _, mlp, biases, gen = _model("bc6h", "blocks", True)
    uv = torch.rand((4096, 2), generator=gen)
    target = torch.rand((4096, 5), generator=gen)
    params = _params(levels) + [mlp[k] for k in ("w1", "b1", "w2", "b2")]
    runs = []
    for chunks in (2, 2, 1):
        fs = FusedStep(mc, biases, mlp, levels, chunks=chunks, backend=backend)
        for p in params:
            p.grad = None
        fs(uv, target, None, 0.7)
        runs.append([None if p.grad is None else p.grad.clone() for p in params])
    for a, b, c in zip(*runs):
        if a is None:
            continue
        assert torch.equal(a, b)
        assert float((a - c).abs().max()) <= 1e-5 * max(float(c.abs().max()), 1e-30)


def test_fused_training_is_deterministic_and_trains_as_well_as_torch():
    from bcfpipe.texset.texture_set import TextureSpec, load_texture_set
    from bcfpipe.train.trainer import train

    ts = load_texture_set([TextureSpec.parse(f"albedo={TEXTURES / 'tiles_albedo.png'}:rgb")], resolution=128)
    mc = ModelConfig(features=FeatureFormat.BC6H, resolutions=(64, 32, 16, 8))
    cfg = TrainConfig(model=mc, preset=PRESETS["smoke"], preset_name="smoke", threads=1)
    torch_run = train(ts, cfg, measure_float=False)
    a = train(ts, cfg.with_(kernel=Kernel.FUSED), measure_float=False)
    b = train(ts, cfg.with_(kernel=Kernel.FUSED), measure_float=False)
    for la, lb in zip(a.layers, b.layers):
        for x, y in zip(la, lb):
            assert np.array_equal(x.endpoints, y.endpoints) and np.array_equal(x.indices, y.indices)
    assert np.array_equal(a.mlp.w1, b.mlp.w1)
    last = {name: v for name, _, v in torch_run.history}
    fused_last = {name: v for name, _, v in a.history}
    for phase in ("warmup", "constrained", "finetune"):  # the end-of-phase loss, within 10 %
        assert fused_last[phase] == pytest.approx(last[phase], rel=0.1), phase


@pytest.mark.parametrize("wrap", ["repeat", "clamp", "mirror", ("clamp", "repeat"), ("repeat", "mirror")])
def test_targets_match_the_reference_lookup(wrap):
    """The fused path's targets, both backends: the bicubic lookup agrees with
    reference.sample_reference to float rounding, the texel-centre batches are bit-identical to
    CentreTargets.batch with the same draws (native: sorted into texel order)."""
    from bcfpipe.texset.reference import CentreTargets, sample_reference
    from bcfpipe.train.fused import step as fused_step
    from bcfpipe.train.fused import targets

    pyr = _box_pyramid(64, 3)
    centres = CentreTargets(pyr, wrap, min_texels=256)
    rows = CentreTargets(pyr, wrap, min_texels=256, interleave=True)  # the levels texel by texel
    gen = torch.Generator().manual_seed(3)
    uv = torch.rand((1000, 2), generator=gen) * 3 - 1
    saved = fused_step._BACKEND
    try:
        for backend in BACKENDS:
            fused_step._BACKEND = backend
            for s in (0.0, 0.4, 2.5, 3.0, 5.7, 6.0):
                ref = sample_reference(pyr, uv, s, wrap)
                got = targets.sample_reference(pyr, uv, s, wrap)
                assert float((got - ref).abs().max()) <= 1e-5, (backend, s)
                if centres.covers(s):
                    a = centres.batch(500, s, torch.Generator().manual_seed(1))
                    b = targets.centre_batch(centres, 500, s, torch.Generator().manual_seed(1))
                    if backend == "native":  # the same samples, in texel order
                        order = torch.argsort(a[0][:, 1] * 1e4 + a[0][:, 0], stable=True)
                        a = a[0][order], a[1][order]
                    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1]), (backend, s)
                    c = targets.centre_batch(rows, 500, s, torch.Generator().manual_seed(1))
                    assert torch.equal(c[0], b[0]) and torch.equal(c[1], b[1]), (backend, s)
    finally:
        fused_step._BACKEND = saved


@pytest.mark.parametrize("wrap", ["repeat", "clamp", ("repeat", "mirror")])
def test_lazy_centre_levels_match_precomputed_ones(wrap):
    """A level drawn little (``draws``) is looked up per batch, not precomputed:
    its batches are bit-identical to a precomputed level's, in both layouts, on both paths."""
    from bcfpipe.texset.reference import CentreTargets
    from bcfpipe.train.fused import native
    from bcfpipe.train.fused import targets

    if native.load() is None:
        pytest.skip("no C++ compiler: the native lookup is what makes a lazy level exact")
    pyr = _box_pyramid(64, 3)
    draws = [100.0, 5000.0, 10.0] + [0.0] * (pyr.num_levels - 3)  # levels 0 and 2 lazy, level 1 precomputed
    lazy = CentreTargets(pyr, wrap, min_texels=256, bicubic=targets.bicubic, draws=draws)
    assert lazy.lazy[:3] == [True, False, True] and lazy.up[0] is None and lazy.up[1] is not None
    for interleave in (False, True):
        full = CentreTargets(pyr, wrap, min_texels=256, bicubic=targets.bicubic, interleave=interleave)
        for s in (0.0, 0.3, 0.7, 1.5, 2.0, 2.6):
            assert lazy.covers(s) == full.covers(s)
            for f in (targets.centre_batch, lambda c, n, s, g: c.batch(n, s, g)):
                a = f(full, 700, s, torch.Generator().manual_seed(2))
                b = f(lazy, 700, s, torch.Generator().manual_seed(2))
                assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1]), (interleave, s)


def test_the_native_steps_adam_is_torchs_adam_then_the_clamp():
    """FusedStep.adam (adam.cpp) against torch.optim.Adam and the trainer's clamp on the same
    gradients: the levels a step touches move alike, with per-level step counts; the others stay."""
    import copy

    mc, levels, _, mlp, biases, gen = _model("bc6h", "blocks", True)
    ref = copy.deepcopy(levels)
    lo, hi = codec_of(mc).param_range(mc)
    ours = FusedStep(mc, biases, mlp, levels, backend="native", own_adam=True)
    theirs = FusedStep(mc, biases, mlp, ref, backend="native")
    params = _params(ref)
    opt = torch.optim.Adam(params, lr=0.3)
    uv = torch.rand((2048, 2), generator=gen)
    target = torch.rand((2048, 5), generator=gen)
    for s in (0.0, 1.7, 0.0, 5.5, 0.4):
        ours(uv, target, None, s)
        ours.adam(0.3)
        for p in params:
            p.grad = None
        theirs(uv, target, None, s)
        opt.step()
        with torch.no_grad():
            for p in params:
                if p.grad is not None:
                    p.clamp_(lo, hi) if p.dim() == 3 else p.clamp_(0.0, 1.0)
    moved = 0
    for a, b, start in zip(_params(levels), params, _params(_model("bc6h", "blocks", True)[1])):
        assert float((a.detach() - b.detach()).abs().max()) <= 1e-4, tuple(a.shape)
        moved += int(not torch.equal(b.detach(), start.detach()))
    assert 0 < moved < len(params)  # some levels were never sampled: they did not move


def test_without_a_compiler_the_numba_kernel_runs_and_says_why(monkeypatch, capsys):
    from bcfpipe.train.fused import native
    from bcfpipe.train.fused import step as fused_step

    monkeypatch.setenv("CXX", "/nonexistent/g++")
    monkeypatch.setattr(native, "_lib", None)
    monkeypatch.setattr(fused_step, "_BACKEND", None)
    assert fused_step.default_backend() == "numba"
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["bcfpipe: no C++ compiler (/nonexistent/g++) found (install g++, or set CXX); "
                   "the fused kernel runs in numba and the first encode in torch (slower)"]


def test_a_source_the_compiler_refuses_is_reported_by_its_first_error(monkeypatch, tmp_path):
    """A failed build names the compiler's first error (file:line: error: ...), not the caret
    line GCC ends with."""
    from bcfpipe.train.fused import native

    bad = tmp_path / "bad.cpp"
    bad.write_text("int f() {\n    return 1\n}\n")
    monkeypatch.setattr(native, "SOURCES", (bad,))
    with pytest.raises(native.NativeUnavailable) as e:
        native._build(native._compiler(), tmp_path / "out.so")
    message = str(e.value)
    assert message.startswith("building the fused kernel failed: ") and "bad.cpp:2" in message and "error" in message
    assert not (tmp_path / "out.so").exists() and [p.name for p in tmp_path.iterdir()] == ["bad.cpp"]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64, torch.float16, torch.bfloat16, torch.int64])
def test_host_tensors_come_from_numpys_allocator_where_numpy_has_the_type(dtype):
    """texset.hostmem.empty: numpy's allocator (transparent huge pages) for the types numpy has,
    torch's for the others (bfloat16 has no numpy type); the tensor is the shape and type asked,
    and writable."""
    from bcfpipe.texset import hostmem

    t = hostmem.empty((3, 1000), dtype)
    assert t.shape == (3, 1000) and t.dtype == dtype and t.device.type == "cpu"
    t.fill_(2)
    assert bool((t == 2).all())


# a fixed T_0 (--t0 pca): sampled from its decoded values, no gradient, in both phases
FIXED_CASES = [("free", False), ("blocks", False), ("blocks", True)]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("phase,quantized", FIXED_CASES)
def test_a_fixed_t0_is_sampled_bit_identically_and_gets_no_gradient(phase, quantized, backend):
    mc, levels, level_fn, mlp, biases, gen = _model("bc7", phase, True, fixed_t0=True)
    fs = FusedStep(mc, biases, mlp, levels, lambda: quantized, backend=backend)
    params = _params(levels) + [mlp[k] for k in ("w1", "b1", "w2", "b2")]
    for s in SCALES:
        uv = torch.rand((2048, 2), generator=gen) * 3 - 1
        with torch.no_grad():
            ref = M.sample_features(level_fn(quantized), mc.mip_counts, biases, uv, s, mc.wrap)
        assert torch.equal(fs.features(uv, s).view(torch.int32), ref.view(torch.int32)), f"s={s}"
        target = torch.rand((2048, 5), generator=gen)
        loss, grads = _torch_step(mc, level_fn(quantized), mlp, biases, params, uv, target, None, s)
        for p in params:
            p.grad = None
        assert fs(uv, target, None, s) == pytest.approx(loss, rel=1e-5)
        for p in params:
            r = grads[id(p)]
            if r is None:
                assert p.grad is None
                continue
            assert float((p.grad - r).abs().max()) <= 1e-5 * max(float(r.abs().max()), 1e-30), f"s={s}"
    assert fs.fixed == {(0, k) for k in range(len(levels[0]))}
