"""Addressing as USD says it (issue 57, item 1): one texture read by a repeat, a clamp, a
clamp-S/repeat-T and a clamp-S/mirror-T material. Each addressing is its own texture set; a neural
material samples its features with its sources' wrap per axis and is trained for it; material.json
and bcf:wrapS / bcf:wrapT say it; `bcfpipe render --compare` matches the original per material, with
--layout neural and with the default layout; and the independent rebuild of tests/test_t0_layers.py
(OpenImageIO, numpy, onnxruntime: material.json alone) agrees with bcfpipe's decode, with the GLSL
decoder and with the source's own addressing at and beyond the borders.

Real USD, real builds (tiny profile, draft preset, a 64² texture), real OpenGL through EGL.
"""
from __future__ import annotations

import json
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

from bcfpipe.builder import Execution, build
from bcfpipe.cli import main
from bcfpipe.config import TrainingOptions
from bcfpipe.scan.grouping import group_materials
from bcfpipe.scan.stage import scan_stage
from bcfpipe.scan.texture_sets import material_wrap
from test_render import write_png
from test_t0_layers import REBUILD_TOL, bilinear, rebuild_at

N = 64  # texels a side
#: (S, T) per material, as its UsdUVTexture's wrapS / wrapT say
MATERIALS = {"Repeat": ("repeat", "repeat"), "Clamp": ("clamp", "clamp"),
             "ClampRepeat": ("clamp", "repeat"), "ClampMirror": ("clamp", "mirror")}
#: what a build before issue 57 sampled: repeat unless every wrap clamps, mirror as repeat
BEFORE = {"Repeat": ("repeat", "repeat"), "Clamp": ("clamp", "clamp"),
          "ClampRepeat": ("repeat", "repeat"), "ClampMirror": ("repeat", "repeat")}
ST_RANGE = (-0.5, 1.5)  # each quad's st: the texture in its middle, addressing all around it
SIZE = "256x192"
MIN_PSNR_DB = 35.0  # the bar for `render --compare`, each material, each layout
BORDER_MEAN_ABS = 0.03  # the model against its source beyond the borders (stored units, [0, 1])
GL_TOL = 1e-2  # GLSL decode against the rebuild: 8-bit filter fractions on the GPU's side


def texture() -> np.ndarray:
    """(N, N, 3): smooth inside, different across each pair of opposite borders (u = 0 vs 1, v = 0
    vs 1), so that repeat, clamp and mirror each give their own values past the edges."""
    y, x = (np.mgrid[0:N, 0:N] + 0.5) / N
    return np.stack([0.5 + 0.35 * np.cos(np.pi * x), 0.5 + 0.35 * np.cos(np.pi * y), 0.25 + 0.5 * x * y], -1)


def wrap_stage(root: Path) -> Path:
    """Four quads side by side, one per material of MATERIALS, each with st over ST_RANGE and a
    camera straight above it that it fills; every material reads the same PNG for diffuseColor."""
    (root / "tex").mkdir(parents=True)
    write_png(root / "tex" / "ramps.png", texture())
    stage = Usd.Stage.CreateNew(str(root / "wrap.usda"))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(stage.GetPrimAtPath("/World"))
    a, b = ST_RANGE
    for i, (name, (ws, wt)) in enumerate(MATERIALS.items()):
        base = f"/World/Looks/{name}"
        mat = UsdShade.Material.Define(stage, base)
        surf = UsdShade.Shader.Define(stage, f"{base}/Surface")
        surf.CreateIdAttr("UsdPreviewSurface")
        reader = UsdShade.Shader.Define(stage, f"{base}/St")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
        reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
        tex = UsdShade.Shader.Define(stage, f"{base}/Tex")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./tex/ramps.png")
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
        tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set(ws)
        tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set(wt)
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
        surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.6)
        mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
        x = 3.0 * i
        mesh = UsdGeom.Mesh.Define(stage, f"/World/Quad{name}")
        mesh.CreatePointsAttr([(x - 1, 0, -1), (x + 1, 0, -1), (x + 1, 0, 1), (x - 1, 0, 1)])
        mesh.CreateFaceVertexCountsAttr([4])
        mesh.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
        mesh.CreateSubdivisionSchemeAttr("none")
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
        st.Set([(a, b), (b, b), (b, a), (a, a)])
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
        cam = UsdGeom.Camera.Define(stage, f"/World/Cam{name}")
        cam.AddTranslateOp().Set(Gf.Vec3d(x, 3.3, 0))
        cam.AddRotateXOp().Set(-90.0)
        cam.CreateFocalLengthAttr(35.0)
    stage.GetRootLayer().Save()
    return root / "wrap.usda"


def _build(tmp_path_factory, layout: str | None):
    root = tmp_path_factory.mktemp(f"wrap-{layout or 'default'}")
    options = dict(profile="tiny", preset="draft", seed=0) | ({"layout": layout} if layout else {})
    result = build(wrap_stage(root), execution=Execution(jobs=1), training=TrainingOptions(**options))
    assert result.exit_code == 0, [(m.path, m.status, m.message) for m in result.manifest.materials]
    return result


@pytest.fixture(scope="module")
def builds(tmp_path_factory):
    """{"neural": ..., "default": ...}: the scene built with --layout neural and with the default."""
    return {"neural": _build(tmp_path_factory, "neural"), "default": _build(tmp_path_factory, None)}


def _folders(result) -> dict[str, Path]:
    """Each built material's folder (OUT/materials/<job>), by material name."""
    return {m.path.rsplit("/", 1)[1]: result.out / "materials" / m.job for m in result.manifest.materials
            if m.job is not None}


# ---------------------------------------------------------------------------------------- scan


def test_each_addressing_is_its_own_texture_set(tmp_path) -> None:
    """The scan groups by (S, T): four sets from one file; none warns."""
    scene = wrap_stage(tmp_path)
    result = scan_stage(scene)
    grouping = group_materials(scene, {}, result.materials, digest=False)
    by_material = {g.materials[0].rsplit("/", 1)[1]: g for g in grouping.groups}
    assert sorted(by_material) == sorted(MATERIALS) and all(len(g.materials) == 1 for g in grouping.groups)
    for name, wrap in MATERIALS.items():
        mm = grouping.model_of(f"/World/Looks/{name}")
        assert mm.wrap == wrap and not [w for w in mm.warnings if "wrap" in w], (name, mm.wrap, mm.warnings)


def test_inputs_that_disagree_are_named_with_what_was_chosen() -> None:
    wrap, warning = material_wrap([("diffuseColor", ("clamp", "repeat")), ("roughness", ("clamp", "mirror")),
                                   ("metallic", ("repeat", "mirror"))])
    assert wrap == ("clamp", "mirror")
    assert warning == ("inputs disagree on wrap (diffuseColor clamp S, repeat T, roughness clamp S, mirror T, "
                       "metallic repeat S, mirror T); the neural features sample clamp S, mirror T, the mode most "
                       "inputs use per axis")
    assert material_wrap([("diffuseColor", ("mirror", "mirror")), ("normal", ("mirror", "mirror"))]) == (
        ("mirror", "mirror"), None)


def test_a_material_whose_inputs_disagree_warns(tmp_path) -> None:
    """A clamp diffuseColor and a repeat roughness from the same file: one set, and a warning that
    names both inputs and the modes chosen."""
    scene = wrap_stage(tmp_path)
    stage = Usd.Stage.Open(str(scene))
    base = "/World/Looks/Clamp"
    rough = UsdShade.Shader.Define(stage, f"{base}/RoughTex")
    rough.CreateIdAttr("UsdUVTexture")
    rough.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./tex/ramps.png")
    rough.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    rough.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("mirror")
    rough.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        UsdShade.Shader.Get(stage, f"{base}/St").ConnectableAPI(), "result")
    rough.CreateOutput("b", Sdf.ValueTypeNames.Float)
    surf = UsdShade.Shader.Get(stage, f"{base}/Surface")
    surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).ConnectToSource(rough.ConnectableAPI(), "b")
    stage.GetRootLayer().Save()
    result = scan_stage(scene)
    mm = group_materials(scene, {}, result.materials, digest=False).model_of(base)
    said = [w for w in mm.warnings if "disagree on wrap" in w]
    assert mm.wrap == ("clamp", "clamp") and said == [
        "inputs disagree on wrap (diffuseColor clamp, roughness repeat S, mirror T); the neural features sample "
        "clamp, the mode most inputs use per axis"], mm.warnings


# ---------------------------------------------------------------------------------------- builds


def test_neural_sets_stay_apart_and_say_their_addressing(builds) -> None:
    """--layout neural: four jobs; each material.json's sampling and each material's bcf:wrapS /
    bcf:wrapT are its UsdUVTexture's wrapS / wrapT."""
    result = builds["neural"]
    folders = _folders(result)
    assert sorted(folders) == sorted(MATERIALS) and len(set(folders.values())) == 4
    stage = Usd.Stage.Open(str(result.root_layer))
    for name, (ws, wt) in MATERIALS.items():
        d = json.loads((folders[name] / "material.json").read_text())
        want = {"addressing": ws} if ws == wt and ws != "mirror" else {"wrap_s": ws, "wrap_t": wt}
        assert {k: d["sampling"][k] for k in ("addressing", "wrap_s", "wrap_t") if k in d["sampling"]} == want
        assert d["format_version"] == (7 if "wrap_s" in want else d["format_version"])
        prim = stage.GetPrimAtPath(f"/World/Looks/{name}")
        assert (prim.GetAttribute("bcf:wrapS").Get(), prim.GetAttribute("bcf:wrapT").Get()) == (ws, wt), name
        assert not [w for m in result.manifest.materials for w in m.warnings if "wrap" in w]


def _compare(out: Path, name: str, png: Path) -> dict:
    """`bcfpipe render OUT --compare --json` through material ``name``'s camera: the report."""
    r = CliRunner().invoke(main, ["render", str(out), "-o", str(png), "--compare", "--force", "--json",
                                  "--size", SIZE, "--camera", f"/World/Cam{name}"])
    if r.exit_code != 0 and "OpenGL" in r.output:
        pytest.skip(r.output.strip())
    assert r.exit_code == 0, r.output
    return json.loads(r.output)


@contextmanager
def _sampled_as(out: Path, name: str, wrap: tuple[str, str]):
    """Within the block, the built material ``name``'s BcfNeuralMaterial shader samples with ``wrap``
    instead of what the build wrote (the overrides layer edited in place, then restored)."""
    from bcfpipe.builder import OVERRIDES
    from bcfpipe.builder.usd_layer import SURFACE_SHADER

    layer = Sdf.Layer.FindOrOpen(str(out / OVERRIDES))
    spec = layer.GetPrimAtPath(f"/World/Looks/{name}/{SURFACE_SHADER}")
    built = tuple(spec.attributes[f"inputs:{k}"].default for k in ("wrapS", "wrapT"))
    try:
        for k, v in zip(("wrapS", "wrapT"), wrap):
            spec.attributes[f"inputs:{k}"].default = v
        layer.Save()
        yield
    finally:
        for k, v in zip(("wrapS", "wrapT"), built):
            spec.attributes[f"inputs:{k}"].default = v
        layer.Save()


@pytest.mark.gl
@pytest.mark.parametrize("layout", ["neural", "default"])
@pytest.mark.parametrize("name", list(MATERIALS))
def test_render_compare_per_material(builds, layout, name, tmp_path) -> None:
    """`bcfpipe render --compare` through each material's camera: >= 35 dB, neural against original.
    Measured (tiny, draft, llvmpipe): docs/build.md, "Addressing and uv". With --layout neural, the
    same features sampled with the addressing a build before issue 57 wrote fall below the bar: the
    comparison sees the borders."""
    out = builds[layout].root_layer.parent
    rep = _compare(out, name, tmp_path / "cmp.png")
    print(f"render --compare {layout} {name}: {rep['difference']['psnr_db']:.2f} dB")
    drawn = [m for key in ("neural_materials", "classic_materials", "original_materials") for m in rep.get(key, [])]
    assert f"/World/Looks/{name}" in drawn, rep
    assert rep["difference"]["psnr_db"] >= MIN_PSNR_DB, rep
    if layout == "neural":
        assert f"/World/Looks/{name}" in rep["neural_materials"], rep
        if BEFORE[name] != MATERIALS[name]:
            with _sampled_as(out, name, BEFORE[name]):
                wrong = _compare(out, name, tmp_path / "wrong.png")["difference"]["psnr_db"]
            print(f"render --compare {layout} {name} sampled {BEFORE[name]}: {wrong:.2f} dB")
            assert wrong < MIN_PSNR_DB, wrong


def _border_points() -> np.ndarray:
    """uv at and beyond every border (and a few inside): a 41 x 41 grid over [-0.3, 1.3]², with the
    edges 0 and 1 on it."""
    g = np.linspace(-0.3, 1.3, 41)
    u, v = np.meshgrid(g, g)
    return np.stack([u.ravel(), v.ravel()], 1)


def _source_at(uv: np.ndarray, wrap: tuple[str, str]) -> np.ndarray:
    """The PNG's stored values (what the model learns: 8-bit, as written) sampled at mip 0 with ``wrap``."""
    return bilinear(np.clip(np.rint(texture() * 255), 0, 255) / 255.0, uv, wrap)


@pytest.mark.parametrize("layout", ["neural", "default"])
def test_independent_rebuild_agrees_at_the_borders(builds, layout, rt) -> None:
    """Every neural material of the build, rebuilt from material.json alone at and beyond the borders
    (s = 0 and 1.5): equal to bcfpipe's decode (its torch sampler and onnxruntime), close to the
    GLSL decoder (GL_MIRRORED_REPEAT and per-axis range reduction), and at s = 0 close to the source
    sampled with the material's own wrapS / wrapT: nearer than with the addressing a build before
    issue 57 gave it."""
    from bcfpipe.export import writer as E
    from bcfpipe.verify import glsl as G

    uv = _border_points()
    outside = (uv < 0).any(1) | (uv > 1).any(1)
    checked = []
    for name, folder in _folders(builds[layout]).items():
        d = json.loads((folder / "material.json").read_text())
        if not d.get("layers"):
            continue  # a classic layout: its UsdUVTextures keep the wraps (render compares them)
        em = E.load(folder)
        sess = E.onnx_session(em)
        gm = rt.load(G.read_material(folder))
        for s in (0.0, 1.5):
            ours = rebuild_at(folder, uv, s)
            theirs = sess.run(None, {d["onnx"]["input"]: E.sample_exported_features(em, uv.astype(np.float32), s)})[0]
            assert float(np.abs(ours - theirs).max()) <= REBUILD_TOL, (name, s)
            gl = rt.decode(gm, uv.astype(np.float32), s)
            assert float(np.abs(ours - gl).max()) <= GL_TOL, (name, s, float(np.abs(ours - gl).max()))
        rgb = rebuild_at(folder, uv, 0.0)[:, :3]
        right = float(np.abs(rgb - _source_at(uv, MATERIALS[name]))[outside].mean())
        assert right <= BORDER_MEAN_ABS, (name, right)
        if BEFORE[name] != MATERIALS[name]:
            before = float(np.abs(rgb - _source_at(uv, BEFORE[name]))[outside].mean())
            print(f"{layout} {name}: beyond the borders, mean |model - source| {right:.4f} with "
                  f"{MATERIALS[name]}, {before:.4f} with {BEFORE[name]}")
            assert before >= 3 * right, (name, right, before)
        checked.append(name)
    if layout == "neural":
        assert sorted(checked) == sorted(MATERIALS)


@pytest.mark.gl
def test_verify_passes_every_addressing(builds) -> None:
    """`bcfpipe verify` on the neural build: the GLSL decoder (samplers' wrap per axis, GL_MIRRORED_REPEAT,
    per-axis range reduction) against onnxruntime within its derived tolerance, borders included, for
    each of the four addressings."""
    import subprocess
    import sys

    v = subprocess.run([sys.executable, "-m", "bcfpipe", "verify", str(builds["neural"].root_layer.parent), "--json"],
                       capture_output=True, text=True, timeout=900)
    assert v.returncode == 0, v.stdout[-3000:] + v.stderr[-2000:]
    report = json.loads(v.stdout)
    checks = [{c["name"]: c["passed"] for c in m["checks"]} for m in report["materials"]]
    assert len(checks) == len(MATERIALS), report
    if any(c.get("glsl") is None for c in checks):
        pytest.skip("no OpenGL 4.5 through EGL: verify's GLSL check did not run")
    assert all(c["glsl"] and c["files"] and c["openimageio"] for c in checks), checks
