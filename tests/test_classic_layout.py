"""Issue 31's layouts: classic groups, the choice rule, and a mixed material rebuilt from its
material.json alone (OpenImageIO for every DDS, onnxruntime for the decoder)."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from bcfpipe.config import TrainingOptions
from bcfpipe.export import writer as E
from bcfpipe.export.material import FIGURES, train_material, make_config
from bcfpipe.formats import dds, material as mf
from bcfpipe.layout import choose as C
from bcfpipe.layout import kinds as K
from bcfpipe.formats.bcn import ClassicFormat, decode_levels
from bcfpipe.layout.classic import channel_errors, encode, groups
from bcfpipe.layout.export import export_layout
from bcfpipe.layout.kinds import subset
from bcfpipe.layout.result import LayoutFit
from bcfpipe.resources import SCHEMA_DIR
from bcfpipe.texset.metrics import mse_per_channel
from bcfpipe.texset.normals import unit
from bcfpipe.texset.texture_set import Channel, TextureSet, build_mip_chain

SCHEMA = SCHEMA_DIR / "material.schema.json"


def _set(size=64, seed=0) -> TextureSet:
    """albedo (rgb, its own file), normal (x, y), roughness alone in its file: BC1 + BC7 (the normal's x, y, z) + BC4."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size] / size
    alb = np.stack([0.5 + 0.4 * np.sin(6.28 * xx), 0.5 + 0.3 * np.cos(6.28 * yy), 0.3 + 0.2 * xx], -1)
    nx, ny = 0.4 * np.sin(12.56 * xx), 0.4 * np.cos(12.56 * yy)
    rough = 0.5 + 0.3 * np.sin(6.28 * (xx + yy)) + 0.05 * rng.standard_normal((size, size))
    data = np.concatenate([alb, nx[..., None], ny[..., None], np.clip(rough, 0, 1)[..., None]], -1).astype(np.float32)
    ch = (Channel("albedo", "r", "color", "a.png", 0), Channel("albedo", "g", "color", "a.png", 1),
          Channel("albedo", "b", "color", "a.png", 2), Channel("normal", "x", "normal", "n.png", 0),
          Channel("normal", "y", "normal", "n.png", 1), Channel("roughness", "r", "scalar", "r.png", 0))
    return TextureSet(data, ch, size, size)


def test_groups_are_benchs_bc_set_with_the_normal_as_bc5_slopes():
    """Bench's BC set, the normal in BC5 as bench has it, but of its slopes (x / z, y / z), so that a
    UsdUVTexture gives its direction (issue 57)."""
    gs = groups(_set())
    assert [(g.format, g.channels, g.name, g.slope) for g in gs] == [
        (ClassicFormat.BC1, (0, 1, 2), "albedo", False), (ClassicFormat.BC5, (3, 4), "normal", True),
        (ClassicFormat.BC4, (5,), "roughness", False)]


def test_classic_blocks_decode_to_what_bench_measured():
    ts = _set()
    ref = build_mip_chain(ts.data)
    for enc in encode(ts, 32, ref):
        texels = decode_levels(enc.group.format, enc.levels)
        scale_bias = np.array(enc.texel_map(ts))
        # level 0 is reference mip 1 (R = 32 for a 64² set); every level after it in turn
        for k, t in enumerate(texels):
            if enc.group.slope:  # what USD shades with: the slopes (2t - 1) m as (s_x, s_y, 1), normalised
                s = t[..., :2] * scale_bias[:, 0] + scale_bias[:, 1]
                np.testing.assert_allclose(unit(np.concatenate([s, np.ones_like(s[..., :1])], -1)), enc.decoded[k + 1],
                                           atol=1e-6)
                continue
            np.testing.assert_allclose(t * scale_bias[:, 0] + scale_bias[:, 1], enc.decoded[k + 1], atol=1e-6)


def bc_at(ts: TextureSet, ref, resolution: int = 32):
    """BC@R of ``ts`` at ``resolution``: (its encoded groups, per-channel errors, its candidate)."""
    enc = encode(ts, resolution, ref)
    e_bc = channel_errors(ts, enc, ref)
    bc = C.Candidate(tuple(g.group.name for g in enc), None, sum(g.size_bytes for g in enc),
                     C.combine(None, e_bc, range(ts.num_channels)), "measured", tuple(range(len(ref))), kind=K.BC_AT_R)
    return enc, e_bc, bc


def _cand(classic, size, mse, basis="measured", profile="1k", kind=K.MIXED):
    return C.Candidate(classic, profile, size, tuple(mse), basis, (0, 1, 2), K.NeuralPart() if profile else None,
                       kind=kind)


def test_rule_keeps_bc_when_nothing_else_qualifies_and_picks_the_best_that_does():
    bc = _cand(("a", "b"), 1000, [1e-4, 1e-4, 1e-4], profile=None, kind=K.BC_AT_R)
    too_big = _cand((), 1001, [1e-6] * 3, kind=K.NEURAL)
    too_weak_at_mip0 = _cand((), 500, [1.2e-4, 1e-6, 1e-6], kind=K.NEURAL)  # 0.79 dB below BC at mip 0
    assert C.choose([too_big, too_weak_at_mip0], bc).chosen is bc
    assert "2.67" not in C.admissible(too_big, bc) and "MiB" in C.admissible(too_big, bc)
    assert C.admissible(too_weak_at_mip0, bc).startswith("mip 0")
    ok_small = _cand(("a",), 900, [1.1e-4, 5e-5, 5e-5])  # 0.41 dB under at mip 0: within the slack
    ok_best = _cand(("b",), 950, [1.05e-4, 2e-5, 2e-5])
    d = C.choose([ok_small, ok_best, too_big], bc)
    assert d.chosen is ok_best and d.chosen.psnr > bc.psnr
    # --match-bc: every mip at BC or better, then the smallest
    m1, m2 = _cand(("a",), 800, [1e-4, 9e-5, 9e-5]), _cand(("b",), 700, [0.99e-4, 5e-5, 5e-5])
    assert C.choose([m1, m2, ok_small], bc, match_bc=True).chosen is m2


def test_combine_is_the_per_channel_mean():
    n = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    c = np.array([[10.0, 20.0, 30.0], [40.0, 50.0, 60.0]])
    assert C.combine(n, c, [1]) == (pytest.approx((1 + 20 + 3) / 3), pytest.approx((4 + 50 + 6) / 3))


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    """albedo and roughness neural (a model on those channels alone), the normal map classic (BC7 x, y, z)."""
    tmp = tmp_path_factory.mktemp("mixed")
    ts = _set()
    ref = build_mip_chain(ts.data)
    enc, e_bc, bc = bc_at(ts, ref)
    keep = [0, 1, 2, 5]
    sub = subset(ts, keep)
    _, cfg = make_config(sub, TrainingOptions(profile="tiny", preset="smoke", device="cpu", threads=1))
    res, _ = train_material(sub, tmp / "neural", cfg, "tiny")
    err = np.zeros((len(ref), ts.num_channels))
    err[:, keep] = res.mse_per_channel
    err[:, [3, 4]] = e_bc[:, [3, 4]]
    chosen = C.Candidate(("normal",), "tiny", res.size_bytes + enc[1].size_bytes, tuple(err.mean(1)), "measured",
                         bc.use, K.NeuralPart(), kind=K.MIXED)
    d = C.Decision(bc, (bc, chosen), chosen, "test", "quality")
    fit = LayoutFit(d, d, enc, res, tuple(keep), res, 0.0, 0.0)
    out = export_layout(fit, ts, tmp / "material", "repeat")
    return ts, ref, out, chosen


def test_a_probe_skips_ssim_and_flip_but_measures_the_same_errors(tmp_path):
    """The layout judges its probe by PSNR and per-channel errors: ``image_metrics=False`` leaves
    out SSIM and FLIP and changes no error (training is deterministic on the CPU)."""
    ts = _set()
    _, cfg = make_config(ts, TrainingOptions(profile="tiny", preset="smoke", device="cpu", threads=1))
    full, _ = train_material(ts, tmp_path / "full", cfg, "tiny")
    probe, _ = train_material(ts, tmp_path / "probe", cfg, "tiny", measure=FIGURES)
    assert full.metrics.ssim is not None and full.metrics.flip is not None
    assert probe.metrics.ssim is None and probe.metrics.flip is None
    assert probe.metrics.psnr_per_mip == full.metrics.psnr_per_mip
    assert np.array_equal(probe.mse_per_channel, full.mse_per_channel)


def test_mixed_material_json_says_where_each_output_comes_from(mixed):
    import jsonschema

    ts, _, out, _ = mixed
    d = json.loads((out / "material.json").read_text())
    jsonschema.validate(d, json.loads(SCHEMA.read_text()))
    assert d["format_version"] == 8  # a normal stored as slopes (issue 57)
    assert [c["file"] for c in d["classic"]] == ["C0.dds"] and d["classic"][0]["format"] == "BC5_UNORM"
    assert d["classic"][0]["channels"] == 2  # the normal's slopes (issue 57)
    assert d["classic"][0]["width"] == 32 and d["classic"][0]["lod_bias"] == -1.0
    src = {o["name"]: o.get("source", "mlp") for o in d["outputs"]}
    assert src == {"albedo.r": "mlp", "albedo.g": "mlp", "albedo.b": "mlp", "normal.x": "classic",
                   "normal.y": "classic", "normal.z": "classic", "roughness.r": "mlp"}
    nx = next(o for o in d["outputs"] if o["name"] == "normal.x")
    m = nx["texel_scale"] / 2.0
    assert (nx["texture"], nx["texel_channel"], nx["texel_bias"], nx["encoding"]) == (0, 0, -m, "slope") and m >= 1 / 64
    nz = next(o for o in d["outputs"] if o["name"] == "normal.z")
    assert nz["reconstructed"] and (nz["texture"], nz["encoding"]) == (0, "slope") and "texel_channel" not in nz
    assert d["mlp"]["n_out"] == 4 and sorted(d["sha256"]) == sorted(
        ["T0.dds", "T1.dds", "T2.dds", "T3.dds", "weights.bin", "decoder.onnx", "C0.dds"])
    assert not (out / "probe").exists() and sorted(p.name for p in out.iterdir()) == sorted(
        [*d["sha256"], "material.json"])


def _usd_normal_errors(ts: TextureSet, ref, out: Path) -> np.ndarray:
    """(mips, 2) errors of the normal's x and y as the layout counts them, rebuilt from the folder:
    the classic normal's DDS as a UsdPreviewSurface reads it ((s_x, s_y, 1) normalised) against the
    reference's x, y and rebuilt z, each at the normal's peak, half of z's added to x's and to y's."""
    from bcfpipe.layout.classic import usd_normals
    from bcfpipe.texset.normals import rebuild_z

    desc = mf.read(out)
    x = next(o for o in desc.outputs if o.name == "normal.x")
    seen = usd_normals(dds.read(out / desc.classic[x.texture].file).levels, [m.shape[:2] for m in ref], desc.wrap,
                       -x.texel_bias)
    xy = [i for i, c in enumerate(ts.channels) if c.kind == "normal"]
    e = np.array([[np.mean((s[..., i].astype(np.float64) - t[..., i]) ** 2) / 4.0 for i in range(3)]
                  for s, t in zip(seen, (rebuild_z(r[..., xy]) for r in ref))])
    return e[:, :2] + e[:, 2:] / 2.0


def test_mixed_material_measures_what_its_choice_predicted(mixed):
    """Decoding the exported folder gives exactly the per-mip errors the choice combined: the
    decoder's outputs and the classic ones as material.json says, the classic normal as USD reads
    it (z counted, issue 57)."""
    ts, ref, out, chosen = mixed
    em = E.load(out)
    dec = E.decode_mips(em, [m.shape[:2] for m in ref])
    per = mse_per_channel(ref, dec, ts.channels)
    per[:, [i for i, c in enumerate(ts.channels) if c.kind == "normal"]] = _usd_normal_errors(ts, ref, out)
    np.testing.assert_allclose(per.mean(1), chosen.mse_per_mip, rtol=1e-5)


def _trilinear(levels, uv, lod, wrap):
    """GL's LINEAR_MIPMAP_LINEAR at one lod for every uv, in float64, written from the spec."""
    lod = min(max(lod, 0.0), len(levels) - 1)
    l0 = int(np.floor(lod))
    l1, f = min(l0 + 1, len(levels) - 1), lod - l0

    def bilinear(img):
        h, w = img.shape[:2]
        x, y = uv[:, 0] * w - 0.5, uv[:, 1] * h - 0.5
        x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]

        def at(ix, iy):
            ix = ix % w if wrap == "repeat" else np.clip(ix, 0, w - 1)
            iy = iy % h if wrap == "repeat" else np.clip(iy, 0, h - 1)
            return img[iy, ix].astype(np.float64)

        top = at(x0, y0) * (1 - fx) + at(x0 + 1, y0) * fx
        bot = at(x0, y0 + 1) * (1 - fx) + at(x0 + 1, y0 + 1) * fx
        return top * (1 - fy) + bot * fy

    return bilinear(levels[l0]) * (1 - f) + bilinear(levels[l1]) * f


def _oiio_levels(path, channels):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    levels, k = [], 0
    while inp.seek_subimage(0, k):
        px = inp.read_image(format="float")
        levels.append(np.asarray(px, np.float32)[..., :channels])
        k += 1
    inp.close()
    return levels


def read_independently(out: Path):
    """material.json as JSON, every layer's and classic texture's mips through OpenImageIO (as many
    as material.json says), and the decoder in onnxruntime: what an independent reader starts from."""
    import onnxruntime as ort

    d = json.loads((out / "material.json").read_text())
    layers = [_oiio_levels(out / l["file"], l["channels"]) for l in d["layers"]]
    classic = [_oiio_levels(out / c["file"], c["channels"]) for c in d["classic"]]
    assert [len(c) for c in classic] == [c["mip_count"] for c in d["classic"]]
    return d, layers, classic, ort.InferenceSession(str(out / d["onnx"]["file"]), providers=["CPUExecutionProvider"])


def test_mixed_material_rebuilt_from_material_json_alone(mixed):
    """An independent consumer: OpenImageIO reads every DDS (the features, the BC5 slope normal), numpy
    samples them as GL would, onnxruntime runs the decoder, material.json says the rest."""
    ts, ref, out, _ = mixed
    d, layers, classic, sess = read_independently(out)
    wrap = d["sampling"]["addressing"]
    ours = E.decode_mips(E.load(out), [m.shape[:2] for m in ref], drop_normal_z=False)
    for k in (0, 1, 3):
        h, w = ref[k].shape[:2]
        ids = np.arange(h * w)
        uv = np.stack([(ids % w + 0.5) / w, (ids // w + 0.5) / h], 1)
        feats = np.concatenate([_trilinear(lv, uv, k + l["lod_bias"], wrap) for lv, l in zip(layers, d["layers"])], 1)
        y_mlp = sess.run([d["onnx"]["output"]], {d["onnx"]["input"]: feats.astype(np.float32)})[0]
        texels = [_trilinear(lv, uv, k + c["lod_bias"], wrap) for lv, c in zip(classic, d["classic"])]
        cols, j = [], 0
        for o in d["outputs"]:
            if o.get("source", "mlp") == "mlp":
                cols.append(y_mlp[:, j])
                j += 1
            elif o["reconstructed"] and o.get("encoding") == "slope":  # (s_x, s_y, 1) normalised
                sx, sy = cols[-2], cols[-1]
                z = 1.0 / np.sqrt(1.0 + sx * sx + sy * sy)
                cols[-2:] = [sx * z, sy * z]
                cols.append(z)
            elif o["reconstructed"]:
                x, y = cols[-2], cols[-1]
                cols.append(np.sqrt(np.maximum(0.0, 1.0 - x * x - y * y)))
            else:
                v = texels[o["texture"]][:, o["texel_channel"]] * o["texel_scale"] + o["texel_bias"]
                cols.append(v if o.get("encoding") == "slope" else np.clip(v, *o["range"]))
        theirs, mine = np.stack(cols, 1), ours[k].reshape(h * w, -1)
        for i, o in enumerate(d["outputs"]):
            if o.get("source", "mlp") == "mlp":
                np.testing.assert_allclose(theirs[:, i], mine[:, i], atol=2e-4, err_msg=o["name"])
            elif not o["reconstructed"]:
                # OpenImageIO rounds BC5's interpolated palette differently from quicktex and
                # texture2ddecoder (which agree exactly): at most one 8-bit step apart
                step = abs(o["texel_scale"]) / 255
                np.testing.assert_allclose(theirs[:, i], mine[:, i], atol=step + 1e-6, err_msg=o["name"])
            else:
                x, y = mine[:, i - 2], mine[:, i - 1]
                np.testing.assert_allclose(mine[:, i], np.sqrt(np.maximum(0, 1 - x * x - y * y)), atol=1e-6)


def test_a_layer_file_that_is_a_classic_format_is_refused(mixed, tmp_path):
    import shutil

    _, _, out, _ = mixed
    bad = tmp_path / "bad"
    shutil.copytree(out, bad)
    t0 = dds.read(bad / "T0.dds")  # a BC5 texture (a classic format) of T0's size in its place
    dds.write(bad / "T0.dds", [(np.zeros((b.shape[0], 16), np.uint8), w, h) for b, w, h in t0.levels],
              dxgi_format=dds.DXGI_FORMAT_BC5_UNORM)
    with pytest.raises(dds.DdsError, match="no feature-layer format"):
        E.load(bad)


@pytest.mark.gl
def test_verify_checks_both_parts_of_a_mixed_material(mixed):
    """The MLP's outputs GLSL against ONNX, the classic texture against independent decoders."""
    from bcfpipe.verify.checks import verify

    _, _, out, _ = mixed
    rep = verify(out)
    assert rep.exit_code == 0, rep.to_dict()
    checks = {c.name: c for c in rep.materials[0].checks}
    assert set(checks) == {"files", "integrity", "weights", "openimageio", "classic", "glsl"}
    assert "1 classic texture(s)" in checks["classic"].detail
    assert [ch["name"] for ch in rep.materials[0].channels] == ["albedo.r", "albedo.g", "albedo.b", "roughness.r"]


def test_verify_refuses_a_classic_texture_whose_bytes_changed(mixed, tmp_path):
    import shutil

    from bcfpipe.verify.checks import verify

    _, _, out, _ = mixed
    bad = tmp_path / "bad"
    shutil.copytree(out, bad)
    data = bytearray((bad / "C0.dds").read_bytes())
    data[200] ^= 0xFF
    (bad / "C0.dds").write_bytes(bytes(data))
    rep = verify(bad, glsl=False)
    assert rep.exit_code == 1
    assert "C0.dds differs from its recorded SHA-256" in {c.name: c for c in rep.materials[0].checks}["integrity"].detail


def test_bc_at_r_ships_when_no_neural_candidate_clears_its_floor():
    bc = _cand(("a", "b"), 1000, [1e-4, 1e-4, 1e-4], profile=None, kind=K.BC_AT_R)
    near = _cand(("a",), 800, (2e-4, 5e-5, 5e-5), "predicted")  # 3.0 dB under at mip 0
    nearer = _cand(("b",), 900, (1.5e-4, 5e-5, 5e-5), "predicted")  # 1.3 dB under
    too_big = _cand(("b",), 1100, (1.2e-4, 5e-5, 5e-5), "predicted", profile="2k")
    assert C.choose([near, nearer, too_big], bc).chosen is bc
    assert C.deficit(nearer, bc) == pytest.approx(10 * np.log10(1.5) - 0.5)


SAMPLE = Path(__file__).resolve().parents[1] / "samples"


def test_train_layout_auto_writes_the_chosen_layout_and_why(tmp_path):
    """A real `bcfpipe train --layout auto`: one folder, material.json + layout.json, measured."""
    from click.testing import CliRunner

    from bcfpipe.cli import main

    t = SAMPLE / "textures"
    out = tmp_path / "m"
    r = CliRunner().invoke(main, ["train", f"albedo={t / 'bricks_albedo.png'}:rgb",
                                  f"normal={t / 'bricks_normal.png'}:xy", "--layout", "auto",
                                  "--quality", "smoke", "--threads", "1", "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout.strip().splitlines()[-1])
    lay = d["layout"]
    assert lay["objective"] == "quality" and lay["chosen"]["layout"]
    # weighed: everything the first choice was made among, the probe's bound included (issue 58: the
    # probe never ships, so the final candidates are what is measured or encodable)
    assert {c["layout"] for c in lay["weighed"]} >= {"all classic (BC@R)", "neural 0.5k"}
    assert "all classic (BC@R)" in {c["layout"] for c in lay["candidates"]}
    assert set(d["phase_seconds"]) >= {"layout_estimate", "layout_probe", "layout_classic_encode"}
    assert "cost_seconds" not in lay  # layout.json holds no seconds: a build's outputs are byte-identical
    assert json.loads((out / "layout.json").read_text()) == lay
    assert not (out / ".layout-work").exists()
    assert d["size_bytes"] <= lay["bc"]["size_bytes"] and d["size_bytes"] == lay["chosen"]["size_bytes"]
    # the folder measures what the choice said, but for the classic normal's z: the choice counts it as
    # USD reads it (half its MSE on x and half on y, issue 57), the folder's PSNR, as every PSNR, x and y
    # (0.02 dB on these bricks)
    assert abs(d["psnr"] - lay["chosen"]["psnr"]) < 0.05
    from bcfpipe.verify.checks import verify

    assert verify(out, glsl=False).exit_code == 0


@pytest.mark.parametrize("args, message", [
    (["--match-bc", "--layout", "neural"], "--match-bc chooses a layout: use it with --layout auto"),
    (["--match-bc", "--target-psnr", "30"], "--match-bc sizes a layout against BC@R; --target-psnr sizes"),
    (["--classic", "albedo", "--target-psnr", "30"], "--classic fixes part of the layout"),
    (["--layout", "auto", "--target-psnr", "30"], "use one (--layout neural --target-psnr DB)"),
])
def test_layout_options_that_do_not_combine_are_refused_in_one_line(tmp_path, args, message):
    from click.testing import CliRunner

    from bcfpipe.cli import main

    t = SAMPLE / "textures"
    r = CliRunner().invoke(main, ["train", f"albedo={t / 'bricks_albedo.png'}:rgb", "-o", str(tmp_path / "m"), *args])
    assert r.exit_code == 2 and message in r.output and "Traceback" not in r.output


def test_layout_defaults_to_auto_and_to_neural_with_a_target_psnr():
    """Issue 31: `auto` is the default; --target-psnr sizes an all-neural material, so with it the
    default is neural; asking for both is refused."""
    from bcfpipe.errors import InputError
    from bcfpipe.formats.vocabulary import Layout

    assert TrainingOptions().layout == Layout.AUTO
    assert TrainingOptions(target_psnr=30.0).layout == Layout.NEURAL
    assert TrainingOptions(layout="neural").layout == Layout.NEURAL
    with pytest.raises(InputError, match="use one"):
        TrainingOptions(layout="auto", target_psnr=30.0)


def test_build_layout_auto_records_each_choice_and_verifies(tmp_path):
    """A real build with the default layout (auto): every built material says what was chosen
    against BC@R; one kept as BC@R gets no neural override (its UsdUVTexture nodes read its DDS
    instead, test_usd_classic), and verify passes."""
    from click.testing import CliRunner

    from bcfpipe.cli import main
    from bcfpipe.formats import manifest as mfst
    from bcfpipe.verify.checks import verify

    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["build", str(SAMPLE / "sample_scene.usda"), "-o", str(out),
                                  "--quality", "smoke", "--jobs", "1", "--threads", "1", "--json"])
    assert r.exit_code == 0, r.output
    report = json.loads(r.stdout)
    assert all(m["layout"]["bc_size_bytes"] > 0 for m in report["materials"] if m["status"] == "built")
    man = mfst.read(out)
    assert man.options["layout"] == "auto"
    built = man.built()
    assert built and all(m.layout is not None for m in built)
    for m in built:
        assert m.layout.size_bytes <= m.layout.bc_size_bytes
        assert min(m.layout.margin_per_mip_db) >= -0.5 - 1e-6
        if m.layout.profile is None:  # no bcf context; its UsdUVTexture nodes read the DDS (test_usd_classic)
            assert m.outputs.weights_index is None and m.sizes.classic_bytes > 0
            assert "BcfNeuralMaterialAPI" not in _material_spec(out / "overrides.usda", m.path)
    assert verify(out, glsl=False).exit_code == 0
    from bcfpipe.cache.store import Cache  # BC@R's blocks were kept in the build's cache

    assert Cache(os.environ["BCFPIPE_CACHE"]).blocks.files()


def _material_spec(layer: Path, path: str) -> str:
    """The apiSchemas the overrides layer gives one material prim (empty when none)."""
    from pxr import Sdf

    opened = Sdf.Layer.FindOrOpen(str(layer))  # held: a spec of a released layer is expired
    spec = opened.GetPrimAtPath(Sdf.Path(path))
    return str(spec.GetInfo("apiSchemas")) if spec is not None and "apiSchemas" in spec.ListInfoKeys() else ""


def test_a_builds_usd_override_drives_only_the_decoders_outputs(mixed):
    """assemble keeps the classic targets on their UsdUVTexture and renumbers the rest to the
    decoder's outputs (normal z is the decoder's own only when the normal is)."""
    from bcfpipe.builder.assemble import _neural_targets
    from bcfpipe.builder.plan import TargetMap

    _, _, out, _ = mixed
    desc = mf.read(out)
    names = ["diffuseColor.r", "diffuseColor.g", "diffuseColor.b", "normal.x", "normal.y", "normal.z", "roughness"]
    targets = [TargetMap(n, n.split(".")[0], i, 1.0, 0.0, "raw", "f.png", "r") for i, n in enumerate(names)]
    targets.append(TargetMap("metallic", "metallic", -1, 0.0, 0.25, "raw", None, None))
    kept = _neural_targets(targets, desc)
    assert [(t.target, t.channel) for t in kept] == [("diffuseColor.r", 0), ("diffuseColor.g", 1),
                                                     ("diffuseColor.b", 2), ("roughness", 3), ("metallic", -1)]
    assert [o.name for o in desc.mlp_outputs] == ["albedo.r", "albedo.g", "albedo.b", "roughness.r"]


def test_a_layout_exported_over_an_earlier_one_leaves_none_of_its_files(mixed, tmp_path):
    """`train --force` into a folder that held another layout: only the new layout's files stay."""
    import shutil

    from bcfpipe.layout.export import export_layout

    ts, _, out, chosen = mixed
    folder = tmp_path / "m"
    shutil.copytree(out, folder)
    (folder / "C1.dds").write_bytes((folder / "C0.dds").read_bytes())  # as if an earlier layout had two
    bc_only = C.Decision(chosen, (chosen,), C.Candidate(("albedo", "normal", "roughness"), None, 0, chosen.mse_per_mip,
                                                        "measured", chosen.use, kind=K.BC_AT_R), "test", "quality")
    fit = LayoutFit(bc_only, bc_only, encode(ts, 32, build_mip_chain(ts.data)), None, (), None, 0.0, 0.0)
    export_layout(fit, ts, folder, "repeat")
    assert sorted(p.name for p in folder.iterdir()) == ["C0.dds", "C1.dds", "C2.dds", "material.json"]
    assert not mf.read(folder).neural


def test_classic_option_is_parsed_once():
    assert TrainingOptions(classic="normal, opacity").classic == ("normal", "opacity")
    assert TrainingOptions(classic="").classic == () and TrainingOptions().classic == ()


def test_train_classic_keeps_the_named_group_and_trains_the_rest(tmp_path):
    """`bcfpipe train --classic normal`: the normal map ships as BC@R's (BC7 x, y, z), the decoder learns the
    other channels only, no probe is trained, and verify passes; a semantic the set lacks changes
    nothing (an all-neural folder)."""
    from click.testing import CliRunner

    from bcfpipe.cli import main
    from bcfpipe.verify.checks import verify

    t = SAMPLE / "textures"
    base = ["train", f"albedo={t / 'bricks_albedo.png'}:rgb", f"normal={t / 'bricks_normal.png'}:xy",
            "--profile", "tiny", "--quality", "smoke", "--threads", "1", "--json"]
    out = tmp_path / "m"
    r = CliRunner().invoke(main, base + ["-o", str(out), "--classic", "normal", "--layout", "neural"])
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout.strip().splitlines()[-1])
    assert d["layout"]["chosen"]["layout"] == "neural tiny + classic normal"
    assert "--classic normal" in d["layout"]["reason"]
    desc = mf.read(out)
    assert [c.dxgi_format for c in desc.classic] == [83]  # BC5_UNORM: the normal's slopes (issue 57)
    assert {o.name for o in desc.outputs if o.source == "classic"} == {"normal.x", "normal.y", "normal.z"}
    assert desc.mlp.n_out == 3  # albedo only
    assert not (out / ".layout-work").exists()
    assert verify(out, glsl=False).exit_code == 0
    plain = tmp_path / "p"
    r = CliRunner().invoke(main, base[:2] + base[3:] + ["-o", str(plain), "--classic", "normal", "--layout", "neural"])
    assert r.exit_code == 0, r.output
    assert not mf.read(plain).classic and not (plain / "layout.json").exists()


def test_build_classic_applies_to_the_materials_that_have_it(tmp_path):
    """`bcfpipe build --classic normal`: the materials with a normal map keep it classic, the
    leaves (no normal) train all neural; the option is in the manifest and the cache key."""
    from click.testing import CliRunner

    from bcfpipe.builder.plan import plan
    from bcfpipe.cli import main
    from bcfpipe.formats import manifest as mfst

    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["build", str(SAMPLE / "sample_scene.usda"), "-o", str(out), "--classic", "normal", "--layout", "neural",
                                  "--quality", "smoke", "--jobs", "1", "--threads", "1", "--json"])
    assert r.exit_code == 0, r.output
    man = mfst.read(out)
    assert man.options["classic"] == ["normal"]
    kept = {m.path: m.layout.classic if m.layout else () for m in man.built()}
    assert kept["/World/Looks/Bricks"] == ("normal",) and kept["/World/Looks/Leaves"] == ()
    keys = {j.name: j.content_hash for j in plan(SAMPLE / "sample_scene.usda",
                                                 TrainingOptions(preset="smoke", layout="neural")).jobs}
    with_classic = {j.name: j.content_hash for j in plan(SAMPLE / "sample_scene.usda",
                                                         TrainingOptions(preset="smoke", layout="neural",
                                                                         classic=("normal",))).jobs}
    assert all(keys[n] != with_classic[n] for n in keys)
    r = CliRunner().invoke(main, ["plan", str(SAMPLE / "sample_scene.usda"), "--classic", "normal,normals"])
    assert r.exit_code == 0 and "--classic normals: no modelled material has such a channel" in r.output
    assert "--classic normal:" not in r.output


def test_decode_cli_writes_every_output_of_a_mixed_or_all_classic_material(mixed, tmp_path):
    """`bcfpipe decode` of a layout: the decoder's outputs and the classic ones, as decode_mips has
    them; a material kept as BC@R (no decoder at all) decodes from its BC textures alone."""
    from bcfpipe.cli.decode import decode_material, select_target

    ts, ref, out, _ = mixed
    enc, _, bc = bc_at(ts, ref)
    d = C.Decision(bc, (bc,), bc, "test", "quality")
    classic = export_layout(LayoutFit(d, d, enc, None, (), None, 0.0, 0.0), ts, tmp_path / "bc", "repeat")
    for folder, used in ((out, "onnx and classic textures"), (classic, "classic textures")):
        ours = E.decode_mips(E.load(folder), [m.shape[:2] for m in ref], drop_normal_z=False)
        for k in (0, 1):
            h, w = ref[k].shape[:2]
            img, how = decode_material(select_target(str(folder), None), (w, h), float(k), "onnx")
            assert how == used and img.shape == (h, w, len(mf.read(folder).outputs))
            np.testing.assert_allclose(img, ours[k], atol=1e-5, err_msg=f"{folder.name} mip {k}")


@pytest.mark.parametrize("resolution", [32, 64])
def test_a_whole_mip_read_texel_for_texel_decodes_to_the_sampled_bits(mixed, tmp_path, resolution):
    """`decode_mips` reads a classic level that a whole mip samples texel for texel as it is (no uv
    made): the same bits as sampling every texel centre through `filtering.trilinear`, for a mixed
    material and for BC@R below the set's side (mip 0 magnified) and at it."""
    ts, ref, out, _ = mixed
    enc, _, bc = bc_at(ts, ref, resolution)
    d = C.Decision(bc, (bc,), bc, "test", "quality")
    classic = export_layout(LayoutFit(d, d, enc, None, (), None, 0.0, 0.0), ts, tmp_path / "bc", "repeat")
    shapes = [m.shape[:2] for m in ref]
    for folder in (out, classic):
        em = E.load(folder)
        assert sum(E._whole_levels(em, float(k), *s) is not None for k, s in enumerate(shapes)) >= len(shapes) - 1
        whole = E.decode_mips(em, shapes, drop_normal_z=False, chunk=1000)
        sampled = E.decode_mips(em, shapes, drop_normal_z=False, texels=[np.arange(h * w) for h, w in shapes])
        for k, (h, w) in enumerate(shapes):
            assert np.array_equal(whole[k], sampled[k].reshape(h, w, -1)), f"{folder.name} mip {k}"
