"""What is built is what USD sees (issue 50): a default-layout build of the sample scene ships its
sets as classic BC textures (BC7 repacks at smoke), and the USD layer points every UsdUVTexture a
UsdPreviewSurface of those materials draws at the shipped DDS, with the channel, scale, bias and
colour space that make its value the one `bcfpipe decode` gives.

The values are read from the USD alone: the file the composed UsdUVTexture names, decoded by
OpenImageIO (the reader Hio uses, not bcfpipe's decoders), sampled trilinearly as a GPU does (texel
centres, lod clamped to the stored mips, the node's wrap), the output's slot, sRGB decoded when
sourceColorSpace says so, then scale and bias. They are compared with `bcfpipe decode`'s library
function (bcfpipe.export.writer.classic_outputs, which decode_material calls) mapped by the build's
targets (the source network's scale, bias and colour space).

Tolerance, the DDS palette rounding: two conforming BC decoders may give a texel one 8-bit level
apart (BC1's 1/3 and 2/3 interpolants round differently; BC7's are exact), so a filtered texel,
a convex mix of texels, differs by at most 1/255; the input then differs by at most
1/255 * |scale| (2 for normals), times 2.28 for an sRGB slot (the sRGB-to-linear curve's largest
slope, 2.4 / 1.055), plus float32 rounding.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from pxr import Usd, UsdShade

from bcfpipe.cli import main
from bcfpipe.formats import manifest as mfst
from bcfpipe.formats import material as mf

SAMPLE = Path(__file__).resolve().parent.parent / "samples" / "sample_scene.usda"
POINTS = 1000
SRGB_SLOPE = 2.4 / 1.055  # d/dx ((x + 0.055) / 1.055) ** 2.4 at x = 1, the curve's largest slope


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    """The sample scene built with the default layout at smoke (every set a classic BC7 repack)."""
    out = tmp_path_factory.mktemp("usd_classic") / "out"
    r = CliRunner().invoke(main, ["build", str(SAMPLE), "-o", str(out), "--quality", "smoke", "--jobs", "1",
                                  "--threads", "1"])
    assert r.exit_code == 0, r.output
    assert "USD: " in r.output and "UsdUVTexture" in r.output  # the table says what the layer changed
    return out


def _srgb_to_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.04045, x / 12.92, ((np.maximum(x, 0.04045) + 0.055) / 1.055) ** 2.4)


def _oiio_mips(path: str) -> list[np.ndarray]:
    """Every mip of a DDS as OpenImageIO decodes it, (h, w, 4) float rgba (missing g, b: 0; a: 1)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    assert inp is not None, oiio.geterror()
    levels = []
    try:
        k = 0
        while inp.seek_subimage(0, k):
            px = np.asarray(inp.read_image("float"), np.float64)  # the level seek_subimage chose
            px = px.reshape(*px.shape[:2], -1)
            rgba = np.zeros((*px.shape[:2], 4))
            rgba[..., 3] = 1.0
            rgba[..., :px.shape[-1]] = px[..., :4]
            levels.append(rgba)
            k += 1
    finally:
        inp.close()
    return levels


def _bilinear(img: np.ndarray, u: float, v: float, wrap: tuple[str, str]) -> np.ndarray:
    h, w = img.shape[:2]
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = int(np.floor(x)), int(np.floor(y))
    fx, fy = x - x0, y - y0

    def addr(i: int, n: int, mode: str) -> int:
        return i % n if mode == "repeat" else min(max(i, 0), n - 1)

    xa, xb = addr(x0, w, wrap[0]), addr(x0 + 1, w, wrap[0])
    ya, yb = addr(y0, h, wrap[1]), addr(y0 + 1, h, wrap[1])
    top = img[ya, xa] + (img[ya, xb] - img[ya, xa]) * fx
    bot = img[yb, xa] + (img[yb, xb] - img[yb, xa]) * fx
    return top + (bot - top) * fy


def _trilinear(levels: list[np.ndarray], u: float, v: float, lod: float, wrap: tuple[str, str]) -> np.ndarray:
    lod = min(max(lod, 0.0), len(levels) - 1)
    lo = int(lod)
    hi, t = min(lo + 1, len(levels) - 1), lod - lo
    a = _bilinear(levels[lo], u, v, wrap)
    return a if hi == lo else a + (_bilinear(levels[hi], u, v, wrap) - a) * t


def _drawn_textures(stage: Usd.Stage, material: str):
    """(input name, UsdUVTexture shader, output name) for each input of the material's
    UsdPreviewSurface that a UsdUVTexture feeds, as the composed stage says."""
    surface, _, _ = UsdShade.Material(stage.GetPrimAtPath(material)).ComputeSurfaceSource("")
    out = []
    for inp in surface.GetInputs():
        if not inp.HasConnectedSource():
            continue
        src, name, _ = inp.GetConnectedSource()
        node = UsdShade.Shader(src.GetPrim())
        if node.GetIdAttr().Get() == "UsdUVTexture":
            out.append((inp.GetBaseName(), node, name))
    return out


def _components(name: str, output: str) -> list[tuple[str, int]]:
    """(target, rgba slot) of an input read through a UsdUVTexture output."""
    if output == "rgb":
        names = ("normal.x", "normal.y", "normal.z") if name == "normal" else tuple(f"{name}.{c}" for c in "rgb")
        return [(t, k) for k, t in enumerate(names)]
    return [(name, "rgba".index(output))]


def _check_values(out: Path, m: mfst.Material, stage: Usd.Stage, drawn, pts: np.ndarray) -> int:
    """Assert that each drawn (input, UsdUVTexture, output) reads a DDS of ``m`` in ``out`` and yields,
    at every point (u, v, lod: the texture's own lod), decode's value within the palette rounding;
    returns the comparisons."""
    from bcfpipe.export import writer as E

    folder = out / m.outputs.folder
    desc = mf.read(folder)
    em = E.load(folder)
    targets = {t.target: t for t in m.targets}
    wants: dict[float, np.ndarray] = {}

    def decoded(lod_bias: float) -> np.ndarray:
        """Every output at every point, from bcfpipe decode's library function, at the reference lod
        s = lod - lod_bias that the texture's own lod stands for (a GPU's lod of a texture smaller
        than the reference is smaller by log2 of the ratio: material.json's lod_bias)."""
        if lod_bias not in wants:
            want = np.zeros((len(pts), len(desc.outputs)), np.float32)
            for i, (u, v, lod) in enumerate(pts):
                E.classic_outputs(em, np.array([[u, v]], np.float32), float(lod - lod_bias), want[i:i + 1])
            wants[lod_bias] = want
        return wants[lod_bias]

    checked = 0
    for name, node, output in drawn:
        asset = node.GetInput("file").Get()
        path = Path(asset.resolvedPath)
        assert path.suffix == ".dds" and path.resolve().is_relative_to(out.resolve()), (m.path, name, asset)
        assert path.name in {c.file for c in desc.classic}
        want = decoded(next(c.lod_bias for c in desc.classic if c.file == path.name))
        levels = _oiio_mips(str(path))
        scale = np.array(node.GetInput("scale").Get(), np.float64)
        bias = np.array(node.GetInput("bias").Get(), np.float64)
        srgb = node.GetInput("sourceColorSpace").Get() == "sRGB"
        wrap = (node.GetInput("wrapS").Get() or "useMetadata", node.GetInput("wrapT").Get() or "useMetadata")
        assert wrap == desc.wrap  # (S, T)
        if name == "normal":
            checked += _check_slope_normal(m, desc, targets, levels, scale, bias, wrap, pts, want)
            continue
        for target, slot in _components(name, output):
            t = targets[target]
            o = desc.outputs[t.channel] if t.channel >= 0 else None
            assert o is None or o.source == mf.Source.CLASSIC, (m.path, target)
            for i, (u, v, lod) in enumerate(pts):
                x = _trilinear(levels, u, v, lod, wrap)[slot]
                got = (_srgb_to_linear(x) if srgb and slot < 3 else x) * scale[slot] + bias[slot]
                if o is None:  # a constant component
                    expect = t.bias
                else:
                    f = float(want[i, t.channel]) * o.value_scale + o.value_bias
                    expect = (_srgb_to_linear(f) if t.color_space == "sRGB" else f) * t.scale + t.bias
                tol = abs(scale[slot]) / 255.0 * (SRGB_SLOPE if srgb and slot < 3 else 1.0) + 1e-5
                assert abs(got - expect) <= tol, (m.path, target, (u, v, lod), got, expect, tol)
                checked += 1
    return checked


def _check_slope_normal(m: mfst.Material, desc: mf.MaterialFile, targets: dict, levels, scale: np.ndarray,
                        bias: np.ndarray, wrap, pts: np.ndarray, want: np.ndarray) -> int:
    """A normal stored as slopes (usd_classic's note): r, g read s / M (scale 2m / M, bias -m / M), b the
    constant 1 / M, M = max(m, 1), each within [-1, 1]; normalised, what USD reads is decode's (x, y, z)
    within the palette rounding (an 8-bit step of t moves x or y by at most 2m / 255)."""
    x = desc.outputs[targets["normal.x"].channel]
    assert x.encoding == mf.SLOPE, (m.path, x)
    slope = x.texel_scale / 2.0
    big = max(slope, 1.0)
    np.testing.assert_allclose(scale[:3], (2 * slope / big, 2 * slope / big, 0.0), rtol=1e-6, err_msg=m.path)
    np.testing.assert_allclose(bias[:3], (-slope / big, -slope / big, 1 / big), rtol=1e-6, err_msg=m.path)
    chans = [targets[f"normal.{c}"].channel for c in "xyz"]
    for i, (u, v, lod) in enumerate(pts):
        got = _trilinear(levels, u, v, lod, wrap)[:3] * scale[:3] + bias[:3]
        assert np.all(np.abs(got) <= 1.0 + 1e-6), (m.path, (u, v, lod), got)
        seen = got / np.linalg.norm(got)
        tol = 2 * slope / 255.0 + 1e-5
        assert np.all(np.abs(seen - want[i, chans]) <= tol), (m.path, (u, v, lod), seen, want[i, chans], tol)
    return 3 * len(pts)


def _points(n: int = POINTS) -> np.ndarray:
    """``n`` random (u, v, lod): lods from magnified (-1) to past the coarsest mip."""
    rng = np.random.default_rng(50)
    return np.column_stack([rng.random(n), rng.random(n), rng.uniform(-1.0, 10.5, n)])


def test_every_classic_texture_usd_draws_is_the_shipped_dds_and_yields_decodes_values(built):
    man = mfst.read(built)
    stage = Usd.Stage.Open(str(built / man.root_layer))
    pts = _points()
    classic = [m for m in man.built() if m.layout is not None and m.layout.profile is None]
    assert len(classic) == 4  # Bricks, Tiles, TilesWorn, Leaves: every built material is all classic
    checked = 0
    for m in classic:
        assert all(o.source == mf.Source.CLASSIC for o in mf.read(built / m.outputs.folder).outputs)
        drawn = _drawn_textures(stage, m.path)
        assert {n for n, _, _ in drawn} == {t.input for t in m.targets}, m.path  # every modelled input drawn
        checked += _check_values(built, m, stage, drawn, pts)
    assert checked >= POINTS * 20  # every component of every drawn input at every point


@pytest.fixture(scope="module")
def mixed(tmp_path_factory) -> tuple[Path, str]:
    """The sample scene built neural with its normal maps kept classic (`--classic normal`: BC7 x, y, z)."""
    out = tmp_path_factory.mktemp("usd_mixed") / "out"
    r = CliRunner().invoke(main, ["build", str(SAMPLE), "-o", str(out), "--quality", "smoke", "--profile", "tiny",
                                  "--layout", "neural", "--classic", "normal", "--jobs", "1", "--threads", "1"])
    assert r.exit_code == 0, r.output
    return out, r.output


def test_a_mixed_layouts_classic_group_reaches_usd_and_the_rest_stays_neural(mixed):
    """Bricks and Tiles: the normal reads its BC7 DDS (decode's values, z stored); every other input keeps its
    source texture in the universal context, the decoder drives it in the bcf one."""
    out, output = mixed
    man = mfst.read(out)
    stage = Usd.Stage.Open(str(out / man.root_layer))
    src = Usd.Stage.Open(str(SAMPLE))
    by_path = {m.path: m for m in man.built()}
    for path in ("/World/Looks/Bricks", "/World/Looks/Tiles"):
        m = by_path[path]
        prim = stage.GetPrimAtPath(path)
        assert "BcfNeuralMaterialAPI" in prim.GetAppliedSchemas() or prim.HasAttribute("bcf:featureTextures")
        drawn = _drawn_textures(stage, path)
        dds = [(n, node, o) for n, node, o in drawn if node.GetInput("file").Get().resolvedPath.endswith(".dds")]
        assert [n for n, _, _ in dds] == ["normal"], drawn
        assert _check_values(out, m, stage, dds, _points(200)) == 3 * 200
        before = {n: node.GetInput("file").Get().resolvedPath for n, node, _ in _drawn_textures(src, path)}
        for n, node, _ in drawn:
            if n != "normal":
                assert node.GetInput("file").Get().resolvedPath == before[n]
    from bcfpipe.builder.usd_classic import usd_notes

    notes = usd_notes(str(out / "overrides.usda"))
    assert notes["/World/Looks/Bricks"] == "USD: neural (bcf context); 1 UsdUVTexture → C0.dds"
    assert notes["/World/Looks/Leaves"] == "USD: neural (bcf context)"
    table = " ".join(output.replace("│", " ").split())  # the note column's wrapped lines, joined
    assert "USD: neural (bcf context); 1 UsdUVTexture → C0.dds" in table


def test_the_table_and_the_layer_agree(built):
    """The note the build table shows is the layer's own, read back from overrides.usda."""
    from bcfpipe.builder.usd_classic import usd_notes

    notes = usd_notes(str(built / "overrides.usda"))
    assert notes["/World/Looks/Leaves"] == "USD: 1 UsdUVTexture → C0.dds"
    assert notes["/World/Looks/Bricks"].startswith("USD: 4 UsdUVTexture → C0.dds, C1.dds, C2.dds")
    assert "kept on sources" not in " ".join(notes.values())


@pytest.mark.gl
def test_render_compare_of_the_default_build(built, tmp_path, rt):
    """`render --compare` of an all-classic build: exit 0, three panels, the source scene drawn
    against the build (no refusal), and the two close: they differ by BC7 rounding only."""
    import OpenImageIO as oiio

    from bcfpipe.render import compare as C

    png = tmp_path / "cmp.png"
    r = CliRunner().invoke(main, ["render", str(built), "-o", str(png), "--compare", "--size", "320x180"])
    assert r.exit_code == 0, r.output
    assert "[original | built | difference]" in r.output
    spec = oiio.ImageInput.open(str(png)).spec()
    assert (spec.width, spec.height) == (3 * 320 + 2 * C.GAP, 180)
    psnr = float(r.output.split("PSNR ")[1].split(" dB")[0])
    assert 35.0 <= psnr < 80.0, r.output  # the DDS is drawn (not the sources again), and it is close


def test_the_built_stages_validate(built, mixed):
    """0 UsdValidation errors (schema and Sdr node registered) with the new UsdUVTexture nodes and
    re-pointed inputs, in an all-classic and a mixed build."""
    from test_build import validate

    for out in (built, mixed[0]):
        n, text = validate(out / mfst.read(out).root_layer)
        assert n == 0, text


STAGE = """#usda 1.0
def Material "M"
{
    token outputs:surface.connect = </M/S.outputs:surface>
    def Shader "S"
    {
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor.connect = </M/Col.outputs:rgb>
        float inputs:roughness.connect = </M/Orm.outputs:g>
        float inputs:metallic.connect = </M/Orm.outputs:b>
        token outputs:surface
    }
    def Shader "Col"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @col.png@
        token inputs:sourceColorSpace = "sRGB"
        float2 inputs:st.connect = </M/St.outputs:result>
        token inputs:wrapS = "repeat"
        token inputs:wrapT = "repeat"
        float3 outputs:rgb
    }
    def Shader "Orm"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @orm.png@
        token inputs:sourceColorSpace = "raw"
        float2 inputs:st.connect = </M/St.outputs:result>
        token inputs:wrapS = "clamp"
        token inputs:wrapT = "clamp"
        float outputs:g
        float outputs:b
    }
    def Shader "St"
    {
        uniform token info:id = "UsdPrimvarReader_float2"
        string inputs:varname = "st"
        float2 outputs:result
    }
}
"""


def _classic_desc(where: dict[str, tuple[int, int]]) -> mf.MaterialFile:
    """An all-classic material.json: output name -> (texture, texel channel), two BC7 textures."""
    outs = []
    for name, target, kind in (("albedo.r", "diffuseColor.r", "color"), ("albedo.g", "diffuseColor.g", "color"),
                               ("albedo.b", "diffuseColor.b", "color"), ("roughness.g", "roughness", "scalar"),
                               ("metallic.b", "metallic", "scalar")):
        tex, ch = where[name]
        outs.append(mf.Output(name, name.split(".")[0], name.split(".")[1], kind, target, (0.0, 1.0), 0, "uint8",
                              False, source=mf.Source.CLASSIC.value, texture=tex, texel_channel=ch, texel_scale=1.0,
                              texel_bias=0.0))
    tex = tuple(mf.ClassicTexture(f"C{i}.dds", 98, "BC7_UNORM", 4, 4, 3, 0.0, 4) for i in range(2))
    return mf.MaterialFile(layers=(), sampling=mf.Sampling("repeat"), reference=mf.Reference(4, 4, 3),
                           outputs=tuple(outs), training=mf.Training((), "none", 0, "cpu"), classic=tex)


def _wired(where: dict[str, tuple[int, int]], tmp_path: Path) -> tuple[str, Usd.Stage]:
    """The overrides layer usd_classic writes for STAGE's material with ``where``'s layout: its text,
    and the source composed under it."""
    from pxr import Sdf

    from bcfpipe.builder.plan import TargetMap
    from bcfpipe.builder.usd_classic import author_classic, wire_material

    (tmp_path / "src.usda").write_text(STAGE)
    stage = Usd.Stage.Open(str(tmp_path / "src.usda"))
    targets = [TargetMap(t, t.split(".")[0], i, 1.0, 0.0, "sRGB" if t.startswith("diffuse") else "raw", None, None)
               for i, t in enumerate(("diffuseColor.r", "diffuseColor.g", "diffuseColor.b", "roughness", "metallic"))]
    cm = wire_material(stage, "/M", "/M/S", targets, _classic_desc(where), "./materials/M")
    layer = Sdf.Layer.CreateAnonymous(".usda")
    author_classic(layer, stage, [cm])
    (tmp_path / "over.usda").write_text(layer.ExportToString())
    root = Sdf.Layer.CreateAnonymous(".usda")
    root.subLayerPaths = [str(tmp_path / "over.usda"), str(tmp_path / "src.usda")]
    return layer.ExportToString(), Usd.Stage.Open(root)


def test_a_node_whose_readers_move_to_two_dds_files_is_left_and_two_are_defined(tmp_path):
    """Orm fed roughness and metallic; they now live in C0.a and C1.g: Orm stays as it is (nothing
    reads it), OrmTex-like nodes Orm_C0 and Orm_C1 are defined with its st and wrap; Col moves whole."""
    text, stage = _wired({"albedo.r": (0, 0), "albedo.g": (0, 1), "albedo.b": (0, 2), "roughness.g": (0, 3),
                          "metallic.b": (1, 1)}, tmp_path)
    got = {n: (str(node.GetPath()), o, node.GetInput("file").Get().path, node.GetInput("sourceColorSpace").Get())
           for n, node, o in _drawn_textures(stage, "/M")}
    assert got == {"diffuseColor": ("/M/Col", "rgb", "./materials/M/C0.dds", "sRGB"),
                   "roughness": ("/M/Orm_C0", "a", "./materials/M/C0.dds", "raw"),
                   "metallic": ("/M/Orm_C1", "g", "./materials/M/C1.dds", "raw")}
    for path in ("/M/Orm_C0", "/M/Orm_C1"):
        node = UsdShade.Shader(stage.GetPrimAtPath(path))
        assert node.GetInput("wrapS").Get() == "clamp" and node.GetInput("st").GetConnectedSource()[0].GetPath() == "/M/St"
    assert stage.GetPrimAtPath("/M/Orm").GetAttribute("inputs:file").Get().path == "orm.png"
    assert "USD: 3 UsdUVTexture → C0.dds, C1.dds" in text


def test_an_input_no_one_output_can_give_keeps_its_source(tmp_path):
    """A colour across two DDS files, and one not at r, g, b, keep their source texture; the note says why."""
    text, stage = _wired({"albedo.r": (0, 0), "albedo.g": (0, 1), "albedo.b": (1, 2), "roughness.g": (1, 0),
                          "metallic.b": (1, 1)}, tmp_path)
    files = {n: node.GetInput("file").Get().path for n, node, _ in _drawn_textures(stage, "/M")}
    assert files == {"diffuseColor": "col.png", "roughness": "./materials/M/C1.dds", "metallic": "./materials/M/C1.dds"}
    assert "kept on sources: diffuseColor (its channels lie in 2 DDS files)" in text
    text, stage = _wired({"albedo.r": (0, 1), "albedo.g": (0, 2), "albedo.b": (0, 3), "roughness.g": (1, 0),
                          "metallic.b": (1, 1)}, tmp_path)
    assert "diffuseColor (albedo.r is in slot g of C0, not r)" in text
    # Orm's two readers both move to C1: the source node itself is pointed there
    assert {n: str(node.GetPath()) for n, node, _ in _drawn_textures(stage, "/M")}["roughness"] == "/M/Orm"


def test_a_mip_split_keeps_its_universal_context_and_says_so(tmp_path):
    from types import SimpleNamespace

    from pxr import Sdf

    from bcfpipe.builder.usd_classic import SPLIT_WHY, author_classic, usd_notes, wire_material

    (tmp_path / "src.usda").write_text(STAGE)
    stage = Usd.Stage.Open(str(tmp_path / "src.usda"))
    cm = wire_material(stage, "/M", "/M/S", [], SimpleNamespace(split=2, neural=True, outputs=()), "./m")
    layer = Sdf.Layer.CreateAnonymous(".usda")
    author_classic(layer, stage, [cm])
    layer.Export(str(tmp_path / "over.usda"))
    assert usd_notes(str(tmp_path / "over.usda")) == {
        "/M": f"USD: neural (bcf context); universal context on its sources ({SPLIT_WHY})"}
    assert layer.GetPrimAtPath("/M/S") is None and layer.GetPrimAtPath("/M/Col") is None


def test_a_classic_dds_that_nothing_reads_fails_the_build(built):
    """The build's consistency check (issue 57: no file shipped that nothing reads): with the wiring as
    the built stage has it every DDS is read; were one texture's UsdUVTexture nodes missing, the build
    would fail naming that file (bcfpipe.builder.assemble.check_classic_read, run before the layers)."""
    from bcfpipe.builder.assemble import check_classic_read
    from bcfpipe.builder.usd_classic import ClassicMaterial, Wiring
    from bcfpipe.errors import WorkFailed

    man = mfst.read(built)
    stage = Usd.Stage.Open(str(built / man.root_layer))
    job_of, descs, classic = {}, {}, []
    for m in man.built():
        folder = built / m.outputs.folder
        job_of[m.path], descs[folder.name] = folder.name, mf.read(folder)
        files = [c.file for c in descs[folder.name].classic]
        wired = []
        for name, node, output in _drawn_textures(stage, m.path):
            path = Path(node.GetInput("file").Get().resolvedPath)
            wired.append(Wiring(name, "", str(node.GetPath()), files.index(path.name), path.name, output, (), False))
        classic.append(ClassicMaterial(m.path, "", tuple(wired)))
    check_classic_read(job_of, descs, classic)
    bricks = next(cm for cm in classic if cm.material.endswith("/Bricks"))
    dropped = bricks.wired[0].texture
    without = [cm if cm is not bricks else ClassicMaterial(cm.material, "", tuple(w for w in cm.wired
                                                                               if w.texture != dropped))
               for cm in classic]
    with pytest.raises(WorkFailed, match=f"materials/{job_of[bricks.material]}/C{dropped}.dds"):
        check_classic_read(job_of, descs, without)
