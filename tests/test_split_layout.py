"""The mip-split layout (issue 31): BC@R's own levels below a reference mip, neural features from it
on. Features trained for s >= split only, the folder's material.json (format 4), its decode by
bcfpipe and by an independent reader (OpenImageIO, onnxruntime, the contract in the schema), and
verify's classic check."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from bcfpipe.config import TrainingOptions
from bcfpipe.formats.record import FormatError
from bcfpipe.export import writer as E
from bcfpipe.export.material import FIGURES, train_material, make_config
from bcfpipe.formats import material as mf
from bcfpipe.layout.classic import encode
from bcfpipe.layout.classic import split_levels
from bcfpipe.layout.export import export_split
from bcfpipe.texset.texture_set import build_mip_chain
from bcfpipe.train.trainer import StratifiedScale
from test_classic_layout import SCHEMA, _set, _trilinear, read_independently  # noqa: E402

SPLIT, R = 3, 32  # a 64² set: reference mips 64 .. 1, BC@R at 32², the features from mip 3 (8²)


def test_split_levels_count_the_bc_levels_below_the_split():
    assert split_levels(3, 1024, 2048) == 2  # mip 0 magnified from level 0, mips 1 and 2: levels 0 and 1
    assert split_levels(3, 1024, 1024) == 3
    assert split_levels(1, 1024, 2048) == 1
    assert split_levels(1, 512, 2048) == 1  # never fewer than one level


def test_a_split_model_draws_its_scales_from_the_split_on():
    s_max = 11.0
    for power in (1.0, 2.0):
        draw = StratifiedScale(s_max, torch.Generator().manual_seed(0), power=power, s_min=3.0)
        s = np.array([draw() for _ in range(512)])
        assert s.min() >= 3.0 and s.max() <= s_max
        # stratified over [3, 11] as the full draw is over [0, 11]: every sixteenth of u is visited
        u = ((s - 3.0) / (s_max - 3.0)) ** (1 / power)
        assert len(np.unique(np.floor(u * 16).astype(int))) == 16
    full = StratifiedScale(s_max, torch.Generator().manual_seed(0), power=2.0)
    same = StratifiedScale(s_max, torch.Generator().manual_seed(0), power=2.0, s_min=0.0)
    assert [full() for _ in range(40)] == [same() for _ in range(40)]  # s_min 0: today's draw, bit for bit


@pytest.fixture(scope="module")
def split(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("split")
    ts = _set()
    ref = build_mip_chain(ts.data)
    enc = encode(ts, R, ref)
    _, cfg = make_config(ts, TrainingOptions(profile="tiny", preset="smoke", device="cpu", threads=1))
    cfg = cfg.with_(model=replace(cfg.model, resolutions=(4, 4, 4, 4), split=SPLIT))
    res, _ = train_material(ts, tmp / "neural", cfg, "split", measure=FIGURES)
    out = export_split(enc, tmp / "neural", ts, tmp / "material", SPLIT, R)
    return ts, ref, enc, tmp / "neural", out, res


def test_split_material_json_says_both_sources_of_every_output(split):
    import jsonschema

    ts, ref, enc, _, out, _ = split
    d = json.loads((out / "material.json").read_text())
    jsonschema.validate(d, json.loads(SCHEMA.read_text()))
    assert d["format_version"] == 8 and d["split"] == SPLIT  # 8: its BC@R normal is stored as slopes (issue 57)
    assert [o.get("encoding") for o in d["outputs"] if o["semantic"] == "normal"] == ["slope"] * 3
    assert {o["source"] for o in d["outputs"]} == {"split"}
    keep = split_levels(SPLIT, R, 64)
    assert [c["mip_count"] for c in d["classic"]] == [keep] * len(enc) == [2, 2, 2]
    assert [c["lod_bias"] for c in d["classic"]] == [-1.0] * 3
    desc = mf.read(out)
    assert desc.mixed and desc.neural and len(desc.mlp_outputs) == len(desc.outputs)
    assert sorted(desc.files) == sorted(["T0.dds", "T1.dds", "T2.dds", "T3.dds", "weights.bin", "decoder.onnx",
                                         "C0.dds", "C1.dds", "C2.dds"])
    with pytest.raises(FormatError, match="split"):
        replace(desc, split=None)
    with pytest.raises(FormatError, match="split"):
        replace(desc, split=0)


def test_split_decodes_to_bc_below_the_split_and_to_the_model_from_it(split):
    """At the reference mips, the folder decodes exactly as BC@R's blocks below the split and as
    the neural model alone from it on: the figures of both parts carry over unchanged."""
    ts, ref, enc, neural, out, res = split
    shapes = [m.shape[:2] for m in ref]
    ours = E.decode_mips(E.load(out), shapes)
    model = E.decode_mips(E.load(neural), shapes)
    cols = {c: (g, j) for g in enc for j, c in enumerate(g.group.channels)}
    for k in range(len(ref)):
        if k < SPLIT:
            # a slope normal was measured as USD reads it, (s_x, s_y, 1) normalised: as the decoder reads it
            bc = np.stack([enc_g.decoded[k][..., j] for c, (enc_g, j) in sorted(cols.items())], -1)
            np.testing.assert_allclose(ours[k], bc, atol=1e-6, err_msg=f"mip {k}")
        else:
            np.testing.assert_array_equal(ours[k], model[k], err_msg=f"mip {k}")


def test_split_material_rebuilt_from_material_json_alone(split):
    """An independent reader, at reference mips and between them: OpenImageIO reads the DDS files
    (the truncated BC chains too), numpy samples them as GL would with the lod clamped to the
    stored mips, onnxruntime runs the decoder, and the schema's mixing rule joins the two."""
    ts, ref, enc, _, out, _ = split
    em = E.load(out)
    d, layers, classic, sess = read_independently(out)
    wrap = d["sampling"]["addressing"]
    rng = np.random.default_rng(1)
    uv = rng.random((2000, 2))
    for s in (0.0, 1.0, 1.5, 2.0, 2.25, 2.5, 2.75, 3.0, 4.5):
        w = min(1.0, max(0.0, s - d["split"] + 1))
        feats = np.concatenate([_trilinear(lv, uv, s + l["lod_bias"], wrap) for lv, l in zip(layers, d["layers"])], 1)
        y_mlp = sess.run([d["onnx"]["output"]], {d["onnx"]["input"]: feats.astype(np.float32)})[0]
        texels = [_trilinear(lv, uv, s + c["lod_bias"], wrap) for lv, c in zip(classic, d["classic"])]
        raw = {j: texels[o["texture"]][:, o["texel_channel"]] * o["texel_scale"] + o["texel_bias"]
               for j, o in enumerate(d["outputs"]) if not o["reconstructed"]}
        slope = [j for j in raw if d["outputs"][j].get("encoding") == "slope"]
        if slope:  # the normal's slopes (s_x, s_y), read as (s_x, s_y, 1) normalised
            sx, sy = raw[slope[0]], raw[slope[1]]
            inv = 1.0 / np.sqrt(1.0 + sx * sx + sy * sy)
            raw[slope[0]], raw[slope[1]] = sx * inv, sy * inv
        theirs = []
        for j, o in enumerate(d["outputs"]):
            if o["reconstructed"]:
                x, y = theirs[-2], theirs[-1]
                z = np.sqrt(np.maximum(0.0, 1.0 - x * x - y * y))
                theirs.append(y_mlp[:, j] if w == 1.0 else z)
                continue
            v = np.clip(raw[j], *o["range"])
            theirs.append((1 - w) * v + w * y_mlp[:, j])
        theirs = np.stack(theirs, 1)
        mine = np.empty_like(theirs, dtype=np.float32)
        mine[:] = sess.run([mf.ONNX_OUTPUT], {mf.ONNX_INPUT: E.sample_exported_features(em, uv.astype(np.float32), s)})[0]
        E.classic_outputs(em, uv.astype(np.float32), s, mine)
        # OpenImageIO's BC palettes round differently from quicktex (verify's classic check): a step
        step = 2 * max(abs(o.get("texel_scale") or 0) for o in d["outputs"]) / 255 * (1 - w) + 2e-4
        np.testing.assert_allclose(mine, theirs, atol=step, err_msg=f"s = {s}")


def test_verify_accepts_the_truncated_chains_and_refuses_a_wrong_count(split, tmp_path):
    import shutil

    from bcfpipe.verify.checks import check_classic
    from bcfpipe.verify.glsl import read_material

    ts, ref, enc, _, out, _ = split
    check = check_classic(read_material(out))
    assert check.passed, check.detail
    bad = tmp_path / "m"
    shutil.copytree(out, bad)
    d = json.loads((bad / "material.json").read_text())
    d["split"] = SPLIT + 1  # now the chains hold one level fewer than material.json's split needs
    (bad / "material.json").write_text(json.dumps(d))
    check = check_classic(read_material(bad))
    assert not check.passed and "serve s < 4" in check.detail


@pytest.mark.gl
def test_verify_passes_a_split_material(split):
    """The decoder's outputs GLSL against ONNX (every output is the MLP's from the split on), the
    classic textures against independent decoders."""
    from bcfpipe.verify.checks import verify

    rep = verify(split[4])
    assert rep.exit_code == 0, rep.to_dict()
    assert {c.name for c in rep.materials[0].checks} == {"files", "integrity", "weights", "openimageio", "classic",
                                                          "glsl"}


def test_split_candidates_fit_bc_bytes_and_hold_the_predicted_floor():
    """Every predicted split stays within BC@R's bytes, with the largest features that do; one whose
    probe falls below the floor from its split on is not offered."""
    from bcfpipe.layout import choose as C
    from bcfpipe.layout.classic import channel_errors
    from bcfpipe.formats.sizes import neural_bytes
    from bcfpipe.layout.kinds import BC_AT_R, ClassicFit, split_bytes, split_candidates

    ts, r = _set(256), 128  # a 64² set's BC@R is too small for any features beside it
    ref = build_mip_chain(ts.data)
    enc = encode(ts, r, ref)

    e_bc = channel_errors(ts, enc, ref)
    use = tuple(k for k, m in enumerate(ref) if min(m.shape[:2]) >= 4)
    bc = C.Candidate(tuple(g.group.name for g in enc), None, sum(g.size_bytes for g in enc),
                     C.combine(None, e_bc, range(ts.num_channels)), "measured", use, kind=BC_AT_R)
    cf = ClassicFit(enc, e_bc, bc, use)
    better = e_bc * 0.25  # a probe 6 dB better than BC@R at every mip: every split holds the floor
    cands = split_candidates(ts, cf, better, r, (12, 16))
    assert cands and all(c.part.split >= 1 and c.size_bytes <= bc.size_bytes and c.basis == "predicted" for c in cands)
    for c in cands:
        t, k = c.part.resolutions[0], c.part.split
        assert c.part.resolutions == (t, t, t, t // 2) and t <= 256 >> k
        assert c.size_bytes >= split_bytes(enc, split_levels(k, r, 256))
        bigger = neural_bytes((2 * t, 2 * t, 2 * t, t), 12, 16, ts.num_channels)
        assert 2 * t > 256 >> k or split_bytes(enc, split_levels(k, r, 256)) + bigger > bc.size_bytes
        np.testing.assert_allclose(c.mse_per_mip[:k], bc.mse_per_mip[:k])
    # the probe's features 2^5+ times larger than any split's: 5+ halvings at 3 dB each lose the floor
    assert split_candidates(ts, cf, better, r, (12, 16), probe_t0=4096, halving_db=3.0) == []
    same = split_candidates(ts, cf, better, r, (12, 16), probe_t0=min(c.part.resolutions[0] for c in cands),
                            halving_db=3.0)
    assert same and same[-1] == cands[-1]  # the smallest features: no halving from a probe of their size
    worse = e_bc * 4.0  # 6 dB worse everywhere: no split holds the floor past its split
    assert split_candidates(ts, cf, worse, r, (12, 16)) == []


def test_a_chosen_split_is_exported_as_one_folder(split, tmp_path):
    """export_layout writes a LayoutFit whose choice is a split as export_split does."""
    from bcfpipe.layout import choose as C
    from bcfpipe.layout.export import export_layout
    from bcfpipe.layout.result import LayoutFit
    from bcfpipe.layout.kinds import BC_AT_R, SPLIT as MIP_SPLIT, SplitPart

    ts, ref, enc, neural, out, res = split
    use = tuple(range(len(ref)))
    bc = C.Candidate(tuple(g.group.name for g in enc), None, 1, (1.0,) * len(ref), "measured", use, kind=BC_AT_R)
    ch = C.Candidate(bc.classic, "4/4/4/4", 1, (1.0,) * len(ref), "measured", use, SplitPart(SPLIT, (4, 4, 4, 4)),
                     kind=MIP_SPLIT)
    assert ch.label == "BC@R below mip 3 + neural 4/4/4/4 from it" and ch.to_json()["split"] == SPLIT
    d = C.Decision(bc, (bc, ch), ch, "test", "quality")
    fit = LayoutFit(d, d, enc, res, tuple(range(ts.num_channels)), None, 0.0, 0.0)
    again = export_layout(fit, ts, tmp_path / "m", "repeat")
    assert (again / "material.json").read_text() == (out / "material.json").read_text()
    for f in mf.read(out).files:
        assert (again / f).read_bytes() == (out / f).read_bytes(), f


def test_a_builds_usd_layer_says_the_split(split, tmp_path):
    """assemble keeps every target on the decoder (a split's outputs are all the MLP's) and the
    overrides layer authors bcf:split and the shader's split input, only for a split."""
    from pxr import Usd

    from bcfpipe.builder.assemble import _neural_targets
    from bcfpipe.builder.plan import TargetMap
    from bcfpipe.builder.usd_layer import SURFACE_SHADER, NeuralMaterialOverride, write_overrides_layer

    desc = mf.read(split[4])
    names = ["diffuseColor.r", "diffuseColor.g", "diffuseColor.b", "normal.x", "normal.y", "normal.z", "roughness"]
    targets = [TargetMap(n, n.split(".")[0], i, 1.0, 0.0, "raw", "f.png", "r") for i, n in enumerate(names)]
    assert [(t.target, t.channel) for t in _neural_targets(targets, desc)] == [(n, i) for i, n in enumerate(names)]

    def override(path, k):
        return NeuralMaterialOverride(
            path, tuple(f"T{i}.dds" for i in range(4)), (4,) * 4, (1,) * 4, (0.0,) * 4, False, "repeat", (64, 64),
            "st", (1.0, 1.0), 0.0, (0.0, 0.0), "weights.bin", 0, 10, 0, desc.mlp, "decoder.onnx", ("roughness",),
            (5,), (1.0,), (0.0,), ("raw",), None, "test", split=k)

    write_overrides_layer(tmp_path / "o.usda", [override("/A", SPLIT), override("/B", 0)])
    stage = Usd.Stage.Open(str(tmp_path / "o.usda"))
    a, b = stage.GetPrimAtPath("/A"), stage.GetPrimAtPath("/B")
    assert a.GetAttribute("bcf:split").Get() == SPLIT and not b.HasAttribute("bcf:split")
    assert stage.GetPrimAtPath(f"/A/{SURFACE_SHADER}").GetAttribute("inputs:split").Get() == SPLIT
    assert not stage.GetPrimAtPath(f"/B/{SURFACE_SHADER}").HasAttribute("inputs:split")


def test_the_reported_worst_margin_counts_the_mips_the_rule_counts():
    """A split's 1×1 mip may fall below BC@R (the teapot scene's did, by 1.2 dB); the rule does not
    count mips under 4 texels a side, and neither does the worst margin the reports print."""
    from bcfpipe.layout import choose as C
    from bcfpipe.layout.kinds import BC_AT_R, SPLIT as MIP_SPLIT, SplitPart

    use = (0, 1, 2)
    bc = C.Candidate(("a",), None, 10, (1e-4, 1e-4, 1e-4, 1e-4), "measured", use, kind=BC_AT_R)
    c = C.Candidate(("a",), "8/8/8/4", 9, (1e-4, 5e-5, 5e-5, 1e-3), "measured", use, SplitPart(1, (8, 8, 8, 4)),
                    kind=MIP_SPLIT)
    d = c.to_json(bc)
    assert min(d["margin_per_mip_db"]) == -10.0 and d["worst_margin_db"] == 0.0
    assert C.admissible(c, bc) is None


@pytest.mark.parametrize("backend", ["onnx", pytest.param("glsl", marks=pytest.mark.gl)])
def test_decode_cli_shows_what_the_split_material_shows(split, backend):
    """`bcfpipe decode` of a split material: below the split its classic textures, from the split
    on the decoder, as decode_mips (material.json's rule) has them at each reference mip."""
    from bcfpipe.cli.decode import decode_material, select_target

    ts, ref, _, _, out, _ = split
    ours = E.decode_mips(E.load(out), [m.shape[:2] for m in ref], drop_normal_z=False)
    for k in (0, SPLIT - 1, SPLIT):
        h, w = ref[k].shape[:2]
        img, used = decode_material(select_target(str(out), None), (w, h), float(k), backend)
        assert used == f"{backend} and classic textures"
        # GL filters BC7's UNORM8 texels with 8-bit weights (llvmpipe: fixed point), bcfpipe in float:
        # the features differ by up to 2^-8 of a texel step, times the MLP's gain (verify derives it per point)
        np.testing.assert_allclose(img, ours[k], atol=5e-3 if backend == "glsl" else 1e-5, err_msg=f"mip {k}")
