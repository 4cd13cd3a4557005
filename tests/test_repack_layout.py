"""Issue 31's BC7 repacks: BC@R's groups merged into BC7 textures in the same bytes, measured
exactly, exported as DXGI 98 DDS files that OpenImageIO and Mesa decode bit for bit, and rebuilt
from material.json alone."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from bcfpipe.export import writer as E
from bcfpipe.formats import dds, material as mf
from bcfpipe.formats.bcn import ClassicFormat, decode_levels
from bcfpipe.layout import choose as C
from bcfpipe.layout.classic import Group, encode_bc7, groups, measure_repack, repacks
from bcfpipe.layout.export import export_layout
from bcfpipe.layout.result import LayoutFit
from bcfpipe.layout.kinds import REPACK
from bcfpipe.texset.metrics import mse_per_channel
from bcfpipe.texset.texture_set import Channel, TextureSet, build_mip_chain

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_classic_layout import SAMPLE, SCHEMA, _oiio_levels, _set, _trilinear, _usd_normal_errors, bc_at  # noqa: E402


def _two_colours() -> TextureSet:
    """albedo and an ARM file: two BC1 groups, one byte per texel, which no BC7 repack fits."""
    rng = np.random.default_rng(1)
    data = rng.random((16, 16, 6)).astype(np.float32)
    ch = tuple(Channel("albedo", c, "color", "a.png", i) for i, c in enumerate("rgb")) + tuple(
        Channel(s, "r", "scalar", "arm.png", i) for i, s in enumerate(("occlusion", "roughness", "metallic")))
    return TextureSet(data, ch, 16, 16)


def test_repacks_merge_bc1_with_bc4_and_pack_every_channel_where_the_bytes_allow():
    gs = groups(_set())  # albedo BC1, normal BC5 (slopes), roughness BC4: 32 bytes per 4x4 block
    rp = repacks(gs)
    # the normal's slopes stay BC5 (issue 57): never repacked; every other channel in
    # one BC7 is the albedo+roughness repack itself, so it is offered once
    assert [(r.label, r.replaces) for r in rp] == [("albedo+roughness as BC7", ("albedo", "roughness"))]
    assert rp[0].groups == (Group(ClassicFormat.BC7, (0, 1, 2, 5), "albedo+roughness"),)
    assert repacks(groups(_two_colours())) == []  # 6 channels need 2 bytes per texel, BC@R has 1
    # each colour whole at r, g, b of one texture (a UsdUVTexture's rgb), scalars after
    three = TextureSet(np.zeros((8, 8, 6), np.float32), _two_colours().channels[:3] + tuple(
        Channel(s, "r", "scalar", f"{s}.png", 0) for s in ("occlusion", "roughness", "metallic")), 8, 8)
    (every,) = [r for r in repacks(groups(three)) if r.label.startswith("all")]
    assert [g.channels for g in every.groups] == [(0, 1, 2, 3), (4, 5)]


def test_a_bc7_group_decodes_to_what_was_measured():
    ts = _set()
    ref = build_mip_chain(ts.data)
    g = repacks(groups(ts))[0].groups[0]
    enc = encode_bc7(ts, g, 32, ref)
    assert [(w, h) for _, w, h in enc.levels] == [(32 >> k, 32 >> k) for k in range(6)]
    assert enc.size_bytes == dds.HEADER_BYTES + 16 * sum(max(1, (32 >> k) // 4) ** 2 for k in range(6))
    scale, bias = np.array(g.texel_map(ts)).T
    for k, t in enumerate(decode_levels(ClassicFormat.BC7, enc.levels)):  # level k serves reference mip k + 1
        np.testing.assert_allclose(t * scale + bias, enc.decoded[k + 1], atol=1e-6)


@pytest.fixture(scope="module")
def repacked(tmp_path_factory):
    """_set()'s BC@R with albedo and roughness merged into one BC7 texture, exported."""
    tmp = tmp_path_factory.mktemp("repack")
    ts = _set()
    ref = build_mip_chain(ts.data)
    enc, e_bc, bc = bc_at(ts, ref)
    rp = repacks([g.group for g in enc])[0]
    new, e, size = measure_repack(ts, enc, e_bc, rp, 32, ref)
    assert size == enc[1].size_bytes + new[0].size_bytes
    chosen = C.Candidate(("normal", "albedo+roughness"), None, size, C.combine(None, e, range(6)), "measured",
                         bc.use, REPACK.Part(rp.label), kind=REPACK)
    d = C.Decision(bc, (bc, chosen), chosen, "test", "quality")
    out = export_layout(LayoutFit(d, d, enc, None, (), None, 0.0, 0.0, {rp.label: (rp, new)}), ts, tmp / "m", "repeat")
    return ts, ref, out, chosen


def test_a_repack_exports_bc7_and_says_where_each_output_comes_from(repacked):
    import jsonschema

    ts, ref, out, chosen = repacked
    d = json.loads((out / "material.json").read_text())
    jsonschema.validate(d, json.loads(SCHEMA.read_text()))
    assert [(c["file"], c["dxgi_format"], c["format"], c["channels"]) for c in d["classic"]] == [
        ("C0.dds", 83, "BC5_UNORM", 2), ("C1.dds", 98, "BC7_UNORM", 4)]
    where = {o["name"]: (o["source"], o["texture"], o.get("texel_channel")) for o in d["outputs"]}
    assert where == {"albedo.r": ("classic", 1, 0), "albedo.g": ("classic", 1, 1), "albedo.b": ("classic", 1, 2),
                     "normal.x": ("classic", 0, 0), "normal.y": ("classic", 0, 1), "normal.z": ("classic", 0, None),
                     "roughness.r": ("classic", 1, 3)}
    assert not d["layers"] and "mlp" not in d and sorted(p.name for p in out.iterdir()) == [
        "C0.dds", "C1.dds", "material.json"]
    assert dds.read(out / "C1.dds").is_bc7 and sum((out / f).stat().st_size for f in ("C0.dds", "C1.dds")) == \
        chosen.size_bytes
    # the folder decodes to exactly what the choice measured (the normal as USD reads it)
    dec = E.decode_mips(E.load(out), [m.shape[:2] for m in ref])
    per = mse_per_channel(ref, dec, ts.channels)
    per[:, [3, 4]] = _usd_normal_errors(ts, ref, out)
    np.testing.assert_allclose(per.mean(1), chosen.mse_per_mip, rtol=1e-5)


def test_a_repack_rebuilt_from_material_json_alone(repacked):
    """OpenImageIO reads both DDS files (the BC5 slope normal and the BC7 repack); numpy samples them as GL would;
    material.json says the rest (a slope normal: (s_x, s_y, 1) normalised). BC7's palette is exact integer arithmetic, so every BC7 output agrees bit for bit."""
    ts, ref, out, _ = repacked
    d = json.loads((out / "material.json").read_text())
    classic = [_oiio_levels(out / c["file"], c["channels"]) for c in d["classic"]]
    ours = E.decode_mips(E.load(out), [m.shape[:2] for m in ref], drop_normal_z=False)
    for k in (0, 1, 3):
        h, w = ref[k].shape[:2]
        ids = np.arange(h * w)
        uv = np.stack([(ids % w + 0.5) / w, (ids // w + 0.5) / h], 1)
        texels = [_trilinear(lv, uv, k + c["lod_bias"], "repeat") for lv, c in zip(classic, d["classic"])]
        mine = ours[k].reshape(h * w, -1)
        raw = {i: texels[o["texture"]][:, o["texel_channel"]] * o["texel_scale"] + o["texel_bias"]
               for i, o in enumerate(d["outputs"]) if not o["reconstructed"]}
        sx, sy = (raw[i] for i, o in enumerate(d["outputs"]) if o.get("encoding") == "slope" and i in raw)
        inv = 1.0 / np.sqrt(1.0 + sx * sx + sy * sy)
        raw.update({i: v * inv for i, v in zip((3, 4), (sx, sy))})
        assert [d["outputs"][i]["name"] for i in (3, 4)] == ["normal.x", "normal.y"]
        for i, o in enumerate(d["outputs"]):
            if o["reconstructed"]:
                continue
            v = np.clip(raw[i], *o["range"])
            bc7 = d["classic"][o["texture"]]["dxgi_format"] == 98
            np.testing.assert_allclose(v, mine[:, i], atol=1e-6 if bc7 else abs(o["texel_scale"]) / 255 + 1e-6,
                                       err_msg=f"{o['name']} mip {k}")


def test_verify_checks_a_repacks_bc7_texture_against_openimageio(repacked):
    from bcfpipe.verify.checks import verify

    _, _, out, _ = repacked
    r = verify(out, glsl=False)
    assert r.exit_code == 0
    detail = next(c.detail for m in r.materials for c in m.checks if c.name == "classic")
    assert "bit-identical for BC7" in detail


@pytest.mark.gl
def test_mesa_decodes_a_repacks_bc7_texture_as_bcfpipe_does(repacked):
    """Mesa's BPTC decoder (GL_COMPRESSED_RGBA_BPTC_UNORM), an independent oracle, on every mip of
    the exported file: ISPC's blocks use every BC7 mode, not only bcfpipe's feature modes 6 and 7."""
    import gl_oracle

    _, _, out, _ = repacked
    tex = dds.read(out / "C1.dds")
    for (blocks, w, h), ours, gl in zip(tex.levels, decode_levels(ClassicFormat.BC7, tex.levels),
                                         gl_oracle.gl_decode_bc7_mips(tex.levels)):
        np.testing.assert_array_equal(np.rint(ours * 255).astype(np.uint8), gl[:h, :w], err_msg=f"{w}x{h}")
    modes = {int(np.flatnonzero(np.unpackbits(b[:1], bitorder="little"))[0]) for b in tex.levels[0][0]}
    assert len(modes) > 1, modes  # more than one mode in use


def test_train_ships_a_bc7_repack_where_it_beats_bc_at_every_mip(tmp_path):
    """A real `bcfpipe train` of the sample leaves (RGBA albedo: BC1 + BC4 in BC@R): the rule weighs
    the albedo and opacity in one BC7 texture, in the same bytes, and ships it (the probe is larger
    than BC@R); the folder measures what the choice said, and verify passes."""
    from click.testing import CliRunner

    from bcfpipe.cli import main
    from bcfpipe.verify.checks import verify

    leaves = SAMPLE / "textures" / "leaves_albedo.png"
    out = tmp_path / "m"
    r = CliRunner().invoke(main, ["train", f"albedo={leaves}:rgb", f"opacity={leaves}:a", "--quality", "smoke",
                                  "--threads", "1", "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout.strip().splitlines()[-1])
    lay = d["layout"]
    assert lay["chosen"]["layout"] == "BC@R with albedo+opacity as BC7" and lay["chosen"]["repack"]
    assert lay["chosen"]["size_bytes"] <= lay["bc"]["size_bytes"]
    assert min(lay["chosen"]["margin_per_mip_db"]) >= 0.0 and lay["chosen"]["psnr"] > lay["bc"]["psnr"] + 1.0
    assert abs(d["psnr"] - lay["chosen"]["psnr"]) < 0.01
    assert [c.dxgi_format for c in mf.read(out).classic] == [dds.DXGI_FORMAT_BC7_UNORM]
    assert verify(out, glsl=False).exit_code == 0


def test_classic_keeps_its_group_as_bc_at_r_has_it_and_a_repack_of_the_rest_ships_alone(tmp_path):
    """`--classic normal` with the default layout: repacks that would merge the named group are not
    weighed, those that keep it are; the one shipped is all classic (no probe's files beside it)."""
    from click.testing import CliRunner

    from bcfpipe.cli import main
    from bcfpipe.verify.checks import verify

    t = SAMPLE / "textures"
    out = tmp_path / "m"
    r = CliRunner().invoke(main, ["train", f"albedo={t / 'bricks_albedo.png'}:rgb", f"normal={t / 'bricks_normal.png'}:xy",
                                  f"roughness={t / 'bricks_roughness.png'}:r",
                                  f"displacement={t / 'bricks_height.png'}:r", "--classic", "normal",
                                  "--quality", "smoke", "--threads", "1", "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    lay = json.loads(r.stdout.strip().splitlines()[-1])["layout"]
    weighed = {c["layout"] for c in lay["candidates"] if c.get("repack")}
    assert weighed == {"BC@R with albedo+roughness as BC7", "BC@R with albedo+displacement as BC7"}
    assert lay["chosen"].get("repack") and "normal" in lay["chosen"]["classic"]
    desc = mf.read(out)
    assert not desc.neural and not desc.layers
    assert sorted(p.name for p in out.iterdir()) == ["C0.dds", "C1.dds", "C2.dds", "layout.json", "material.json"]
    assert [c.dxgi_format for c in desc.classic].count(dds.DXGI_FORMAT_BC7_UNORM) == 1  # the repack (the normal: BC5)
    assert verify(out, glsl=False).exit_code == 0
