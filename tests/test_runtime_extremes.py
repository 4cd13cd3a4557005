"""Runtime extremes of the GLSL decoder (issue #11, item 4), through OpenGL against the CPU paths:
uv far outside [0, 1], lods far outside the mip range, zero / huge / infinite derivatives, and fp16
weight records near overflow. ``bcfpipe verify`` samples the same cases on every material
(bcfpipe/verify/points.py); these tests pin down what the shader returns there."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from bcfpipe.model.decoder import FP16_MAX, MlpWeights, balance_for_fp16, decode_numpy, from_bytes, to_bytes
from bcfpipe.verify import checks as V
from bcfpipe.verify.glsl import read_material

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_verify import gl_runtime, make_material  # noqa: E402,F401


@pytest.fixture(scope="module")
def mats(tmp_path_factory):
    base = tmp_path_factory.mktemp("extremes")
    out = {}
    for name, kw in {"repeat": {}, "clamp": dict(wrap="clamp", normal=True, signed=True)}.items():
        (base / name).mkdir()
        out[name] = make_material(base / name, **kw)
    return out


@pytest.fixture()
def loaded(mats, gl_runtime):
    done = []

    def load(name):
        gm = gl_runtime.load(read_material(mats[name]))
        done.append(gm)
        return gm
    yield load
    for gm in done:
        gl_runtime.unload(gm)


def _points(n=512, seed=0):
    return np.random.default_rng(seed).random((n, 2)).astype(np.float32)


@pytest.mark.parametrize("offset", [1e4, -1e4, 3e5, -1e7])
def test_far_uv_with_repeat_decodes_exactly_as_its_fraction(loaded, gl_runtime, offset):
    """The shader range-reduces uv itself (uv - floor(uv), exact in fp32), so a far uv decodes
    bit for bit like the fraction of the same fp32 value, whatever the texture unit's precision."""
    gm = loaded("repeat")
    far = (_points() + np.float32(offset)).astype(np.float32)
    frac = (far.astype(np.float64) - np.floor(far.astype(np.float64))).astype(np.float32)
    for s in (0.0, 1.37):
        a, b = gl_runtime.decode(gm, far, s), gl_runtime.decode(gm, frac, s)
        assert np.array_equal(a, b)


def test_far_uv_with_clamp_decodes_the_edge(loaded, gl_runtime):
    gm = loaded("clamp")
    t = _points(256)[:, 0]
    for far, edge in ((-1e4, 0.0), (1e4, 1.0), (-1e30, 0.0), (1e30, 1.0)):
        uv = np.stack([np.full_like(t, far), t], 1)
        ref = np.stack([np.full_like(t, edge), t], 1)
        assert np.abs(gl_runtime.decode(gm, uv, 0.5) - gl_runtime.decode(gm, ref, 0.5)).max() < 1e-6


def test_lods_far_outside_the_mip_range_clamp(mats, loaded, gl_runtime):
    gm = loaded("repeat")
    m = read_material(mats["repeat"])
    s_last = max(n - 1 - b for n, b in zip(m.mip_counts, m.lod_biases))
    uv = _points()
    at0, at_last = gl_runtime.decode(gm, uv, 0.0), gl_runtime.decode(gm, uv, s_last)
    for s in (-np.inf, -1e30, -1e4, -100.0):
        assert np.array_equal(gl_runtime.decode(gm, uv, s), at0), s
    for s in (100.0, 1e4, 1e30, np.inf):
        assert np.array_equal(gl_runtime.decode(gm, uv, s), at_last), s
    assert np.isfinite(at0).all() and np.isfinite(at_last).all()


def test_derivatives_zero_tiny_huge_and_infinite(mats, loaded, gl_runtime):
    """bcfDecodeGrad: zero and tiny derivatives magnify level 0, huge ones (whose squares overflow
    fp32) and infinite ones give the last mip, one reference texel per pixel is s = 0 exactly."""
    gm = loaded("repeat")
    m = read_material(mats["repeat"])
    w = m.ref_size[0]
    uv = _points(256)
    n = len(uv)
    at0, at2, at_last = (gl_runtime.decode(gm, uv, s) for s in (0.0, 2.0, 1e30))

    def grad(dx, dy):
        return gl_runtime.decode_grad(gm, uv, np.tile(np.float32(dx), (n, 1)), np.tile(np.float32(dy), (n, 1)))

    assert np.array_equal(grad((0, 0), (0, 0)), at0)
    assert np.array_equal(grad((1e-45, 0), (0, 1e-38)), at0)
    assert np.array_equal(grad((1 / w, 0), (0, 1 / w)), at0)
    assert np.array_equal(grad((4 / w, 0), (0, 1 / w)), at2)
    for dx, dy in (((1e20, 0), (0, 0)), ((3e38, 3e38), (0, 0)), ((np.inf, 0), (0, 0)), ((0, 0), (0, -np.inf))):
        assert np.array_equal(grad(dx, dy), at_last), (dx, dy)


def _near_overflow(part: str):
    """The same decoder with, per hidden unit (``part`` "W1") or per output ("out_scale"), a power of
    two moved into that part up to just below fp16's largest value; W2 shrinks by the same factor
    into fp16's subnormal range."""
    def transform(w: MlpWeights) -> MlpWeights:
        w1, b1, w2, b2, sc, bi = (np.array(a, np.float32) for a in w.arrays())
        if part == "W1":
            f = np.exp2(np.floor(np.log2(FP16_MAX / np.maximum(np.abs(w1).max(1), np.abs(b1))))).astype(np.float32)
            w1, b1, w2 = w1 * f[:, None], b1 * f, w2 / f[None, :]
        else:
            g = np.exp2(np.floor(np.log2(FP16_MAX / np.abs(sc)))).astype(np.float32)
            w2, b2, sc = w2 / g[:, None], b2 / g, sc * g
        return MlpWeights(*(a.astype(np.float16).astype(np.float32) for a in (w1, b1, w2, b2, sc, bi)))
    return transform


@pytest.mark.parametrize("part", ["W1", "out_scale"])
def test_fp16_weights_near_overflow_verify_end_to_end(tmp_path, gl_runtime, part):
    """A record whose W1 and b1, or out_scale, reach 2^15..65504 while W2 is subnormal: the
    shader's fp32 arithmetic cannot overflow, and GL matches ONNX within the derived tolerance."""
    out = make_material(tmp_path, normal=True, mlp_transform=_near_overflow(part))
    w, _ = from_bytes((out / "weights.bin").read_bytes())
    big = np.abs(w.w1 if part == "W1" else w.out_scale).max()
    assert 32768 <= big <= FP16_MAX
    tiny = np.abs(w.w2[w.w2 != 0])
    assert tiny.size > 0.9 * w.w2.size and (tiny < 6.1e-5).all()  # subnormal, and not flushed to zero
    rep = V.verify(out, runtime=gl_runtime)
    m = rep.materials[0]
    assert rep.exit_code == 0, [c.to_dict() for c in m.checks]
    print(f"\n[{part} near overflow, max {big:g}] max |GL - ONNX| {max(ch['max_abs'] for ch in m.channels):.3g}")


def test_fp16_balance_keeps_the_function_and_leaves_fitting_records_alone():
    rng = np.random.default_rng(0)
    w = MlpWeights(rng.normal(size=(16, 12)).astype(np.float32), rng.normal(size=16).astype(np.float32),
                   rng.normal(size=(5, 16)).astype(np.float32), rng.normal(size=5).astype(np.float32),
                   np.ones(5, np.float32), np.zeros(5, np.float32)).to_fp16()
    assert to_bytes(balance_for_fp16(w)) == to_bytes(w) == to_bytes(w.to_fp16())
    feats = rng.random((1000, 12)).astype(np.float32)
    kinds = ("albedo",) * 5
    f, g = np.float32(2.0 ** 20), np.float32(2.0 ** 24)  # the same function, far beyond fp16
    blown = MlpWeights(w.w1 * f, w.b1 * f, w.w2 / f * g, w.b2 * g, w.out_scale / g, w.out_bias)
    fixed = blown.to_fp16()
    assert max(float(np.abs(a).max()) for a in fixed.arrays()) <= FP16_MAX
    assert np.abs(decode_numpy(fixed, feats, kinds) - decode_numpy(w, feats, kinds)).max() < 2e-3


def test_fp16_weights_that_cannot_fit_fail_training_clearly():
    w = MlpWeights(np.full((4, 12), 1e9, np.float32), np.zeros(4, np.float32), np.full((2, 4), 1e9, np.float32),
                   np.zeros(2, np.float32), np.ones(2, np.float32), np.zeros(2, np.float32))
    with pytest.raises(FloatingPointError, match="beyond fp16"):
        w.to_fp16()


def test_a_record_with_nan_or_inf_is_refused():
    w = MlpWeights(np.zeros((4, 12), np.float32), np.zeros(4, np.float32), np.zeros((2, 4), np.float32),
                   np.zeros(2, np.float32), np.ones(2, np.float32), np.zeros(2, np.float32))
    data = bytearray(to_bytes(w))
    data[24:26] = np.float16(np.inf).tobytes()
    with pytest.raises(ValueError, match="NaN or infinite"):
        from_bytes(bytes(data))
