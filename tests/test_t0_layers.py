"""A T_0 of one to three layers of principal components (issue 52, ModelConfig.t0_layers): fixed as
the one-layer T_0 is, T_1..T_3 and the MLP trained around it. The fused kernel samples any number of
layers as the torch path does; the export names the layers T0, T0b, T0c, T1..T3 in material.json
(format 6); and the files decode, rebuilt from material.json alone (OpenImageIO and onnxruntime), to
what bcfpipe's own decode gives. The rebuild (`rebuild_at`) addresses each axis as material.json's
sampling says (repeat, clamp or mirror, in the GL spec's words); tests/test_wrap.py runs it at and
beyond the borders."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from bcfpipe.config import PRESETS, PROFILES, ModelConfig, TrainConfig
from bcfpipe.errors import InputError
from bcfpipe.export import writer as E
from bcfpipe.formats import material as mf
from bcfpipe.formats.vocabulary import T0, FeatureFormat, Kernel
from bcfpipe.model import neural as M
from bcfpipe.model.features import Layers, codec_of
from bcfpipe.texset.texture_set import build_mip_chain, load_texture_set

SRC = Path(__file__).resolve().parents[1] / "samples" / "textures"
# the bricks (albedo rgb, normal xy, roughness, height) and the tiles' ORM as generic channels: 10
SPECS = [f"albedo={SRC / 'bricks_albedo.png'}:rgb", f"normal={SRC / 'bricks_normal.png'}:rg",
         f"roughness={SRC / 'bricks_roughness.png'}:r", f"height={SRC / 'bricks_height.png'}:r",
         f"generic={SRC / 'tiles_orm.png'}:rgb"]
REBUILD_TOL = 1e-5  # onnxruntime outputs, [0, 1]-ranged, features sampled in float64 here, float32 there (measured: 2.4e-7)


def _config(k: int, kernel: Kernel = Kernel.FUSED, t0: T0 = T0.PCA) -> TrainConfig:
    mc = ModelConfig(resolutions=PROFILES["tiny"], features=FeatureFormat.BC7, t0_layers=k)
    return TrainConfig(model=mc, preset=PRESETS["smoke"], preset_name="smoke", t0=t0, kernel=kernel)


@pytest.fixture(scope="module")
def ts():
    return load_texture_set(SPECS, resolution=64)


@pytest.fixture(scope="module")
def trained(ts, tmp_path_factory):
    """k = 2 and 3, trained at tiny / smoke and exported (a few seconds each)."""
    from bcfpipe.export.material import train_material

    out = {}
    for k in (2, 3):
        folder = tmp_path_factory.mktemp(f"t0x{k}")
        res, tm = train_material(ts, folder, _config(k))
        out[k] = (folder, res, tm)
    return out


def test_model_layers_are_t0s_then_the_profiles():
    mc = ModelConfig(resolutions=(1024, 512, 256, 128), features=FeatureFormat.BC7, t0_layers=3)
    assert mc.layer_resolutions == (1024, 1024, 1024, 512, 256, 128) and mc.n_layers == 6 and mc.n_inputs == 24
    assert mc.mip_counts == (9, 9, 9, 8, 7, 6)
    assert M.layer_lod_biases(mc, 2048, 2048)[:3] == (M.lod_biases(mc.resolutions, 2048, 2048)[0],) * 3
    one = ModelConfig(resolutions=(1024, 512, 256, 128), features=FeatureFormat.BC7)
    assert one.n_inputs == 16 and one.layer_resolutions == one.resolutions
    assert [mf.layer_file(i) for i in range(4)] == ["T0.dds", "T1.dds", "T2.dds", "T3.dds"]
    assert [mf.layer_name(i, 3) for i in range(6)] == ["T0", "T0b", "T0c", "T1", "T2", "T3"]
    with pytest.raises(ValueError, match="t0_layers must be 1..3"):
        ModelConfig(t0_layers=4)


def test_files_and_material_json_list_every_layer_in_input_order(trained):
    for k, (folder, res, tm) in trained.items():
        desc = mf.read(folder)
        names = ["T0", "T0b", "T0c"][:k] + ["T1", "T2", "T3"]
        assert [layer.file for layer in desc.layers] == [f"{n}.dds" for n in names]
        assert desc.format_version == mf.MANY_LAYERS_VERSION == 6  # its addressing is one mode (repeat)
        assert desc.mlp.n_in == 4 * (k + 3) and desc.mlp.input_order == tuple(f"{n}.{c}" for n in names for c in "rgba")
        t0 = desc.layers[:k]
        assert {(layer.resolution, layer.mip_count, layer.lod_bias) for layer in t0} == {
            (desc.layers[0].resolution, desc.layers[0].mip_count, desc.layers[0].lod_bias)}
        assert all(layer.blocks == mf.ANY_BC7_MODE for layer in t0)
        assert all(layer.blocks is None for layer in desc.layers[k:])
        assert sorted(p.name for p in folder.iterdir()) == sorted(desc.files + [mf.FILE])
        import onnx

        dims = onnx.load(str(folder / desc.onnx.file)).graph.input[0].type.tensor_type.shape.dim
        assert dims[1].dim_value == 4 * (k + 3)
        assert res.metrics.psnr > 20


def test_the_fixed_layers_hold_successive_components(trained, ts):
    """Layer j's level 0 is components 4j..4j+3 of the set, up to BC7 and the affine map onto [0, 1]."""
    from bcfpipe.train.feature_init import principal_axes

    folder, _, tm = trained[3]
    ref = [torch.as_tensor(np.moveaxis(m, -1, 0)) for m in build_mip_chain(ts.data)]
    mean, axes = principal_axes(ref)
    comps = torch.einsum("chw,jc->jhw", ref[0] - mean[:, None, None], axes)  # T_0 is 64², the set 64²
    em = E.load(folder)
    for j in range(3):
        level = em.levels[j][0]
        for c in range(min(4, ts.num_channels - 4 * j)):
            r = np.corrcoef(level[..., c].ravel(), comps[4 * j + c].numpy().ravel())[0, 1]
            assert r > 0.9, (j, c, r)
    # past the 10 components a constant (BC7 moves it by a few codes), not the random start's 36 codes of noise
    assert np.ptp(em.levels[2][0][..., 2:]) < 12 / 255


def texel_index(i: np.ndarray, n: int, mode: str) -> np.ndarray:
    """Texel i of n along one axis, in the GL spec's words (OpenGL 4.5 §8.14.2): REPEAT i mod n,
    CLAMP_TO_EDGE clamp(i, 0, n - 1), MIRRORED_REPEAT (n - 1) - mirror((i mod 2n) - n), where
    mirror(a) = a if a >= 0 else -(1 + a)."""
    if mode == "repeat":
        return np.mod(i, n)
    if mode == "mirror":
        a = np.mod(i, 2 * n) - n
        return (n - 1) - np.where(a >= 0, a, -(1 + a))
    assert mode == "clamp", mode
    return np.clip(i, 0, n - 1)


def bilinear(img: np.ndarray, uv: np.ndarray, wrap: tuple[str, str] = ("repeat", "repeat")) -> np.ndarray:
    """(h, w, c) sampled at uv, texel centres at (i + 0.5) / size, u addressed with wrap[0] (S) and
    v with wrap[1] (T)."""
    h, w = img.shape[:2]
    x, y = uv[:, 0] * w - 0.5, uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    xa, xb = texel_index(x0, w, wrap[0]), texel_index(x0 + 1, w, wrap[0])
    ya, yb = texel_index(y0, h, wrap[1]), texel_index(y0 + 1, h, wrap[1])
    top = img[ya, xa] * (1 - fx) + img[ya, xb] * fx
    return top * (1 - fy) + (img[yb, xa] * (1 - fx) + img[yb, xb] * fx) * fy


def sampling_axes(d: dict) -> tuple[str, str]:
    """(S, T) addressing of a material.json: ``addressing`` for both axes, or wrap_s / wrap_t (version 7)."""
    s = d["sampling"]
    return (s["addressing"],) * 2 if "addressing" in s else (s["wrap_s"], s["wrap_t"])


def _oiio_levels(path: Path, channels: int) -> list[np.ndarray]:
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    out, m = [], 0
    while inp.seek_subimage(0, m):
        out.append(inp.read_image(0, m, 0, channels, oiio.UINT8).astype(np.float64) / 255.0)
        m += 1
    inp.close()
    return out


def rebuild_at(folder: Path, uv: np.ndarray, s: float) -> np.ndarray:
    """The decoder's outputs (N, n_out) at ``uv`` (N, 2) and lod ``s`` from material.json alone: each
    layer's DDS through OpenImageIO, sampled trilinearly at s + lod_bias (lod clamped to its mips)
    with material.json's addressing per axis, in the order material.json lists them, into onnxruntime."""
    import onnxruntime as ort

    d = json.loads((folder / "material.json").read_text())
    wrap = sampling_axes(d)
    feats = []
    for layer in d["layers"]:
        levels = _oiio_levels(folder / layer["file"], layer["channels"])
        assert len(levels) == layer["mip_count"]
        lod = min(max(s + layer["lod_bias"], 0.0), len(levels) - 1)
        lo, t = int(np.floor(lod)), lod - np.floor(lod)
        f = bilinear(levels[lo], uv, wrap)
        if t > 0:
            f = f + (bilinear(levels[lo + 1], uv, wrap) - f) * t
        feats.append(f)
    x = np.concatenate(feats, 1).astype(np.float32)
    assert x.shape[1] == d["mlp"]["n_in"]
    sess = ort.InferenceSession(str(folder / d["onnx"]["file"]), providers=["CPUExecutionProvider"])
    return sess.run([d["onnx"]["output"]], {d["onnx"]["input"]: x})[0]


def _rebuild(folder: Path, mip: int) -> np.ndarray:
    """Every output at reference mip ``mip``'s texel centres (`rebuild_at`), as (h, w, n_out)."""
    d = json.loads((folder / "material.json").read_text())
    w, h = d["reference"]["width"] >> mip, d["reference"]["height"] >> mip
    ids = np.arange(w * h)
    uv = np.stack([(ids % w + 0.5) / w, (ids // w + 0.5) / h], 1)
    return rebuild_at(folder, uv, float(mip)).reshape(h, w, -1)


@pytest.mark.parametrize("k", [2, 3])
def test_an_independent_rebuild_from_material_json_matches_bcfpipes_decode(trained, k):
    folder = trained[k][0]
    em = E.load(folder)
    shapes = [(64 >> m, 64 >> m) for m in range(4)]
    ours = E.decode_mips(em, shapes, drop_normal_z=False)
    for m in range(4):
        err = float(np.abs(_rebuild(folder, m) - ours[m]).max())
        assert err <= REBUILD_TOL, (k, m, err)


def test_fused_and_torch_sample_three_fixed_layers_alike():
    """The fused step's features of a 6-layer model (3 fixed) are the torch path's, bit for bit, and
    its loss and gradients agree; the fixed layers get none."""
    from bcfpipe.train.fixed_t0 import encoded_levels
    from bcfpipe.train.fused.step import FusedStep

    mc = ModelConfig(resolutions=(32, 16, 8, 4), features=FeatureFormat.BC7, t0_layers=3)
    gen = torch.Generator().manual_seed(0)
    free = M.init_free(mc, gen, "cpu")
    codec = codec_of(mc)
    rng = np.random.default_rng(0)
    fixed = {j: encoded_levels([rng.random((32 >> k, 32 >> k, 4)).astype(np.float32) for k in range(len(free[j]))])
             for j in range(3)}
    with torch.no_grad():
        blocks = [[codec.encode(codec.value(p, mc).permute(1, 2, 0).numpy(), mc, "cpu") for p in mips]
                  for mips in free]
    levels = Layers.of(blocks, fixed)
    mlp = M.init_mlp(mc.n_inputs, 16, 5, gen, "cpu", torch.rand(5, generator=gen))
    biases = M.layer_lod_biases(mc, 64, 64)
    for backend in ("native", "numba"):
        fs = FusedStep(mc, biases, mlp, levels, lambda: False, backend=backend)
        assert fs.fixed == {(j, k) for j in range(3) for k in range(len(free[j]))}
        for s in (0.0, 0.6, 2.5, 5.0):
            uv = torch.rand((512, 2), generator=gen) * 3 - 1
            with torch.no_grad():
                ref = M.sample_features(M.block_level_fn(levels, mc), mc.mip_counts, biases, uv, s, mc.wrap)
            assert ref.shape == (512, 24)
            assert torch.equal(fs.features(uv, s).view(torch.int32), ref.view(torch.int32)), (backend, s)
            target = torch.rand((512, 5), generator=gen)
            params = [t for b in levels.trained_levels() for t in (b.endpoints, b.x)] + [mlp["w1"]]
            for p in params:
                p.grad = None
            pred = M.mlp_raw(mlp, M.sample_features(M.block_level_fn(levels, mc), mc.mip_counts, biases, uv, s,
                                                    mc.wrap)) * mlp["out_scale"] + mlp["out_bias"]
            loss = torch.mean((pred - target) ** 2)
            loss.backward()
            want = {id(p): None if p.grad is None else p.grad.clone() for p in params}
            for p in params:
                p.grad = None
            assert fs(uv, target, None, s) == pytest.approx(float(loss.detach()), rel=1e-5)
            for p in params:
                r = want[id(p)]
                assert (p.grad is None) == (r is None)
                if r is not None:
                    assert float((p.grad - r).abs().max()) <= 1e-5 * max(float(r.abs().max()), 1e-30), (backend, s)


def test_a_layer_past_the_sets_components_is_refused_in_one_line():
    from bcfpipe.train.trainer import train

    four = load_texture_set([SPECS[0], SPECS[2]], resolution=64)  # 4 channels: a second layer holds nothing
    with pytest.raises(InputError) as e:
        train(four, _config(2))
    assert "needs at least 5 channels" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(InputError, match="--t0 pca"):
        train(four, _config(2, t0=T0.TRAINED))


def test_torch_kernel_trains_a_two_layer_t0(ts, tmp_path):
    from bcfpipe.export.material import FIGURES, train_material

    res, tm = train_material(ts, tmp_path / "m", _config(2, Kernel.TORCH), measure=FIGURES)
    assert sorted(tm.layers.fixed) == [0, 1] and res.metrics.psnr > 20


def test_a_build_counts_every_feature_layer(tmp_path) -> None:
    """The manifest's features_bytes counts T0b.dds and T0c.dds too, not T0..T3 alone."""
    from bcfpipe.builder.assemble import _features_bytes

    sizes = {"T0.dds": 10, "T0b.dds": 20, "T0c.dds": 40, "T1.dds": 80, "T2.dds": 160, "T3.dds": 320, "C0.dds": 640}
    for name, n in sizes.items():
        (tmp_path / name).write_bytes(b"x" * n)
    assert _features_bytes(tmp_path) == 630
