"""Model internals against the exported files: per-tap vs whole-level decode, DDS round trip
through the sampler, ONNX vs torch, and the fp16 weight record."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from bcfpipe.export import writer as E
from bcfpipe.model import neural as M
from bcfpipe.bc6h import emulate
from bcfpipe.config import ModelConfig, TrainConfig
from bcfpipe.resources import SCHEMA_DIR
from bcfpipe.model.decoder import MlpWeights, decode_numpy, from_bytes, mlp_raw, postprocess, to_bytes
from bcfpipe.texset.texture_set import Channel, TextureSet
from bcfpipe.model.features import Layers
from bcfpipe.train.trainer import BlockLevel, TrainedMaterial, exact_level
from bcfpipe.formats.vocabulary import T0, FeatureFormat

MC = ModelConfig(features=FeatureFormat.BC6H, resolutions=(32, 16, 8, 4))


def _random_blocks(mc, seed=0, signed=False):
    rng = np.random.default_rng(seed)
    lo, hi = (-32, 31) if signed else (0, 63)
    layers = []
    for res, n in zip(mc.resolutions, mc.mip_counts):
        layer = []
        for k in range(n):
            r = max(4, res >> k)
            nb = (r // 4) ** 2
            layer.append(BlockLevel(rng.integers(lo, hi + 1, (nb, 4, 3)), rng.integers(0, 8, (nb, 16)),
                                    rng.integers(0, 32, nb), r))
        layers.append(layer)
    return layers


def _channels():
    return (Channel("albedo", "r", "color", "a.png", 0), Channel("albedo", "g", "color", "a.png", 1),
            Channel("albedo", "b", "color", "a.png", 2), Channel("normal", "x", "normal", "n.png", 0),
            Channel("normal", "y", "normal", "n.png", 1), Channel("roughness", "g", "scalar", "arm.png", 1))


def _weights(seed=0, c=6, hidden=16):
    rng = np.random.default_rng(seed)
    return MlpWeights(rng.normal(0, 0.5, (hidden, 12)).astype(np.float32), rng.normal(0, 0.1, hidden).astype(np.float32),
                      rng.normal(0, 0.3, (c, hidden)).astype(np.float32), rng.normal(0, 0.1, c).astype(np.float32),
                      np.ones(c, np.float32), rng.uniform(0, 0.5, c).astype(np.float32)).to_fp16()


def _trained(mc, signed=False, seed=0):
    mc = ModelConfig(features=FeatureFormat.BC6H, resolutions=mc.resolutions, signed=signed, wrap=mc.wrap)
    ch = _channels()
    ts = TextureSet(np.zeros((64, 64, len(ch)), np.float32), ch, 64, 64)
    return TrainedMaterial(TrainConfig(model=mc), ts, Layers.of(_random_blocks(mc, seed, signed)), _weights(seed),
                           M.lod_biases(mc.resolutions, 64, 64), {"warmup": 0.0})


def _torch_blocks(layers, requires_grad=False):
    out = []
    for layer in layers:
        mips = []
        for bl in layer:
            e, x, mask, _ = emulate.from_params(bl.endpoints, bl.indices, bl.partition)
            mips.append(M.BlockParams(e.requires_grad_(requires_grad), x.requires_grad_(requires_grad), mask,
                                      bl.partition))
        out.append(mips)
    return Layers.of(out)


@pytest.mark.parametrize("signed", [False, True])
def test_tap_decode_equals_level_decode(signed):
    mc = ModelConfig(features=FeatureFormat.BC6H, resolutions=MC.resolutions, signed=signed)
    blocks = _torch_blocks(_random_blocks(mc, 3, signed))
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():  # continuous parameters too, not only quantized ones
        for layer in blocks:
            for b in layer:
                b.endpoints += torch.rand(b.endpoints.shape, generator=g) * 0.9
                b.x.copy_(torch.rand(b.x.shape, generator=g))
    uv = torch.rand((2000, 2), generator=g) * 1.4 - 0.2
    biases = M.lod_biases(mc.resolutions, 64, 64)
    for s in (0.0, 0.4, 1.0, 2.6, 5.0):
        a = M.sample_features(M.block_level_fn(blocks, mc), mc.mip_counts, biases, uv, s, "repeat")
        b = M.sample_features_taps(M.block_tap_fn(blocks, mc), M.level_sizes(mc), biases, uv, s, "repeat")
        assert torch.equal(a, b)
    free = Layers.of(M.init_free(mc, g, torch.device("cpu")))
    a = M.sample_features(M.free_level_fn(free, mc), mc.mip_counts, biases, uv, 1.3, "clamp")
    b = M.sample_features_taps(M.free_tap_fn(free, mc), M.level_sizes(mc), biases, uv, 1.3, "clamp")
    assert torch.equal(a, b)


@pytest.mark.parametrize("signed", [False, True])
def test_constrained_forward_equals_exported_dds(tmp_path, signed):
    """The training-time BC6H emulation + sampler == bcfpipe.bc6h.decode of the written DDS + sampler."""
    tm = _trained(MC, signed=signed, seed=5)
    E.export(tm, tmp_path)
    em = E.load(tmp_path)
    mc = tm.config.model
    blocks = _torch_blocks(tm.layers)
    g = torch.Generator().manual_seed(1)
    uv = torch.rand((3000, 2), generator=g) * 2 - 0.5
    s = torch.rand(3000, generator=g) * 9 - 2  # magnification, fractional, beyond the last mip
    with torch.no_grad():
        ours = M.sample_features(M.block_level_fn(blocks, mc, quantized=True), mc.mip_counts, tm.lod_biases, uv, s,
                                 mc.wrap)
    exported = E.sample_exported_features(em, uv.numpy(), s.numpy())
    np.testing.assert_array_equal(ours.numpy(), exported)
    for i, layer in enumerate(tm.layers):  # and level by level, bit for bit
        for k, bl in enumerate(layer):
            np.testing.assert_array_equal(exact_level(bl, mc, "cpu").permute(1, 2, 0).numpy(), em.levels[i][k])


def test_onnx_matches_torch_fp16_model(tmp_path):
    ort = pytest.importorskip("onnxruntime")
    tm = _trained(MC, seed=2)
    E.export(tm, tmp_path)
    em = E.load(tmp_path)
    sess = ort.InferenceSession(str(em.onnx_path), providers=["CPUExecutionProvider"])
    feats = np.random.default_rng(0).uniform(0, 2, (5000, 12)).astype(np.float32)
    onnx_out = sess.run(["channels"], {"features": feats})[0]
    w = tm.mlp
    params = {k: torch.from_numpy(v) for k, v in zip(("w1", "b1", "w2", "b2"), w.arrays())}
    torch_out = postprocess(mlp_raw(params, torch.from_numpy(feats)), torch.from_numpy(w.out_scale),
                            torch.from_numpy(w.out_bias), tm.kinds).numpy()
    assert onnx_out.shape == (5000, 7)  # 6 channels + reconstructed normal z
    assert np.abs(onnx_out - torch_out).max() <= 1e-3
    assert np.abs(onnx_out - decode_numpy(em.weights, feats, em.kinds)).max() <= 1e-4  # fp32 summation order
    z = onnx_out[:, 5]
    np.testing.assert_allclose(z, np.sqrt(np.clip(1 - onnx_out[:, 3] ** 2 - onnx_out[:, 4] ** 2, 0, None)), atol=1e-6)
    assert onnx_out[:, :3].min() >= 0 and onnx_out[:, :3].max() <= 1 and onnx_out[:, 3:5].min() >= -1


def test_weight_record_round_trip_and_errors():
    w = _weights(4, c=5, hidden=24)
    data = to_bytes(w)
    assert data[:4] == b"BCFW" and len(data) % 4 == 0
    back, size = from_bytes(b"\0" * 8 + data, 8)
    assert size == len(data)
    for a, b in zip(w.arrays(), back.arrays()):
        np.testing.assert_array_equal(a, b)  # already fp16-representable: exact
    with pytest.raises(ValueError, match="truncated"):
        from_bytes(data[:-4])
    with pytest.raises(ValueError, match="BCFW"):
        from_bytes(b"XXXX" + data[4:])


def test_description_is_self_contained(tmp_path):
    """material.json says everything a consumer needs, and passes the published schema."""
    import json

    import jsonschema

    tm = _trained(MC)
    E.export(tm, tmp_path)
    d = json.loads((tmp_path / "material.json").read_text())
    assert [l["file"] for l in d["layers"]] == ["T0.dds", "T1.dds", "T2.dds", "T3.dds"]
    assert [l["mip_count"] for l in d["layers"]] == list(MC.mip_counts)
    assert d["layers"][0]["lod_bias"] == -1.0 and d["bc6h"]["dxgi_format"] == 95
    assert [o["usd_target"] for o in d["outputs"]] == ["diffuseColor.r", "diffuseColor.g", "diffuseColor.b",
                                                       "normal.x", "normal.y", "normal.z", "roughness"]
    assert d["onnx"]["input"] == "features" and d["mlp"]["n_in"] == 12 and d["sampling"]["addressing"] == "repeat"
    jsonschema.validate(d, json.loads((SCHEMA_DIR / "material.schema.json").read_text()))


@pytest.mark.parametrize("profile, ref", [("0.5k", 2048), ("1k", 2048), ("2k", 2048), ("2k++", 2048),
                                          ("tiny", 64), ("1k", 1024)])
def test_lod_biases_span_the_reference_lod_range(profile, ref):
    """T_0 keeps the texel density of the reference; the coarsest layer's last mip is reached at the
    reference's last lod, so some layer still changes with s all the way to the 1x1 mip."""
    from bcfpipe.config import PROFILES, mip_count

    res = PROFILES[profile]
    b = M.lod_biases(res, ref, ref)
    natural = [np.log2(r / ref) for r in res]
    assert b[0] == natural[0]
    assert all(bi <= ni for bi, ni in zip(b, natural))
    last = [mip_count(r) - 1 - bi for r, bi in zip(res, b)]  # s at which layer i reaches its 4x4 mip
    assert max(last) == np.log2(ref)
    assert last == sorted(last)


def test_hdr_record_version_2_and_its_expansion_in_torch_and_onnx():
    """A record with log gains (HDR channels) is version 2; torch and onnxruntime expand the same
    channels the same way, and leave the linear ones (g = 0) untouched."""
    ort = pytest.importorskip("onnxruntime")
    from dataclasses import replace

    from bcfpipe.model.decoder import to_onnx
    from bcfpipe.texset import encoding

    base = _weights(7, c=3, hidden=16)
    assert to_bytes(base)[4] == 1 and base.version == 1
    w = replace(base, log_gain=np.array([11.546875, 0.0, 3.0], np.float32))
    data = to_bytes(w)
    n_halves = int(np.frombuffer(data, "<u4", 1, 20)[0])
    assert data[4] == 2 and n_halves == int(np.frombuffer(to_bytes(base), "<u4", 1, 20)[0]) + 3
    back, _ = from_bytes(data)
    np.testing.assert_array_equal(back.log_gain, w.log_gain)
    kinds = ("color",) * 3
    feats = np.random.default_rng(1).uniform(0, 2, (4000, 12)).astype(np.float32)
    sess = ort.InferenceSession(to_onnx(w, kinds).SerializeToString(), providers=["CPUExecutionProvider"])
    onnx_out = sess.run(["channels"], {"features": feats})[0]
    linear = decode_numpy(base, feats, kinds)
    ours = decode_numpy(w, feats, kinds)
    np.testing.assert_array_equal(ours[:, 1], linear[:, 1])
    for c in (0, 2):
        np.testing.assert_allclose(ours[:, c], encoding.decode(linear[:, c], float(w.log_gain[c])), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(onnx_out, ours, rtol=1e-5, atol=1e-6)


def test_bc7_constrained_forward_equals_exported_dds_and_onnx(tmp_path):
    """--features bc7: the training-time BC7 emulation (quantization-aware) + sampler == the written
    DDS decoded by bcfpipe.bc7 + sampler, bit for bit, level by level; ONNX takes the 16 features."""
    from bcfpipe.bc7.encode import quantize_endpoints
    from bcfpipe.formats.vocabulary import FeatureFormat
    from bcfpipe.model.features import codec_of

    mc = ModelConfig(resolutions=MC.resolutions, features=FeatureFormat.BC7)
    rng = np.random.default_rng(7)
    codec = codec_of(mc)
    blocks, layers = [], []
    for res, n in zip(mc.resolutions, mc.mip_counts):
        bl_layer, q_layer = [], []
        for k in range(n):
            r = max(4, res >> k)
            nb = (r // 4) ** 2
            e = torch.as_tensor(rng.uniform(0, 255, (nb, 2, 4)), dtype=torch.float32)
            x = torch.as_tensor(rng.uniform(0, 1, (nb, 16)), dtype=torch.float32)
            b = M.BlockParams(e, x)
            bl_layer.append(b)
            q_layer.append(codec.quantize(b, mc, r))
        blocks.append(bl_layer)
        layers.append(q_layer)
    assert (layers[0][0].endpoints == quantize_endpoints(blocks[0][0].endpoints.numpy())).all()
    ch = _channels()
    ts = TextureSet(np.zeros((64, 64, len(ch)), np.float32), ch, 64, 64)
    w = _weights(3)
    rng2 = np.random.default_rng(4)
    w = MlpWeights(rng2.normal(0, 0.5, (16, 16)).astype(np.float32), w.b1, w.w2, w.b2, w.out_scale, w.out_bias).to_fp16()
    tm = TrainedMaterial(TrainConfig(model=mc, t0=T0.TRAINED), ts, Layers.of(layers), w, M.lod_biases(mc.resolutions, 64, 64),
                         {"warmup": 0.0})
    E.export(tm, tmp_path)
    em = E.load(tmp_path)
    assert em.desc.features == "bc7" and em.desc.mlp.n_in == 16
    g = torch.Generator().manual_seed(1)
    uv = torch.rand((3000, 2), generator=g) * 2 - 0.5
    s = torch.rand(3000, generator=g) * 9 - 2
    with torch.no_grad():
        ours = M.sample_features(M.block_level_fn(Layers.of(blocks), mc, quantized=True), mc.mip_counts, tm.lod_biases,
                                 uv, s, mc.wrap)
    exported = E.sample_exported_features(em, uv.numpy(), s.numpy())
    np.testing.assert_array_equal(ours.numpy(), exported)
    for i, layer in enumerate(tm.layers):
        for k, bl in enumerate(layer):
            np.testing.assert_array_equal(exact_level(bl, mc, "cpu").permute(1, 2, 0).numpy(), em.levels[i][k])
    onnx_out = E.onnx_session(em).run(None, {"features": exported[:50].astype(np.float32)})[0]
    assert onnx_out.shape[0] == 50 and np.isfinite(onnx_out).all()
