"""Materials with 4 to 6 feature layers (a T_0 of one to three fixed layers, issue 52) through the
consumers that read them: the GLSL decoder (BCF_N_LAYERS), verify, the renderer's surfaces, the USD
layer and the BcfNeuralMaterial Sdr node.

The 5- and 6-layer materials are made without training: a 4-layer BC7 material (the exporter's own
files) gets copies of T0 as T0b, T0c, whose W1 columns are zero (weights.bin, decoder.onnx and
material.json rewritten together), so every decoder must give the 4-layer decode: the CPU features
exactly, ONNX and GLSL to fp32 rounding (a GLSL compiler may reassociate the longer sums; Mesa's NIR
does)."""
from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bcfpipe.formats import material as mf
from bcfpipe.formats.digest import sha256_file
from bcfpipe.formats.atomic import atomic_write
from bcfpipe.model.decoder import from_bytes, to_bytes, to_onnx
from bcfpipe.verify import glsl as G

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_glsl import ES_HEADER, validate_texels  # noqa: E402

EXTRA_NAMES = ("T0b", "T0c")  # formats.material.layer_name's names of T_0's second and third layers


def make_bc7_material(folder: Path, seed: int = 3) -> Path:
    """A 4-layer BC7 material written by bcfpipe's exporter: random mode-6 blocks, a random fp16
    decoder (6 outputs with a normal map), the sample set's lod biases for a 64² reference."""
    import torch

    from bcfpipe.config import ModelConfig, TrainConfig
    from bcfpipe.export import writer as E
    from bcfpipe.formats.vocabulary import T0, FeatureFormat
    from bcfpipe.model import neural as M
    from bcfpipe.model.decoder import MlpWeights
    from bcfpipe.model.features import Layers, codec_of
    from bcfpipe.texset.texture_set import Channel, TextureSet
    from bcfpipe.train.trainer import TrainedMaterial

    mc = ModelConfig(resolutions=(32, 16, 8, 4), features=FeatureFormat.BC7)
    rng = np.random.default_rng(seed)
    codec, layers = codec_of(mc), []
    for res, n in zip(mc.resolutions, mc.mip_counts):
        layer = []
        for k in range(n):
            r = max(4, res >> k)
            nb = (r // 4) ** 2
            b = M.BlockParams(torch.as_tensor(rng.uniform(0, 255, (nb, 2, 4)), dtype=torch.float32),
                              torch.as_tensor(rng.uniform(0, 1, (nb, 16)), dtype=torch.float32))
            layer.append(codec.quantize(b, mc, r))
        layers.append(layer)
    ch = (Channel("albedo", "r", "color", "a.png", 0), Channel("albedo", "g", "color", "a.png", 1),
          Channel("albedo", "b", "color", "a.png", 2), Channel("normal", "x", "normal", "n.png", 0),
          Channel("normal", "y", "normal", "n.png", 1), Channel("roughness", "g", "scalar", "r.png", 1))
    ts = TextureSet(np.zeros((64, 64, len(ch)), np.float32), ch, 64, 64)
    hidden, n_out = 16, len(ch)
    w = MlpWeights(rng.normal(0, 0.5, (hidden, 16)).astype(np.float32), rng.uniform(-0.3, 0.3, hidden).astype(np.float32),
                   rng.normal(0, 0.4, (n_out, hidden)).astype(np.float32), rng.uniform(-0.2, 0.2, n_out).astype(np.float32),
                   np.full(n_out, 0.8, np.float32), np.full(n_out, 0.1, np.float32)).to_fp16()
    tm = TrainedMaterial(TrainConfig(model=mc, t0=T0.TRAINED), ts, Layers.of(layers), w, M.lod_biases(mc.resolutions, 64, 64),
                         {"warmup": 0.0})
    return E.export(tm, folder)


def widen(src: Path, dst: Path, extra: int) -> Path:
    """``src`` (a BC7 material) with ``extra`` (1 or 2) copies of T0 inserted after it as T_0's
    further layers, their W1 columns zero: the same function of the same features."""
    desc = mf.read(src)
    shutil.copytree(src, dst)
    first, c = desc.layers[0], desc.layers[0].channels
    names = EXTRA_NAMES[:extra]
    for name in names:
        shutil.copyfile(src / first.file, dst / f"{name}.dds")
    w, _ = from_bytes((src / desc.mlp.weights).read_bytes(), desc.mlp.offset)
    w = dataclasses.replace(w, w1=np.insert(w.w1, [c] * (c * extra), 0.0, axis=1).astype(np.float32))
    record = to_bytes(w)
    atomic_write(dst / desc.mlp.weights, record)
    atomic_write(dst / desc.onnx.file, to_onnx(w, desc.kinds).SerializeToString())
    order = desc.mlp.input_order
    order = order[:c] + tuple(f"{n}.{x}" for n in names for x in "rgba"[:c]) + order[c:]
    mlp = dataclasses.replace(desc.mlp, size_bytes=len(record), n_in=w.dims[0], input_order=order)
    layers = (first, *(dataclasses.replace(first, file=f"{n}.dds") for n in names), *desc.layers[1:])
    desc = dataclasses.replace(desc, layers=layers, mlp=mlp, sha256=None)
    mf.write(dst, dataclasses.replace(desc, sha256={f: sha256_file(dst / f) for f in desc.files}))
    return dst


@pytest.fixture(scope="module")
def mats(tmp_path_factory) -> dict[int, Path]:
    root = tmp_path_factory.mktemp("many_layers")
    base = make_bc7_material(root / "4")
    return {4: base, 5: widen(base, root / "5", 1), 6: widen(base, root / "6", 2)}


@pytest.fixture(scope="module")
def rt():
    try:
        runtime = G.open_runtime()
    except G.GLUnavailable as e:
        pytest.skip(str(e))
    yield runtime
    runtime.release()


def test_widened_materials_read_back(mats):
    for n, folder in mats.items():
        desc = mf.read(folder)
        assert len(desc.layers) == n and desc.mlp.n_in == 4 * n == len(desc.mlp.input_order)
    assert [layer.file for layer in mf.read(mats[6]).layers] == ["T0.dds", "T0b.dds", "T0c.dds", "T1.dds",
                                                                 "T2.dds", "T3.dds"]


@pytest.mark.parametrize("n", [5, 6])
@pytest.mark.parametrize("stage", ["frag", "comp", "bcf_render.frag"])
def test_shaders_compile_for_more_layers(n, stage, tmp_path):
    defines = {"BCF_N_LAYERS": n, **({"BCF_NEURAL": 1} if stage == "bcf_render.frag" else {})}
    kind = "frag" if stage.endswith("frag") else "comp"
    validate_texels(G.assemble(stage, defines), kind, tmp_path)
    if stage != "bcf_render.frag":
        validate_texels(G.assemble(stage, defines, version=ES_HEADER), kind, tmp_path)


@pytest.mark.parametrize("n", [3, 7])
def test_other_layer_counts_do_not_compile(n, tmp_path):
    with pytest.raises(AssertionError, match="BCF_N_LAYERS must be 4, 5 or 6"):
        validate_texels(G.assemble("comp", {"BCF_N_LAYERS": n}), "comp", tmp_path)


def _decodes(rt, folder: Path, weights: bytes | None = None, desc_from: Path | None = None,
             fixed: bool = False) -> dict[str, np.ndarray]:
    """Every GL path at random points: lod queries, derivative queries, grids, the fragment shader;
    with ``fixed`` the compute shader compiled for the record's network shape too (``fixed``: the
    shape bcfpipe bench's decode cost compiles, `decode_cost._net`; on llvmpipe 10-15 s a compile)."""
    rng = np.random.default_rng(5)
    uv = rng.uniform(-2, 3, (4000, 2)).astype(np.float32)
    s = rng.uniform(-2, 9, 4000).astype(np.float32)
    dx, dy = (rng.normal(0, 1, (2, 4000, 2)) * np.exp2(rng.uniform(-10, 0, (2, 4000, 1)))).astype(np.float32)
    gm = rt.load(G.read_material(desc_from or folder, weights_file=folder / "weights.bin"), weights)
    try:
        m = gm.desc.file.mlp
        out = {"lod": rt.decode(gm, uv, s), "grad": rt.decode_grad(gm, uv, dx, dy),
               "grid": rt.decode_grid(gm, 40, 24, 1.25), "frag": rt.render_fullscreen(gm, 40, 24),
               "frag_lod": rt.render_fullscreen(gm, 40, 24, lod=2.5, view=2)}
        if fixed:
            out["fixed"] = rt.decode(gm, uv, s, defines={"BCF_N_HIDDEN": m.n_hidden, "BCF_N_OUT": m.n_out,
                                                          "BCF_MAX_OUT": gm.desc.c_out})
        return out
    finally:
        rt.unload(gm)


FP32_SUMS = 2e-5  # (n_hidden + n_in) fp32 roundings of sums whose terms stay below ~4 here, twice


def test_glsl_decode_of_more_layers_equals_the_four_layer_one(mats, rt):
    """Every GL path of the 5- and 6-layer materials gives the 4-layer decode, to fp32 rounding:
    the extra samplers, lod biases and W1 columns are read where they belong. The compute shader
    compiled for the 6-layer record's shape (every BCF_N_LAYERS > 4 and > 5 line) gives it too."""
    base = _decodes(rt, mats[4])
    assert all(np.isfinite(v).all() for v in base.values())
    for n in (5, 6):
        got = _decodes(rt, mats[n], fixed=n == 6)
        if n == 6:
            np.testing.assert_allclose(got.pop("fixed"), base["lod"], rtol=0, atol=FP32_SUMS, err_msg="fixed shape")
        for k, v in base.items():
            np.testing.assert_allclose(got[k], v, rtol=0, atol=FP32_SUMS, err_msg=f"{n} layers, {k}")


def test_a_record_for_another_layer_count_is_rejected(mats, rt):
    """A shader compiled for the material's layer count refuses a record whose n_in is another's:
    NaN from the compute shader (also compiled for one network shape), magenta from the fragment
    shader."""
    six = (mats[6] / "weights.bin").read_bytes()
    four = (mats[4] / "weights.bin").read_bytes()
    for folder, weights in ((mats[4], six), (mats[6], four), (mats[5], six)):
        out = _decodes(rt, folder, weights, fixed=folder == mats[6])
        assert np.isnan(out["lod"]).all() and np.isnan(out["grad"]).all()
        assert folder != mats[6] or np.isnan(out["fixed"]).all()
        assert (out["frag"][..., :3] == (1.0, 0.0, 1.0)).all()


def test_onnx_and_cpu_features_of_more_layers(mats):
    """The CPU reference verify compares against: features sampled from every listed layer in order,
    and decoder.onnx, equal to the 4-layer material's."""
    from bcfpipe.export import writer as E

    rng = np.random.default_rng(2)
    uv = rng.uniform(-1, 2, (3000, 2)).astype(np.float32)
    s = rng.uniform(-1, 8, 3000).astype(np.float32)
    ems = {n: E.load(f) for n, f in mats.items()}
    feats = {n: E.sample_exported_features(em, uv, s) for n, em in ems.items()}
    outs = {n: E.onnx_session(em).run(None, {"features": feats[n]})[0] for n, em in ems.items()}
    for n in (5, 6):
        assert feats[n].shape == (3000, 4 * n)
        np.testing.assert_array_equal(np.delete(feats[n], np.s_[4:4 * (n - 3)], axis=1), feats[4])
        for k in range(1, n - 3):
            np.testing.assert_array_equal(feats[n][:, 4 * k:4 * k + 4], feats[4][:, :4])
        np.testing.assert_allclose(outs[n], outs[4], rtol=0, atol=1e-6)


@pytest.mark.parametrize("n", [5, 6])
def test_verify_passes_on_more_layers(mats, rt, n):
    from bcfpipe.verify import checks as V

    rep = V.verify(mats[n], runtime=rt)
    m = rep.materials[0]
    assert rep.exit_code == 0, [c.to_dict() for c in m.checks]
    assert {c.name: c.passed for c in m.checks} == {"files": True, "integrity": True, "weights": True,
                                                     "openimageio": True, "glsl": True}
    assert f"{n} " in next(c for c in m.checks if c.name == "files").detail


def _rewrite(folder: Path, w=None) -> None:
    """Write ``w`` (if given) as the record and decoder.onnx, and every file's SHA-256 anew."""
    desc = mf.read(folder)
    if w is not None:
        atomic_write(folder / "weights.bin", to_bytes(w))
        atomic_write(folder / "decoder.onnx", to_onnx(w, desc.kinds).SerializeToString())
    mf.write(folder, dataclasses.replace(desc, sha256={f: sha256_file(folder / f) for f in desc.files}))


def test_extra_layers_are_read_where_they_belong(mats, rt, tmp_path):
    """T0b with its own W1 columns and its own texels (T0's blocks in reverse order): the decode
    changes, and GL still agrees with ONNX (verify passes), so the shader samples T0b from layers[1]
    with its W1 columns 4..7; a changed byte of T0b then fails verify's integrity check."""
    from bcfpipe.formats import dds
    from bcfpipe.verify import checks as V

    folder = shutil.copytree(mats[5], tmp_path / "m")
    w, _ = from_bytes((folder / "weights.bin").read_bytes())
    w1 = w.w1.copy()
    w1[:, 4:8] = w.w1[:, :4]
    tex = dds.read(folder / "T0b.dds")
    dds.write(folder / "T0b.dds", [(np.ascontiguousarray(b.reshape(-1, 16)[::-1]), x, y) for b, x, y in tex.levels],
              dxgi_format=tex.dxgi_format)
    _rewrite(folder, dataclasses.replace(w, w1=w1))
    rep = V.verify(folder, runtime=rt)
    assert rep.exit_code == 0, [c.to_dict() for c in rep.materials[0].checks]
    base, changed = _decodes(rt, mats[5]), _decodes(rt, folder)
    assert np.abs(base["lod"] - changed["lod"]).max() > 0.05
    (folder / "T0b.dds").write_bytes((folder / "T0b.dds").read_bytes()[:-16] + bytes(16))
    rep = V.verify(folder, runtime=rt)
    assert rep.exit_code != 0
    assert {c.name: c.passed for c in rep.materials[0].checks}["integrity"] is False


def test_decode_cost_compiles_for_the_layer_count(mats, rt):
    """bcfpipe bench's decode-cost passes build their programs for the material's layer count."""
    from bcfpipe.bench import decode_cost as D

    desc = G.read_material(mats[6])
    assert D._net(desc)["BCF_N_LAYERS"] == 6 and "BCF_N_LAYERS" not in D._net(G.read_material(mats[4]))
    names, _ = D.upload_classic(rt, D.random_classic(desc), desc.wrap)
    try:
        for run in (D.measure, D.measure_compute):
            (c,) = run(rt, [desc], names, (32, 16), frames=2, warmup=1)
            assert c.neural_ms > 0 and c.classic_ms > 0
    finally:
        rt.delete_textures(names)


def test_usd_layer_and_sdr_node_take_extra_layers(mats, tmp_path):
    """A 6-layer material's override: inputs T0..T5 and lodBias0..5 on its BcfNeuralMaterial shader,
    which the Sdr node declares (UsdValidation finds no error), and the renderer reads all six."""
    p = subprocess.run([sys.executable, "-c", SDR_SIX, str(mats[6]), str(tmp_path)], capture_output=True, text=True,
                       timeout=300, cwd="/")
    assert p.returncode == 0, p.stderr[-3000:]
    r = json.loads(p.stdout.strip().splitlines()[-1])
    assert {f"T{i}" for i in range(6)} | {f"lodBias{i}" for i in range(6)} <= set(r["node_inputs"])
    assert sorted(r["authored"]) == sorted([f"T{i}" for i in range(6)] + [f"lodBias{i}" for i in range(6)])
    assert r["errors"] == [], r["errors"]
    desc = mf.read(mats[6])
    assert r["textures"] == [str(mats[6] / layer.file) for layer in desc.layers]
    assert r["lod_biases"] == list(desc.lod_biases)


SDR_SIX = """
import json, sys
from pathlib import Path
from pxr import Sdf, Sdr, Usd, UsdGeom, UsdShade, UsdValidation
from bcfpipe.builder.usd_layer import NeuralMaterialOverride, write_overrides_layer
from bcfpipe.formats import material as mf, usd_schema
from bcfpipe.render import surfaces
folder, tmp = Path(sys.argv[1]), Path(sys.argv[2])
usd_schema.register()
usd_schema.register_shader_defs()
desc = mf.read(folder)
stage = Usd.Stage.CreateNew(str(tmp / "scene.usda"))
UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
UsdGeom.SetStageMetersPerUnit(stage, 1.0)
mat = UsdShade.Material.Define(stage, "/M")
stage.SetDefaultPrim(mat.GetPrim())
stage.Save()
ov = NeuralMaterialOverride(
    material="/M", feature_textures=tuple(str(folder / layer.file) for layer in desc.layers),
    feature_resolutions=tuple(layer.resolution for layer in desc.layers), feature_mip_counts=desc.mip_counts,
    feature_lod_biases=desc.lod_biases, feature_signed=False, wrap=desc.wrap, reference_resolution=(64, 64),
    st_primvar="st", st_scale=(1.0, 1.0), st_rotation=0.0, st_translation=(0.0, 0.0),
    weights=str(folder / "weights.bin"), weights_offset=0, weights_size=desc.mlp.size_bytes, weights_index=0,
    mlp=desc.mlp, decoder=str(folder / "decoder.onnx"), targets=("diffuseColor.r",), channels=(0,), scale=(1.0,),
    bias=(0.0,), color_spaces=("raw",), fallback_surface=None, version="test")
write_overrides_layer(tmp / "over.usda", [ov])
root = Usd.Stage.Open(str(tmp / "over.usda"))
root.GetRootLayer().subLayerPaths.append(str(tmp / "scene.usda"))
root.SetDefaultPrim(root.GetPrimAtPath("/M"))
UsdGeom.SetStageUpAxis(root, UsdGeom.Tokens.y)
UsdGeom.SetStageMetersPerUnit(root, 1.0)
sh = UsdShade.Shader(root.GetPrimAtPath("/M/BcfSurface"))
node = Sdr.Registry().GetShaderNodeByIdentifierAndType("BcfNeuralMaterial", "glsl")
validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
errors = [e.GetName() + ": " + e.GetMessage() for e in UsdValidation.ValidationContext(validators).Validate(root)
          if e.GetType() == UsdValidation.ValidationErrorType.Error]
names = [i.GetBaseName() for i in sh.GetInputs()]
s = surfaces.read_surface(root, "/M", True)
print(json.dumps({"node_inputs": list(node.GetShaderInputNames()), "errors": errors,
                  "authored": [x for x in names if x.startswith(("T", "lodBias"))],
                  "textures": list(s.neural.textures), "lod_biases": list(s.neural.lod_biases)}))
"""


TRAINED_SPECS = ("albedo={}/bricks_albedo.png:rgb", "normal={}/bricks_normal.png:rg",
                 "roughness={}/bricks_roughness.png:r", "height={}/bricks_height.png:r", "generic={}/tiles_orm.png:rgb")


@pytest.mark.parametrize("k", [2, 3])
def test_verify_passes_on_a_trained_t0_of_k_layers(rt, tmp_path, k):
    """A real material with a T_0 of k layers of principal components (10 channels, 64², tiny /
    smoke; ~2 s to train): 3 + k BC7 layers, and verify's every check passes on it."""
    from bcfpipe.config import PRESETS, PROFILES, ModelConfig, TrainConfig
    from bcfpipe.export.material import FIGURES, train_material
    from bcfpipe.formats.vocabulary import T0, FeatureFormat
    from bcfpipe.texset.texture_set import load_texture_set
    from bcfpipe.verify import checks as V

    src = Path(__file__).resolve().parents[1] / "samples" / "textures"
    ts = load_texture_set([s.format(src) for s in TRAINED_SPECS], resolution=64)
    mc = ModelConfig(resolutions=PROFILES["tiny"], features=FeatureFormat.BC7, t0_layers=k)
    train_material(ts, tmp_path, TrainConfig(model=mc, preset=PRESETS["smoke"], preset_name="smoke", t0=T0.PCA),
                 measure=FIGURES)
    desc = mf.read(tmp_path)
    assert len(desc.layers) == 3 + k and desc.mlp.n_in == 4 * (3 + k)
    rep = V.verify(tmp_path, runtime=rt)
    m = rep.materials[0]
    assert rep.exit_code == 0, [c.to_dict() for c in m.checks]
    assert all(c.passed for c in m.checks), [c.to_dict() for c in m.checks]
