"""Tests for the stage scanner (bcfpipe.scan) and `bcfpipe scan`.

Core logic is tested on small stages authored in tmp_path; the decisions on
every real stage in ../shared/scenes are pinned in EXPECTED.
"""
from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pytest
from click.testing import CliRunner
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

from bcfpipe.scan import stage as scan_mod
from bcfpipe.scan.composition import parse_variant
from bcfpipe.scan.results import ScanError, StageScan, Transform2d
from bcfpipe.scan.stage import scan_stage
from bcfpipe.scan.grouping import group_materials
from bcfpipe.cli.scan import scan as scan_cmd

SCENES = Path(__file__).resolve().parents[1].parent / "shared" / "scenes"
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
needs_scenes = pytest.mark.skipif(not SCENES.is_dir(), reason=f"needs the shared scenes at {SCENES}")


def reasons(result: StageScan) -> dict[str, str]:
    """Material path -> 'model' or the skip reason."""
    return {m.path: m.reason or "model" for m in result.materials}


# ---------------------------------------------------------------------------
# Small authored stages
# ---------------------------------------------------------------------------


def touch(path: Path) -> Path:
    """An (empty) texture file: the scanner only needs it to resolve."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")
    return path


def add_material(
    stage: Usd.Stage,
    path: str,
    textures: dict[str, tuple[str, str]] | None = None,
    constants: dict[str, object] | None = None,
    shader_id: str = "UsdPreviewSurface",
) -> UsdShade.Material:
    """A material whose surface reads `textures` {input: (file, channel)} and sets `constants`."""
    mat = UsdShade.Material.Define(stage, path)
    surf = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surf.CreateIdAttr(shader_id)
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    reader = UsdShade.Shader.Define(stage, f"{path}/StReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    st_out = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    for name, (file, channel) in (textures or {}).items():
        tex = UsdShade.Shader.Define(stage, f"{path}/Tex_{name}")
        tex.CreateIdAttr("UsdUVTexture")
        if file:
            tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(st_out)
        vec = channel == "rgb"
        out = tex.CreateOutput(channel, Sdf.ValueTypeNames.Float3 if vec else Sdf.ValueTypeNames.Float)
        in_type = Sdf.ValueTypeNames.Color3f if vec else Sdf.ValueTypeNames.Float
        surf.CreateInput(name, in_type).ConnectToSource(out)
    for name, value in (constants or {}).items():
        in_type = Sdf.ValueTypeNames.Color3f if isinstance(value, tuple) else Sdf.ValueTypeNames.Float
        surf.CreateInput(name, in_type).Set(value)
    return mat


def add_mesh(
    stage: Usd.Stage, path: str, material: UsdShade.Material | None = None, purpose: str | None = None
) -> UsdGeom.Mesh:
    """A (geometry-less) mesh, optionally bound to `material` for `purpose` (None = all purposes)."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    if material is not None:
        api = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
        if purpose:
            api.Bind(material, materialPurpose=purpose)
        else:
            api.Bind(material)
    return mesh


def new_stage(tmp_path: Path, name: str = "scene.usda") -> Usd.Stage:
    stage = Usd.Stage.CreateNew(str(tmp_path / name))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    stage.SetDefaultPrim(stage.DefinePrim("/World", "Xform"))
    return stage


@pytest.fixture()
def textures(tmp_path: Path) -> dict[str, str]:
    """Relative asset paths of three existing texture files."""
    for name in ("base.png", "arm.png", "normal.png"):
        touch(tmp_path / "tex" / name)
    return {"base": "./tex/base.png", "arm": "./tex/arm.png", "normal": "./tex/normal.png"}


def test_stage_facts(tmp_path: Path) -> None:
    stage = new_stage(tmp_path)
    stage.Save()
    result = scan_stage(tmp_path / "scene.usda")
    assert (result.up_axis, result.meters_per_unit, result.default_prim) == ("Z", 0.01, "/World")
    assert result.root_layer == str((tmp_path / "scene.usda").resolve())
    assert result.materials == () and result.rendered_gprims == 0


def test_binding_decides_what_is_rendered(tmp_path: Path, textures: dict[str, str]) -> None:
    stage = new_stage(tmp_path)
    tex = {"diffuseColor": (textures["base"], "rgb")}
    names = ("Bound", "Unbound", "Hidden", "Guide", "Subset", "Preview", "Cards")
    mats = {n: add_material(stage, f"/World/Looks/{n}", tex) for n in names}
    add_mesh(stage, "/World/A", mats["Bound"])
    hidden = add_mesh(stage, "/World/Hidden/B", mats["Hidden"])
    UsdGeom.Imageable(stage.DefinePrim("/World/Hidden", "Xform")).MakeInvisible()
    add_mesh(stage, "/World/C", mats["Guide"]).CreatePurposeAttr(UsdGeom.Tokens.guide)
    mesh = add_mesh(stage, "/World/D")
    subset = UsdGeom.Subset.CreateGeomSubset(mesh, "part", UsdGeom.Tokens.face, [0], "materialBind")
    UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(mats["Subset"])
    add_mesh(stage, "/World/E", mats["Preview"], purpose=UsdShade.Tokens.preview)
    Usd.ModelAPI(stage.GetPrimAtPath("/World")).SetKind("assembly")  # models need a model parent chain
    model = stage.DefinePrim("/World/Model", "Xform")
    Usd.ModelAPI(model).SetKind("component")
    UsdGeom.ModelAPI.Apply(model).CreateModelDrawModeAttr(UsdGeom.Tokens.cards)
    add_mesh(stage, "/World/Model/F", mats["Cards"])
    assert hidden
    stage.Save()

    result = scan_stage(tmp_path / "scene.usda")
    assert reasons(result) == {
        "/World/Looks/Bound": "model",
        "/World/Looks/Unbound": "unbound",
        "/World/Looks/Hidden": "unbound",
        "/World/Looks/Guide": "unbound",
        "/World/Looks/Subset": "model",
        "/World/Looks/Preview": "model",
        "/World/Looks/Cards": "unbound",
    }
    assert result.material("/World/Looks/Preview").bound_purposes == ("preview",)
    assert result.material("/World/Looks/Bound").bound_purposes == ("full", "preview")
    everything = scan_stage(tmp_path / "scene.usda", all_materials=True)
    assert set(reasons(everything).values()) == {"model"}
    assert not everything.material("/World/Looks/Unbound").bound


def test_constant_only_material(tmp_path: Path) -> None:
    stage = new_stage(tmp_path)
    mat = add_material(stage, "/World/Looks/Plain", constants={"diffuseColor": (0.5, 0.25, 1.0), "roughness": 0.3})
    add_mesh(stage, "/World/A", mat)
    stage.Save()
    m = scan_stage(tmp_path / "scene.usda").materials[0]
    assert (m.decision, m.reason) == ("skip", "no-textures")
    assert m.input("diffuseColor").value == (0.5, 0.25, 1.0) and m.input("diffuseColor").authored
    assert m.input("roughness").value == 0.3
    ior = m.input("ior")
    assert (ior.kind, ior.value, ior.authored) == ("constant", 1.5, False)
    assert [i.name for i in m.inputs] == list(scan_mod.PREVIEW_SURFACE_INPUTS)
    assert m.channel_uses == () and m.texture_set_key == ()


def test_shared_file_channel_across_inputs(tmp_path: Path, textures: dict[str, str]) -> None:
    stage = new_stage(tmp_path)
    tex = {
        "diffuseColor": (textures["base"], "rgb"),
        "roughness": (textures["arm"], "g"),
        "metallic": (textures["arm"], "g"),
        "occlusion": (textures["arm"], "r"),
        "opacity": (textures["base"], "a"),
        "normal": (textures["normal"], "rgb"),
    }
    a = add_material(stage, "/World/Looks/A", tex)
    b = add_material(stage, "/World/Looks/B", dict(reversed(list(tex.items()))))
    add_mesh(stage, "/World/A", a)
    add_mesh(stage, "/World/B", b)
    stage.Save()
    result = scan_stage(tmp_path / "scene.usda")
    ma, mb = result.materials
    base, arm, nrm = (str((tmp_path / "tex" / n).resolve()) for n in ("base.png", "arm.png", "normal.png"))
    assert ma.decision == "model"
    want = {(arm, "g"), (arm, "r"), (base, "r"), (base, "g"), (base, "b"), (base, "a"), (nrm, "r"), (nrm, "g")}
    assert ma.channels == tuple(sorted(want))
    targets = {(u.file, u.channel, u.target) for u in ma.channel_uses}
    assert {(arm, "g", "roughness"), (arm, "g", "metallic"), (arm, "r", "occlusion")} <= targets
    assert {(base, c, f"diffuseColor.{c}") for c in "rgb"} <= targets
    assert (base, "a", "opacity") in targets
    assert {(nrm, "r", "normal.x"), (nrm, "g", "normal.y")} <= targets
    assert not any(u.target == "normal.z" for u in ma.channel_uses)
    assert ma.texture_set_key == mb.texture_set_key
    assert all(len(k) == 4 for k in ma.texture_set_key)


def test_missing_texture_gives_its_fallback_udim_skips(tmp_path: Path, textures: dict[str, str]) -> None:
    """A texture with no file, or one that does not resolve, gives its fallback (as Hydra does);
    a UDIM pattern or a time-sampled path with no default still skips the whole material."""
    stage = new_stage(tmp_path)
    good = {"diffuseColor": (textures["base"], "rgb")}
    mats = [
        add_material(stage, "/World/Looks/Missing", {**good, "roughness": ("./tex/nope.png", "r")}),
        add_material(stage, "/World/Looks/NoFile", {**good, "roughness": ("", "r")}),
        add_material(stage, "/World/Looks/Udim", {"diffuseColor": ("./tex/base_<UDIM>.png", "rgb")}),
        add_material(stage, "/World/Looks/Animated", good),
    ]
    UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Missing/Tex_roughness")).CreateInput(
        "fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(0.25, 0.5, 0.75, 1.0))
    animated_tex = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Animated/Tex_diffuseColor"))
    file_attr = animated_tex.GetInput("file").GetAttr()
    file_attr.Clear()
    file_attr.Set(Sdf.AssetPath(textures["base"]), 1.0)
    for i, m in enumerate(mats):
        add_mesh(stage, f"/World/M{i}", m)
    stage.Save()
    result = scan_stage(tmp_path / "scene.usda")
    assert reasons(result) == {"/World/Looks/Missing": "model", "/World/Looks/NoFile": "model",
                               "/World/Looks/Udim": "unresolvable-file", "/World/Looks/Animated": "unresolvable-file"}
    missing = result.material("/World/Looks/Missing")
    assert missing.input("roughness").texture.problem_code == "missing"
    assert missing.input("roughness").texture.uses_fallback
    assert any("nope.png" in w and "fallback 0.25" in w for w in missing.warnings)
    assert {u.input for u in missing.channel_uses} == {"diffuseColor"}
    assert result.material("/World/Looks/NoFile").input("roughness").texture.problem_code == "no-file"
    assert result.material("/World/Looks/Udim").input("diffuseColor").texture.problem_code == "udim"
    animated = result.material("/World/Looks/Animated").input("diffuseColor").texture
    assert (animated.problem_code, animated.animated_file) == ("time-sampled", True)

    import numpy as np
    import OpenImageIO as oiio

    texels = np.random.default_rng(0).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    assert oiio.ImageBuf(texels).write(str(tmp_path / "tex" / "base.png"))
    grouping = group_materials(tmp_path / "scene.usda", {}, result.materials, digest=False)
    mm = grouping.model_of("/World/Looks/Missing")
    assert [(c.target, c.value) for c in mm.constants] == [("roughness", 0.25)]
    nofile = grouping.model_of("/World/Looks/NoFile")
    assert [(c.target, c.value) for c in nofile.constants] == [("roughness", 0.0)]  # the spec's fallback (0, 0, 0, 1)


def test_non_preview_surfaces(tmp_path: Path, textures: dict[str, str]) -> None:
    stage = new_stage(tmp_path)
    mtlx = UsdShade.Material.Define(stage, "/World/Looks/Mtlx")
    shader = UsdShade.Shader.Define(stage, "/World/Looks/Mtlx/Std")
    shader.CreateIdAttr("ND_standard_surface_surfaceshader")
    mtlx.CreateSurfaceOutput("mtlx").ConnectToSource(shader.ConnectableAPI(), "surface")
    nd = add_material(stage, "/World/Looks/NdUniversal", shader_id="ND_UsdPreviewSurface_surfaceshader")
    other = add_material(stage, "/World/Looks/Other", shader_id="MyRendererSurface")
    UsdShade.Material.Define(stage, "/World/Looks/Empty")
    for i, m in enumerate((mtlx, nd, other)):
        add_mesh(stage, f"/World/M{i}", m)
    stage.Save()
    assert reasons(scan_stage(tmp_path / "scene.usda")) == {
        "/World/Looks/Mtlx": "materialx-only",
        "/World/Looks/NdUniversal": "materialx-only",
        "/World/Looks/Other": "not-preview-surface",
        "/World/Looks/Empty": "not-preview-surface",
    }


def test_interface_inputs_and_st_transform(tmp_path: Path, textures: dict[str, str]) -> None:
    """File and varname driven from material interface inputs; st through a UsdTransform2d."""
    stage = new_stage(tmp_path)
    mat = add_material(stage, "/World/Looks/M", {"diffuseColor": ("", "rgb")})
    mat.CreateInput("baseFile", Sdf.ValueTypeNames.Asset).Set(textures["base"])
    mat.CreateInput("uvSet", Sdf.ValueTypeNames.String).Set("uv1")
    tex = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/M/Tex_diffuseColor"))
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).ConnectToSource(mat.GetInput("baseFile"))
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
    tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set((2, 2, 2, 1))
    tex.CreateInput("fallback", Sdf.ValueTypeNames.Float3).Set((0, 0, 1))
    xf = UsdShade.Shader.Define(stage, "/World/Looks/M/Xf")
    xf.CreateIdAttr("UsdTransform2d")
    xf.CreateInput("rotation", Sdf.ValueTypeNames.Float).Set(45.0)
    xf.CreateInput("translation", Sdf.ValueTypeNames.Float2).Set((0.5, -0.2))
    reader = UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/M/StReader"))
    reader.GetInput("varname").ConnectToSource(mat.GetInput("uvSet"))
    xf.CreateInput("in", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.GetOutput("result"))
    tex.GetInput("st").ConnectToSource(xf.CreateOutput("result", Sdf.ValueTypeNames.Float2))
    add_mesh(stage, "/World/A", mat)
    stage.Save()
    m = scan_stage(tmp_path / "scene.usda").materials[0]
    t = m.input("diffuseColor").texture
    assert m.decision == "model"
    assert t.resolved_path == str((tmp_path / "tex" / "base.png").resolve())
    assert (t.st.kind, t.st.varname) == ("transform2d", "uv1")
    assert t.st.transform == Transform2d((1.0, 1.0), 45.0, (0.5, -0.2))
    assert (t.wrap_s, t.wrap_t, t.effective_wrap) == ("clamp", "useMetadata", ("clamp", "repeat"))
    assert (t.scale, t.bias, t.fallback) == ((2, 2, 2, 1), (0, 0, 0, 0), (0, 0, 1, 1))
    assert t.source_color_space == "auto"


def _variant_stage(tmp_path: Path, textures: dict[str, str]) -> Path:
    """/World/Asset: variant set 'look' (plain|fancy, default plain); 'fancy' adds a nested
    set 'finish' (matte|gloss, default gloss) and only 'gloss' binds the textured material.

    /World/Other has its own 'look' set offering only 'plain' and 'odd'.
    """
    stage = new_stage(tmp_path)
    fancy = add_material(stage, "/World/Looks/Fancy", {"diffuseColor": (textures["base"], "rgb")})
    asset = stage.DefinePrim("/World/Asset", "Xform")
    add_mesh(stage, "/World/Asset/Mesh")
    look = asset.GetVariantSets().AddVariantSet("look")
    for name in ("plain", "fancy"):
        look.AddVariant(name)
    look.SetVariantSelection("fancy")
    with look.GetVariantEditContext():
        finish = asset.GetVariantSets().AddVariantSet("finish")
        finish.AddVariant("matte")
        finish.AddVariant("gloss")
        finish.SetVariantSelection("gloss")
        with finish.GetVariantEditContext():
            UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath("/World/Asset/Mesh")).Bind(fancy)
    look.SetVariantSelection("plain")
    other = stage.DefinePrim("/World/Other", "Xform")
    olook = other.GetVariantSets().AddVariantSet("look")
    olook.AddVariant("plain")
    olook.AddVariant("odd")
    olook.SetVariantSelection("odd")
    stage.Save()
    return tmp_path / "scene.usda"


def test_variants_in_session_layer(tmp_path: Path, textures: dict[str, str]) -> None:
    path = _variant_stage(tmp_path, textures)
    before = path.read_text()
    assert reasons(scan_stage(path))["/World/Looks/Fancy"] == "unbound"
    fancy = scan_stage(path, {"look": "fancy"})
    assert reasons(fancy)["/World/Looks/Fancy"] == "model"  # nested finish defaults to gloss
    # /World/Other's 'look' has no 'fancy': left alone.
    assert fancy.variant_selections == (("/World/Asset", "look", "fancy"),)
    matte = scan_stage(path, {"look": "fancy", "finish": "matte"})
    assert reasons(matte)["/World/Looks/Fancy"] == "unbound"
    # 'finish' only exists once 'look=fancy' is selected: found on the second pass.
    assert matte.variant_selections == (("/World/Asset", "finish", "matte"), ("/World/Asset", "look", "fancy"))
    assert path.read_text() == before
    with pytest.raises(ScanError, match="offers fancy, odd, plain"):
        scan_stage(path, {"look": "shiny"})
    with pytest.raises(ScanError, match="not found on any prim"):
        scan_stage(path, {"nope": "x"})


def test_parse_variant() -> None:
    assert parse_variant("modelVariant=Fancy") == ("modelVariant", "Fancy")
    assert parse_variant(" a = b=c ") == ("a", "b=c")
    for bad in ("modelVariant", "=x", "x=", ""):
        with pytest.raises(ScanError, match="SET=VALUE"):
            parse_variant(bad)


def test_instanced_materials_reported_once(tmp_path: Path, textures: dict[str, str]) -> None:
    asset = Usd.Stage.CreateNew(str(tmp_path / "asset.usda"))
    root = asset.DefinePrim("/Asset", "Xform")
    asset.SetDefaultPrim(root)
    mat = add_material(asset, "/Asset/Looks/M", {"diffuseColor": (textures["base"], "rgb")})
    add_mesh(asset, "/Asset/Mesh", mat)
    asset.Save()
    stage = new_stage(tmp_path)
    for name in ("I1", "I2", "I3"):
        prim = stage.DefinePrim(f"/World/{name}")
        prim.GetReferences().AddReference("./asset.usda")
        prim.SetInstanceable(True)
    stage.Save()
    result = scan_stage(tmp_path / "scene.usda")
    assert len(result.materials) == 1
    m = result.materials[0]
    assert m.path == "/World/I1/Looks/M" and m.aliases == ("/World/I2/Looks/M", "/World/I3/Looks/M")
    assert (m.decision, m.bound) == ("model", True)
    assert m.input("diffuseColor").texture.resolved_path == str((tmp_path / "tex" / "base.png").resolve())
    assert result.rendered_gprims == 3


def test_per_material_error_is_a_skip(
    tmp_path: Path, textures: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    stage = new_stage(tmp_path)
    for name in ("Good", "Bad"):
        mat = add_material(stage, f"/World/Looks/{name}", {"diffuseColor": (textures["base"], "rgb")})
        add_mesh(stage, f"/World/{name}", mat)
    stage.Save()
    real = scan_mod.scan_material

    def flaky(material, *args, **kwargs):
        if material.GetPath().name == "Bad":
            raise RuntimeError("boom\nsecond line")
        return real(material, *args, **kwargs)

    monkeypatch.setattr(scan_mod, "scan_material", flaky)
    result = scan_stage(tmp_path / "scene.usda")
    bad = result.material("/World/Looks/Bad")
    assert (bad.reason, bad.message, bad.bound) == ("scan-error", "scan-error: boom", True)
    assert result.material("/World/Looks/Good").decision == "model"


def test_unreadable_stages(tmp_path: Path) -> None:
    with pytest.raises(ScanError, match="no such file"):
        scan_stage(tmp_path / "missing.usda")
    garbage = tmp_path / "garbage.usda"
    garbage.write_text("#usda 1.0\ndef Xform \"A\" {{{{ nonsense\n")
    with pytest.raises(ScanError, match="cannot read stage") as info:
        scan_stage(garbage)
    assert "\n" not in str(info.value)
    with pytest.raises(ScanError, match="cannot read stage"):
        scan_stage(touch(tmp_path / "notes.txt"))


def test_broken_composition_is_reported_not_raised(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    layer = tmp_path / "broken.usda"
    layer.write_text(
        '#usda 1.0\n(\n    subLayers = [@./missing_sub.usda@]\n)\n'
        'def Xform "W" (prepend references = @./missing_ref.usda@) {}\n'
        'def Mesh "M" (prepend apiSchemas = ["MaterialBindingAPI"])\n{\n    rel material:binding = </Looks/Gone>\n}\n'
    )
    result = scan_stage(layer)
    assert len(result.composition_errors) == 2
    assert any("missing_ref.usda" in e for e in result.composition_errors)
    assert result.dangling_bindings == ("/Looks/Gone",)
    assert capfd.readouterr().err == ""  # USD's own warnings are captured, not printed


def test_to_dict_is_json(tmp_path: Path, textures: dict[str, str]) -> None:
    stage = new_stage(tmp_path)
    add_mesh(stage, "/World/A", add_material(stage, "/World/Looks/A", {"normal": (textures["normal"], "rgb")}))
    stage.Save()
    d = json.loads(json.dumps(scan_stage(tmp_path / "scene.usda").to_dict()))
    m = d["materials"][0]
    assert m["decision"] == "model" and m["inputs"][11]["name"] == "normal"
    assert sorted(k[2] for k in m["texture_set_key"]) == ["normal.x", "normal.y"]
    assert d["summary"] == {"materials": 1, "model": 1, "skip": 0}


# ---------------------------------------------------------------------------
# CLI
# ---------------------------------------------------------------------------


def test_cli_json_and_table(tmp_path: Path, textures: dict[str, str]) -> None:
    import numpy as np
    import OpenImageIO as oiio

    # a real image: an empty file is refused by name (the build would not model it)
    texels = np.random.default_rng(0).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    assert oiio.ImageBuf(texels).write(str(tmp_path / "tex" / "base.png"))
    stage = new_stage(tmp_path)
    add_mesh(stage, "/World/A", add_material(stage, "/World/Looks/A", {"diffuseColor": (textures["base"], "rgb")}))
    add_material(stage, "/World/Looks/Spare")
    stage.Save()
    runner = CliRunner()
    res = runner.invoke(scan_cmd, [str(tmp_path / "scene.usda"), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert {m["path"]: m["reason"] for m in data["materials"]} == {"/World/Looks/A": None, "/World/Looks/Spare": "unbound"}
    res = runner.invoke(scan_cmd, [str(tmp_path / "scene.usda")])
    assert res.exit_code == 0 and "/World/Looks/Spare" in res.stdout and "unbound" in res.stdout
    assert "conclusion: a build trains 1 texture set(s) for 1 material(s)" in res.stdout
    res = runner.invoke(scan_cmd, [str(tmp_path / "scene.usda"), "--all-materials", "--json"])
    assert json.loads(res.stdout)["summary"]["model"] == 1  # Spare has no textures


def test_cli_bad_input_exit_2(tmp_path: Path) -> None:
    runner = CliRunner()
    res = runner.invoke(scan_cmd, [str(tmp_path / "missing.usda"), "--json"])
    assert res.exit_code == 2
    assert res.stdout == ""
    assert res.stderr.strip().count("\n") == 0 and "no such file" in res.stderr
    assert "Traceback" not in res.output
    stage = new_stage(tmp_path)
    stage.Save()
    res = runner.invoke(scan_cmd, [str(tmp_path / "scene.usda"), "--variant", "novalue"])
    assert res.exit_code == 2 and "SET=VALUE" in res.stderr
    res = runner.invoke(scan_cmd, [str(tmp_path / "scene.usda"), "--variant", "a=b"])
    assert res.exit_code == 2 and "not found on any prim" in res.stderr


# ---------------------------------------------------------------------------
# The shared scenes
# ---------------------------------------------------------------------------

_OPENUSD = "openusd_preview_surface_tests/testUsdImagingGLPreviewSurface/"
_UDIMS = "openusd_preview_surface_tests/testUsdImagingGLUsdUdims/"
_CARS = "usdwg_vehicles/USD_Mini_Car_Kit/"

#: Decision counts ('model' or skip reason) for every stage under ../shared/scenes, default variants.
EXPECTED: dict[str, dict[str, int]] = {
    "openusd_preview_surface_tests/testUsdImagingGLDisplacement/testUsdImagingGLDisplacement.usda": {"model": 1},
    _OPENUSD + "testPreviewSurfaceAnimated.usda": {"unresolvable-file": 1},
    _OPENUSD + "testPreviewSurfaceConnectedScalar.usda": {"no-textures": 1},
    _OPENUSD + "testPreviewSurfaceDisplacement.geom.usda": {},
    _OPENUSD + "testPreviewSurfaceDisplacement.usda": {"model": 1},
    _OPENUSD + "testPreviewSurfaceFallback.usda": {"no-textures": 100},
    _OPENUSD + "testPreviewSurfaceFallbackPrimvar.usda": {"no-textures": 1},
    _OPENUSD + "testPreviewSurfaceFallbackTexture.usda": {"model": 1},  # the texture gives its fallback
    _OPENUSD + "testPreviewSurfaceInstancedMaterial.usda": {"no-textures": 2},
    _OPENUSD + "testPreviewSurfaceMaterialInterface.usda": {"no-textures": 1},
    _OPENUSD + "testPreviewSurfaceNormalMap.usda": {"model": 1},
    _OPENUSD + "testPreviewSurfaceOpacityThreshold.usda": {"model": 6},
    _OPENUSD + "testPreviewSurfacePrimvarFallback.usda": {"no-textures": 1},
    _OPENUSD + "testPreviewSurfacePrimvarReaderOpacity.usda": {"no-textures": 1},
    _OPENUSD + "testPreviewSurfacePrimvars.usda": {"no-textures": 100},
    _OPENUSD + "testPreviewSurfaceSourceColorSpace.usda": {"model": 2},
    _OPENUSD + "testPreviewSurfaceSpecular.usda": {"no-textures": 10},
    _OPENUSD + "testPreviewSurfaceTexture.usda": {"model": 1},
    _OPENUSD + "testPreviewSurfaceTextureFallback.usda": {"model": 1},  # the texture gives its fallback
    _OPENUSD + "testPreviewSurfaceTextureNoFile.usda": {"model": 1},  # the texture gives its fallback
    _OPENUSD + "testPreviewSurfaceTextureOpacity.usda": {"model": 1},
    _OPENUSD + "testPreviewSurfaceTextureScaleAndBias.usda": {"model": 4},
    _OPENUSD + "testPreviewSurfaceTextureWithToken.usda": {"model": 1},  # the texture gives its fallback
    _OPENUSD + "testPreviewSurfaceTransform2d.usda": {"model": 4},
    _OPENUSD + "testPreviewSurfaceTranslucent.usda": {"no-textures": 3},
    _UDIMS + "usdUdims.usda": {"unresolvable-file": 1},
    _UDIMS + "usdUdims.usdz": {"unresolvable-file": 1},
    _UDIMS + "usdUdimsScaleAndBias.usda": {"unresolvable-file": 1},
    _UDIMS + "usdUdimsSymlinked.usda": {"unresolvable-file": 1},
    _UDIMS + "usdUdimsTextureFallback.usda": {"unresolvable-file": 1},
    "gltf_water_bottle/water_bottle.usda": {"model": 1},
    "pablode_cornell_box/display-color/cornell-box.usda": {},
    "pablode_cornell_box/mtlx-usdshade/cornell-box.usda": {"materialx-only": 4},
    "pablode_cornell_box/usdpreviewsurface/cornell-box.usda": {"no-textures": 4},
    "usdwg_roughness_test/RoughnessTest.usdz": {"model": 6},
    # 35 teapots x 2 materials; only the 7 drawn with drawMode=default render geometry.
    "usdwg_teapot/DrawModes.usd": {"model": 1, "no-textures": 6, "unbound": 63},
    "usdwg_teapot/Teapot.usd": {"no-textures": 1, "unbound": 1},
    "usdwg_teapot/Teapot_Geometry.usd": {},
    "usdwg_teapot/Teapot_Materials.usd": {"no-textures": 1, "unbound": 1},
    "usdwg_teapot/Teapot_Payload.usd": {"no-textures": 1, "unbound": 1},
    "usdwg_teapot/geo/FancyTeapot.usd": {},
    "usdwg_teapot/geo/UtahTeapot.usd": {},
    "usdwg_texture_file_formats/_scene.usda": {"model": 2},  # no file: fallbacks
    "usdwg_texture_file_formats/all_files.usda": {"model": 16},
    "usdwg_texture_file_formats/jpeg_cmyk_8-bit.usda": {"model": 2},
    "usdwg_texture_file_formats/jpeg_grayscale_8-bit.usda": {"model": 2},
    "usdwg_texture_file_formats/jpeg_rgb_8-bit.usda": {"model": 2},
    "usdwg_texture_file_formats/png_grayscale_16-bit.usda": {"model": 2},
    "usdwg_texture_file_formats/png_grayscale_8-bit.usda": {"model": 2},
    "usdwg_texture_file_formats/png_rgb_16-bit.usda": {"model": 2},
    "usdwg_texture_file_formats/png_rgb_32-bit.usda": {"model": 2},
    "usdwg_texture_file_formats/png_rgb_8-bit.usda": {"model": 2},
    "usdwg_texture_transform_test/TextureTransformTest.usd": {"model": 9},
    _CARS + "assets/vehicles/4wd/asset/4wdBodyAsset.usda": {"model": 6},
    _CARS + "assets/vehicles/4wd/asset/4wdFullAsset.usda": {"model": 14},
    _CARS + "assets/vehicles/4wd/geo/4wdGeo.usd": {},
    _CARS + "assets/vehicles/ambulance/asset/ambulanceBodyAsset.usda": {"model": 7},
    _CARS + "assets/vehicles/ambulance/asset/ambulanceFullAsset.usda": {"model": 15},
    _CARS + "assets/vehicles/ambulance/geo/ambulanceGeo.usd": {},
    _CARS + "assets/vehicles/formula/asset/formulaBodyAsset.usda": {"model": 4},
    _CARS + "assets/vehicles/formula/asset/formulaFullAsset.usda": {"model": 16},
    _CARS + "assets/vehicles/formula/geo/formulaGeo.usda": {},
    _CARS + "assets/vehicles/sedan/asset/sedanBodyAsset.usda": {"model": 5},
    _CARS + "assets/vehicles/sedan/asset/sedanFullAsset.usda": {"model": 13},
    _CARS + "assets/vehicles/sedan/geo/sedanGeo.usda": {},
    _CARS + "assets/vehicles/tractor/asset/tractorBodyAsset.usda": {"model": 6},
    _CARS + "assets/vehicles/tractor/asset/tractorFullAsset.usda": {"model": 14},
    _CARS + "assets/vehicles/tractor/geo/tractorGeo.usd": {},
    _CARS + "assets/vehicles/truckFlat/asset/truckFlatBodyAsset.usda": {"model": 6},
    _CARS + "assets/vehicles/truckFlat/asset/truckFlatFullAsset.usda": {"model": 14},
    _CARS + "assets/vehicles/truckFlat/geo/flatTruckGeo.usd": {},
    _CARS + "assets/vehicles/van/asset/vanBodyAsset.usda": {"model": 6},
    _CARS + "assets/vehicles/van/asset/vanFullAsset.usda": {"model": 14},
    _CARS + "assets/vehicles/van/geo/vanGeo.usd": {},
    _CARS + "assets/vehicles/vehicleVariants.usda": {"model": 14},
    _CARS + "assets/wheels/wheelBlack/asset/wheelBlackAsset.usda": {"model": 2},
    _CARS + "assets/wheels/wheelBlack/geo/wheelBlackGeo.usd": {},
    _CARS + "assets/wheels/wheelLargeRim/asset/wheelLargeRimAsset.usda": {"model": 2},
    _CARS + "assets/wheels/wheelLargeRim/geo/wheelLargeRimGeo.usd": {},
    _CARS + "assets/wheels/wheelNormal/asset/wheelNormalAsset.usda": {"model": 2},
    _CARS + "assets/wheels/wheelNormal/geo/wheelNormalGeo.usda": {},
    _CARS + "assets/wheels/wheelRed/asset/wheelRedAsset.usda": {"model": 3},
    _CARS + "assets/wheels/wheelRed/geo/wheelRedGeo.usd": {},
    _CARS + "assets/wheels/wheelVariants.usda": {"model": 2},
    _CARS + "assets/wheels/wheelVintage/asset/wheelVintageAsset.usda": {"model": 3},
    _CARS + "assets/wheels/wheelVintage/geo/wheelVintageGeo.usd": {},
    _CARS + "assets/wheels/wheelWide/asset/wheelWideAsset.usda": {"model": 2},
    _CARS + "assets/wheels/wheelWide/geo/wheelWideGeo.usd": {},
    _CARS + "materials/backLight.usda": {"unbound": 1},
    _CARS + "materials/blue.usda": {"unbound": 1},
    _CARS + "materials/frontLight.usda": {"unbound": 1},
    _CARS + "materials/green.usda": {"unbound": 1},
    _CARS + "materials/lightGrey.usda": {"unbound": 1},
    _CARS + "materials/mediumGrey.usda": {"unbound": 1},
    _CARS + "materials/red.usda": {"unbound": 1},
    _CARS + "materials/white.usda": {"unbound": 1},
    _CARS + "materials/window.usda": {"unbound": 1},
}


def _stage_files() -> list[Path]:
    return sorted(p for p in SCENES.rglob("*") if p.suffix in USD_SUFFIXES) if SCENES.is_dir() else []


def scene(rel: str, **kwargs: object) -> StageScan:
    return scan_stage(SCENES / rel, **kwargs)  # type: ignore[arg-type]


@needs_scenes
@pytest.mark.shared
def test_every_shared_stage_scans() -> None:
    """Every .usd/.usda/.usdc/.usdz scans without raising, to JSON, and is pinned in EXPECTED."""
    files = _stage_files()
    assert {str(p.relative_to(SCENES)) for p in files} == set(EXPECTED), "a stage was added or removed"
    for path in files:
        result = scan_stage(path)
        json.dumps(result.to_dict())
        assert not any(m.reason == "scan-error" for m in result.materials), path


@needs_scenes
@pytest.mark.shared
@pytest.mark.parametrize("rel", sorted(EXPECTED))
def test_shared_stage_decisions(rel: str) -> None:
    result = scene(rel)
    assert dict(Counter(m.reason or "model" for m in result.materials)) == EXPECTED[rel]


@needs_scenes
@pytest.mark.shared
def test_teapot_textured_material_needs_fancy_variant() -> None:
    default = scene("usdwg_teapot/Teapot.usd")
    assert reasons(default) == {"/Teapot/Materials/PorcelainFlowers": "unbound", "/Teapot/Materials/Ceramic": "no-textures"}
    assert (default.up_axis, default.meters_per_unit, default.default_prim) == ("Y", 1.0, "/Teapot")
    fancy = scene("usdwg_teapot/Teapot.usd", variants={"modelVariant": "Fancy"})
    assert fancy.variant_selections == (("/Teapot", "modelVariant", "Fancy"),)
    assert reasons(fancy) == {"/Teapot/Materials/PorcelainFlowers": "model", "/Teapot/Materials/Ceramic": "unbound"}
    everything = scene("usdwg_teapot/Teapot.usd", all_materials=True)
    assert reasons(everything)["/Teapot/Materials/PorcelainFlowers"] == "model"
    for result in (fancy, everything):
        m = result.material("/Teapot/Materials/PorcelainFlowers")
        tex = {i.name: (Path(i.texture.resolved_path).name, i.texture.channel) for i in m.texture_inputs}
        assert tex == {
            "diffuseColor": ("tea_set_01_diff_2k.jpg", "rgb"),
            "occlusion": ("tea_set_01_arm_2k.jpg", "r"),
            "roughness": ("tea_set_01_arm_2k.jpg", "g"),
            "metallic": ("tea_set_01_arm_2k.jpg", "b"),
        }
        assert m.input("ior").value == pytest.approx(1.327)
        assert m.input("diffuseColor").texture.source_color_space == "auto"
        assert m.input("roughness").texture.source_color_space == "raw"
        assert len(m.channels) == 6 and len(m.channel_uses) == 6


@needs_scenes
@pytest.mark.shared
def test_drawmodes_copies_share_one_texture_set() -> None:
    result = scene("usdwg_teapot/DrawModes.usd", all_materials=True)
    porcelain = [m for m in result.materials if m.path.endswith("/PorcelainFlowers")]
    assert len(porcelain) == 35 and len({m.texture_set_key for m in porcelain}) == 1
    bound = scene("usdwg_teapot/DrawModes.usd").to_model
    assert [m.path for m in bound] == ["/World/FancyTeapot_0/Materials/PorcelainFlowers"]


@needs_scenes
@pytest.mark.shared
def test_cornell_box_has_nothing_to_model() -> None:
    for variant in ("display-color", "mtlx-usdshade", "usdpreviewsurface"):
        assert scene(f"pablode_cornell_box/{variant}/cornell-box.usda").to_model == ()
    mtlx = scene("pablode_cornell_box/mtlx-usdshade/cornell-box.usda")
    assert {m.reason for m in mtlx.materials} == {"materialx-only"}
    assert all(m.bound for m in mtlx.materials)
    assert "mtlx" in mtlx.materials[0].message


@needs_scenes
@pytest.mark.shared
def test_texture_file_formats_channels() -> None:
    result = scene("usdwg_texture_file_formats/all_files.usda")
    assert len(result.to_model) == 16
    for m in result.materials:
        stem = m.path.split("/")[3]  # e.g. jpeg_cmyk_8bit
        fmt, kind, bits = stem.split("_")
        expected_file = f"{fmt}_{kind}_{bits[:-3]}-bit.{'jpg' if fmt == 'jpeg' else 'png'}"
        uses = {(Path(u.file).name, u.channel, u.target) for u in m.channel_uses}
        want = {(expected_file, c, f"diffuseColor.{c}") for c in "rgb"}
        if m.path.endswith("WithOpacity"):
            want.add((expected_file, "a", "opacity"))
        assert uses == want, m.path
    unauthored = scene("usdwg_texture_file_formats/_scene.usda")
    assert {i.texture.problem_code for m in unauthored.materials for i in m.texture_inputs} == {"no-file"}
    assert all(i.texture.uses_fallback for m in unauthored.materials for i in m.texture_inputs)


@needs_scenes
@pytest.mark.shared
def test_roughness_usdz_resolves_inside_package() -> None:
    result = scene("usdwg_roughness_test/RoughnessTest.usdz")
    package = str(SCENES / "usdwg_roughness_test" / "RoughnessTest.usdz")
    for m in result.materials:
        for inp in m.texture_inputs:
            assert inp.texture.ok and inp.texture.resolved_path.startswith(package + "[0/"), inp.texture
    channel = {"Tex000": ("r", "sRGB"), "Tex033": ("g", "raw"), "Tex066": ("b", "sRGB")}
    for name, (c, space) in channel.items():
        m = result.material(f"/Roughness/Materials/{name}")
        rough = m.input("roughness").texture
        assert (Path(rough.asset_path).name, rough.channel, rough.source_color_space) == ("roughness.tga", c, space)
        assert any("tagged sRGB" in w for w in m.warnings) == (space == "sRGB")
    # roughness-spec.png is read as sRGB for .rgb and (mostly) raw for .a: keys keep the colour space
    uses = result.material("/Roughness/Materials/Tex000").channel_uses
    spec = {(u.channel, u.color_space) for u in uses if "spec" in u.file}
    assert spec == {("r", "sRGB"), ("g", "sRGB"), ("b", "sRGB"), ("a", "raw")}
    const = result.material("/Roughness/Materials/Const033")
    assert const.input("roughness").kind == "constant" and const.decision == "model"


@needs_scenes
@pytest.mark.shared
def test_openusd_bad_inputs_reported_per_material() -> None:
    cases = {
        _OPENUSD + "testPreviewSurfaceAnimated.usda": "time-sampled",
        _UDIMS + "usdUdims.usda": "udim",
        _UDIMS + "usdUdims.usdz": "udim",
        _UDIMS + "usdUdimsTextureFallback.usda": "udim",
    }
    for rel, code in cases.items():
        (m,) = scene(rel).materials
        assert m.reason == "unresolvable-file" and m.message.startswith("diffuseColor: "), rel
        assert m.input("diffuseColor").texture.problem_code == code, rel
    fallbacks = {  # a missing file, or none: the texture's fallback, as Hydra draws it
        _OPENUSD + "testPreviewSurfaceFallbackTexture.usda": ("missing", (0.0, 0.0, 0.0)),
        _OPENUSD + "testPreviewSurfaceTextureFallback.usda": ("missing", (0.0, 0.0, 1.0)),
        _OPENUSD + "testPreviewSurfaceTextureWithToken.usda": ("missing", None),
        _OPENUSD + "testPreviewSurfaceTextureNoFile.usda": ("no-file", (0.0, 0.0, 1.0)),
    }
    for rel, (code, rgb) in fallbacks.items():
        result = scene(rel)
        (m,) = result.materials
        assert m.decision == "model" and m.input("diffuseColor").texture.problem_code == code, rel
        grouping = group_materials(SCENES / rel, {}, result.materials, digest=False)
        assert grouping.outcome(m)[0] == "constant", rel
        values = {c.target: c.value for c in grouping.model_of(m.path).constants}
        if rgb is not None:
            assert tuple(values[f"diffuseColor.{c}"] for c in "rgb") == rgb, rel
    # Bound only through a preview-purpose collection binding.
    (m,) = scene(_OPENUSD + "testPreviewSurfaceTextureNoFile.usda").materials
    assert m.bound_purposes == ("preview",)
    wrap = m.input("diffuseColor").texture
    assert (wrap.wrap_s, wrap.wrap_t, wrap.fallback) == ("mirror", "repeat", (0, 0, 1, 1))


@needs_scenes
@pytest.mark.shared
def test_openusd_normal_displacement_scale_bias() -> None:
    (m,) = scene(_OPENUSD + "testPreviewSurfaceNormalMap.usda").materials
    t = m.input("normal").texture
    assert (t.scale, t.bias, t.source_color_space) == ((2, 2, 2, 1), (-1, -1, -1, 0), "raw")
    assert [u.target for u in m.channel_uses] == ["normal.x", "normal.y"]
    (m,) = scene(_OPENUSD + "testPreviewSurfaceDisplacement.usda").materials
    assert m.input("displacement").texture.channel == "r"
    assert ("displacement" in {u.target for u in m.channel_uses})
    (inst, *_rest) = scene(_OPENUSD + "testPreviewSurfaceInstancedMaterial.usda").materials
    assert inst.input("diffuseColor").kind == "primvar"


@needs_scenes
@pytest.mark.shared
def test_texture_transform_test() -> None:
    result = scene("usdwg_texture_transform_test/TextureTransformTest.usd")
    assert result.meters_per_unit == 0.01
    by_name = {m.path.rsplit("/", 1)[1]: m.input("diffuseColor").texture for m in result.materials}
    offset = by_name["Offset_U_53148"]
    assert offset.st.kind == "transform2d" and offset.st.varname == "st"
    assert offset.st.transform == Transform2d((1.0, 1.0), 0.0, (0.5, 0.0))
    assert by_name["All_53140"].st.transform.scale == (1.5, 1.5)
    assert by_name["All_53140"].st.transform.rotation == pytest.approx(17.188734)
    assert offset.effective_wrap == ("clamp", "clamp")
    assert by_name["Correct_53142"].st.kind == "primvar"
    assert by_name["Correct_53142"].effective_wrap == ("repeat", "repeat")
    assert all(t.ok and " " in Path(t.resolved_path).name for t in by_name.values())


@needs_scenes
@pytest.mark.shared
def test_vehicles_variants_and_unconnected_st() -> None:
    rel = _CARS + "assets/vehicles/vehicleVariants.usda"
    van = scene(rel, variants={"wheels": "van"})
    assert van.variant_selections == (("/vehicleVariant", "wheels", "van"),)
    assert all(m.path.startswith("/vehicleVariant/vanFullAsset/") for m in van.materials)
    red = scene(rel, variants={"wheels": "wheelRed"})
    assert [p for p, _, _ in red.variant_selections] == [f"/vehicleVariant/tractorFullAsset/wheel{i}" for i in range(1, 5)]
    assert sum(m.path.endswith("/red/redMaterial") for m in red.to_model) == 4
    m = red.to_model[0]
    tex = m.input("diffuseColor").texture
    assert tex.st.kind == "constant" and tex.st.value == (0.0, 0.0)
    assert any("st not connected" in w for w in m.warnings)
    # duplicated material definitions collapse to a handful of texture sets
    assert len({m.texture_set_key for m in red.to_model}) < len(red.to_model)
    geo = scene(_CARS + "assets/vehicles/van/geo/vanGeo.usd")
    assert "/Materials/blueMax" in geo.dangling_bindings


@needs_scenes
@pytest.mark.shared
def test_cli_on_teapot() -> None:
    runner = CliRunner()
    path = str(SCENES / "usdwg_teapot" / "Teapot.usd")
    res = runner.invoke(scan_cmd, [path, "--variant", "modelVariant=Fancy", "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert [m["path"] for m in data["materials"] if m["decision"] == "model"] == ["/Teapot/Materials/PorcelainFlowers"]
    res = runner.invoke(scan_cmd, [path, "--variant", "modelVariant=Nope"])
    assert res.exit_code == 2 and "offers Fancy, Utah" in res.stderr
