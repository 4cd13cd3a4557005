"""Model only what the scene requires (issue #18): constant channels folded into USD values,
duplicate channels merged into one decoder output."""
from __future__ import annotations
from bcfpipe.builder import Execution

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from cli_run import run_cli
from pxr import Usd, UsdShade

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_build import FAST, add_material, new_stage, pattern, write_png  # noqa: E402

from bcfpipe.builder import build, plan  # noqa: E402
from bcfpipe.config import TrainingOptions  # noqa: E402
from bcfpipe.scan.content import channel_contents, srgb_to_linear  # noqa: E402

DRAFT = {"training": TrainingOptions(profile="tiny", preset="draft", seed=0, layout="neural")}  # where decoded values are measured

VEHICLES = "usdwg_vehicles/USD_Mini_Car_Kit/assets/vehicles/vehicleVariants.usda"


def test_constancy_is_one_step_of_the_source_quantisation():
    a = np.full((8, 8, 3), 100, np.uint8)
    a[0, 0, 1] = 101  # one 8-bit step: still constant
    a[0, 0, 2] = 102  # two steps: varies
    c = channel_contents(a)
    assert [x.constant for x in c] == [True, True, False]
    assert c[0].mean == pytest.approx(100 / 255)
    h = np.full((4, 4, 2), 0.5, np.float16)
    h[0, 0, 0] = np.nextafter(np.float16(0.5), np.float16(1))  # one fp16 ulp
    h[0, 0, 1] = np.float16(0.502)
    assert [x.constant for x in channel_contents(h)] == [True, False]
    assert channel_contents(a)[0].digest != channel_contents(a[:4])[0].digest  # size is part of the content


def _oiio_linear_mean(path: Path, channel: int) -> float:
    """The texture's value as Hydra reads it, through OpenImageIO's own sRGB -> linear conversion."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(path))
    lin = oiio.ImageBufAlgo.colorconvert(buf, "sRGB", "linear")
    return float(np.asarray(lin.get_pixels(oiio.FLOAT))[..., channel].mean())


@pytest.mark.shared
def test_vehicles_train_nothing_and_hold_their_constants(shared_scenes, tmp_path):
    """Every texture of the vehicles kit is one colour: 0 trainings, each input holds the value its
    texture gave (within 1/255 after the colour decode, checked with OpenImageIO's sRGB decode),
    and `bcfpipe verify` passes."""
    scene = shared_scenes / VEHICLES
    out = tmp_path / "out"
    p = run_cli("build", scene, "-o", out, "--json")
    assert p.returncode == 0, p.stderr
    report = json.loads(p.stdout)
    assert report["totals"]["trained"] == 0 and report["totals"]["jobs"] == 0
    assert report["totals"]["constant"] == report["totals"]["materials"] == 14
    assert all(m["status"] == "constant" and m["folded"] for m in report["materials"])
    stage = Usd.Stage.Open(str(out / "vehicleVariants.bcf.usda"))
    src = Usd.Stage.Open(str(scene))
    checked = 0
    for prim in stage.Traverse():
        if not prim.IsA(UsdShade.Material):
            continue
        surface, _, _ = UsdShade.Material(prim).ComputeSurfaceSource("")
        inp = surface.GetInput("diffuseColor")
        assert not inp.HasConnectedSource()
        sources, _ = UsdShade.Shader(src.GetPrimAtPath(surface.GetPath())).GetInput("diffuseColor") \
            .GetConnectedSources()
        tex = sources[0].source
        file = UsdShade.Shader(tex.GetPrim()).GetInput("file").Get().resolvedPath
        value = inp.Get()
        for c in range(3):
            assert abs(value[c] - _oiio_linear_mean(Path(file), c)) <= 1 / 255, (prim.GetPath(), c)
        checked += 1
    assert checked == 14
    v = run_cli("verify", out, "--json")
    assert v.returncode == 0, v.stdout[-2000:] + v.stderr
    checks = [c for m in json.loads(v.stdout)["materials"] for c in m["checks"]]
    assert len(checks) == 14 and all(c["name"] == "constants" and c["passed"] for c in checks)


def _duplicate_scene(root: Path) -> Path:
    """Material A: colour a.png, an ORM file whose R equals its G, a constant roughness texture.
    Material B: the same colour image saved under another name, and the same ORM file."""
    a = pattern(c=3, seed=0)
    write_png(root / "tex" / "a.png", a)
    write_png(root / "tex" / "a_copy.png", a)
    orm = pattern(c=3, seed=4)
    orm[..., 1] = orm[..., 0]
    write_png(root / "tex" / "orm.png", orm)
    write_png(root / "tex" / "flat.png", np.full((16, 16), 0.6))
    stage = new_stage(root / "scene.usda")
    add_material(stage, "/World/Looks/A", {
        "diffuseColor": ("./tex/a.png", "rgb", {}), "occlusion": ("./tex/orm.png", "r", {}),
        "roughness": ("./tex/orm.png", "g", {}), "metallic": ("./tex/orm.png", "b", {}),
        "opacity": ("./tex/flat.png", "r", {"scale": (0.5, 0.5, 0.5, 1.0), "bias": (0.1, 0.1, 0.1, 0.0)})},
        mesh="/World/MeshA")
    add_material(stage, "/World/Looks/B", {
        "diffuseColor": ("./tex/a_copy.png", "rgb", {}), "occlusion": ("./tex/orm.png", "r", {}),
        "roughness": ("./tex/orm.png", "g", {}), "metallic": ("./tex/orm.png", "b", {})}, mesh="/World/MeshB")
    stage.Save()
    return root / "scene.usda"


def test_duplicates_merge_and_constants_fold_in_the_plan(tmp_path):
    p = plan(_duplicate_scene(tmp_path), **FAST)
    (job,) = p.jobs  # A and B read the same content: one texture set
    assert [(Path(c.file).name, c.channel) for c in job.channels] == [
        ("a.png", "r"), ("a.png", "g"), ("a.png", "b"), ("orm.png", "b"), ("orm.png", "g")]  # inputs in spec order
    mats = {m.path.rsplit("/", 1)[-1]: m for m in p.materials}
    assert set(job.materials) == {"/World/Looks/A", "/World/Looks/B"}
    ta = {t.target: t for t in mats["A"].targets}
    tb = {t.target: t for t in mats["B"].targets}
    assert ta["roughness"].channel == ta["occlusion"].channel == 4 and ta["metallic"].channel == 3
    assert [tb[f"diffuseColor.{c}"].channel for c in "rgb"] == [0, 1, 2]
    (const,) = mats["A"].constants
    assert const.target == "opacity" and const.value == pytest.approx(0.5 * round(0.6 * 255) / 255 + 0.1)
    reasons = sorted((Path(f.file).name, f.channel, f.reason) for f in mats["B"].folded)
    assert reasons == [("a_copy.png", "b", "duplicate"), ("a_copy.png", "g", "duplicate"),
                       ("a_copy.png", "r", "duplicate"), ("orm.png", "r", "duplicate")]
    # the duplicate's own file is still a dependency of the build
    assert any(Path(s).name == "a_copy.png" for s in p.sources)


def test_duplicates_build_one_output_per_content_and_every_input_keeps_its_value(tmp_path):
    from bcfpipe.export import writer as E
    from bcfpipe.formats import manifest as mfst
    from bcfpipe.texset.texture_set import build_mip_chain, load_texture_set

    scene = _duplicate_scene(tmp_path)
    res = build(scene, execution=Execution(jobs=1), out=tmp_path / "out", **DRAFT)
    m = mfst.read(tmp_path / "out")
    assert m.totals.trained == 1 and m.totals.built == 2
    mats = {x.path.rsplit("/", 1)[-1]: x for x in m.materials}
    folder = tmp_path / "out" / mats["A"].outputs.folder
    em = E.load(folder)
    assert len(em.kinds) == 5  # one decoder output per distinct content
    # each input's target decodes to its own file's texels
    (dec,) = E.decode_mips(em, [(64, 64)])
    for mat in ("A", "B"):
        for t in mats[mat].targets:
            if t.channel < 0 or t.source is None:
                continue
            ts = load_texture_set([f"generic={(tmp_path / 'out' / t.source).resolve()}:{t.source_channel}"])
            ref = build_mip_chain(ts.data)[0][..., 0]
            mse = float(np.mean((dec[..., t.channel] - ref) ** 2))
            assert 10 * np.log10(1 / mse) > 20, (mat, t.target)
    # opacity is a value on the composed stage, not a texture
    stage = Usd.Stage.Open(str(res.root_layer))
    inp = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/A/Surface")).GetInput("opacity")
    assert not inp.HasConnectedSource() and inp.Get() == pytest.approx(0.5 * 153 / 255 + 0.1, abs=1e-6)
    assert UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/A/Surface")).GetInput("roughness").HasConnectedSource()


def test_srgb_decode_is_the_standard_curve():
    assert srgb_to_linear(0.0) == 0.0 and srgb_to_linear(1.0) == pytest.approx(1.0)
    assert srgb_to_linear(0.04045) == pytest.approx(0.04045 / 12.92)
    assert srgb_to_linear(0.5) == pytest.approx(0.21404, abs=1e-5)


def test_a_constant_component_of_a_modelled_input_is_a_channel_minus_one_target(tmp_path):
    """diffuseColor from a texture whose red channel is flat: g and b are decoder outputs, r is a
    target with channel -1 whose value is its bias, in the plan and in the USD layer."""
    from bcfpipe.builder.usd_layer import read_override

    a = pattern(c=3, seed=0)
    a[..., 0] = 0.4
    write_png(tmp_path / "tex" / "a.png", a)
    stage = new_stage(tmp_path / "scene.usda")
    add_material(stage, "/World/Looks/A", {"diffuseColor": ("./tex/a.png", "rgb", {})}, mesh="/World/Mesh")
    stage.Save()
    p = plan(tmp_path / "scene.usda", **FAST)
    (m,) = p.materials
    t = {x.target: x for x in m.targets}
    assert t["diffuseColor.r"].channel == -1 and t["diffuseColor.r"].scale == 0.0
    assert t["diffuseColor.r"].bias == pytest.approx(srgb_to_linear(round(0.4 * 255) / 255))
    assert (t["diffuseColor.g"].channel, t["diffuseColor.b"].channel) == (0, 1) and not m.constants
    res = build(tmp_path / "scene.usda", execution=Execution(jobs=1), out=tmp_path / "out", **FAST)
    built = Usd.Stage.Open(str(res.root_layer))
    ov = read_override(built.GetPrimAtPath("/World/Looks/A"))
    i = list(ov["bcf:outputs:targets"]).index("diffuseColor.r")
    assert ov["bcf:outputs:channels"][i] == -1 and ov["bcf:outputs:scale"][i] == 0.0
    assert ov["bcf:outputs:bias"][i] == pytest.approx(t["diffuseColor.r"].bias)


def test_a_texture_read_at_one_point_folds_to_its_value_there(tmp_path):
    """st not connected: UsdUVTexture reads its st default (0, 0) and the whole texture gives one
    value, the bilinear value at that point (texel centres at (i + 0.5) / w, v = 1 - t, repeat)."""
    a = pattern(c=3, seed=0)
    write_png(tmp_path / "tex" / "a.png", a)
    stage = new_stage(tmp_path / "scene.usda")
    add_material(stage, "/World/Looks/A", {"roughness": ("./tex/a.png", "g", {})}, mesh="/World/Mesh")
    tex = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/A/Tex_roughness"))
    tex.GetInput("st").GetAttr().SetConnections([])
    tex.GetInput("st").Set((0.0, 0.0))
    stage.Save()
    p = plan(tmp_path / "scene.usda", **FAST)
    (m,) = p.materials
    assert m.decision == "constant" and [f.reason for f in m.folded] == ["unread"]
    g = np.round(np.clip(a[..., 1], 0, 1) * 255) / 255
    corners = [g[0, 0], g[0, -1], g[-1, 0], g[-1, -1]]  # st (0, 0) is the corner of 4 texels (repeat)
    # auto resolves to sRGB for an 8-bit RGB file (as in Hydra): the value is decoded
    assert m.constants[0].value == pytest.approx(srgb_to_linear(float(np.mean(corners))), abs=1e-6)


def test_texel_facts_are_kept_so_a_replan_decodes_only_changed_textures(tmp_path, monkeypatch):
    from bcfpipe.cache.store import Cache
    from bcfpipe.scan import content

    scene = _duplicate_scene(tmp_path)
    store = Cache(tmp_path / "cache")
    reads = []
    real = content.read_stored
    monkeypatch.setattr(content, "read_stored", lambda path: reads.append(Path(path).name) or real(path))
    first = plan(scene, facts=store.facts, **FAST)
    # a_copy.png has a.png's bytes: one decode serves both
    assert sorted(set(reads)) == ["a.png", "flat.png", "orm.png"] and store.facts.count() == 3
    reads.clear()
    again = plan(scene, facts=store.facts, **FAST)
    assert reads == [] and [j.content_hash for j in again.jobs] == [j.content_hash for j in first.jobs]
    write_png(tmp_path / "tex" / "flat.png", np.full((16, 16), 0.2))  # new bytes: decoded again
    changed = plan(scene, facts=store.facts, **FAST)
    assert reads == ["flat.png"]
    (c,) = [m for m in changed.materials if m.path.endswith("/A")][0].constants
    assert c.value == pytest.approx(0.5 * round(0.2 * 255) / 255 + 0.1)
    (store.facts.dir / "zz").mkdir()
    for f in store.facts.dir.glob("*/*.json"):
        f.write_text("{ not json")  # damaged facts are recomputed, never trusted
    reads.clear()
    assert [j.content_hash for j in plan(scene, facts=store.facts, **FAST).jobs] == [j.content_hash for j in changed.jobs]
    assert len(reads) == 3
    store.clear()
    assert store.facts.count() == 0
