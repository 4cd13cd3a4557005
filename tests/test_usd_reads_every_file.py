"""Every shipped byte is read (issue 57, item 2): in a default-layout build, every DDS in OUT is
either read by a UsdUVTexture of the built stage or is a neural material's feature texture, and
every diffuseColor reads a file in OUT.

RoughnessTest's colour has its blue equal to its green (a folded duplicate) and 4 of
texture_file_formats' materials read a grey file as diffuseColor: before, their classic textures
packed the colour's channels as scalars, out of the slots a UsdUVTexture's rgb reads, and the
materials kept reading their sources beside a DDS nothing read. Built at the tiny profile (R = 256):
the grouping does not depend on R. Skips without ../shared.
"""
from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner
from pxr import Usd, UsdShade

from bcfpipe.cli import main
from bcfpipe.formats import manifest as mfst
from bcfpipe.formats import material as mf

SCENES = {"roughness": ("usdwg_roughness_test", "RoughnessTest.usdz"),
          "file formats": ("usdwg_texture_file_formats", "all_files.usda")}


@pytest.fixture(scope="module", params=sorted(SCENES))
def built(request, shared_scenes: Path, tmp_path_factory) -> Path:
    folder, name = SCENES[request.param]
    out = tmp_path_factory.mktemp("reads") / "out"
    r = CliRunner().invoke(main, ["build", str(shared_scenes / folder / name), "-o", str(out), "--quality", "smoke",
                                  "--profile", "tiny", "--jobs", "1", "--threads", "1"])
    assert r.exit_code == 0, r.output
    return out


def _read_files(stage: Usd.Stage) -> set[Path]:
    """The files every UsdUVTexture of the composed stage reads, resolved."""
    out = set()
    for prim in stage.Traverse():
        shader = UsdShade.Shader(prim)
        if not shader or shader.GetIdAttr().Get() != "UsdUVTexture":
            continue
        asset = shader.GetInput("file").Get() if shader.GetInput("file") else None
        if asset is not None and asset.resolvedPath:
            out.add(Path(asset.resolvedPath).resolve())
    return out


def test_every_dds_is_read_by_a_usduvtexture_or_is_a_feature_texture(built: Path) -> None:
    man = mfst.read(built)
    stage = Usd.Stage.Open(str(built / man.root_layer))
    read = _read_files(stage)
    features = set()
    for m in man.built():
        folder = built / m.outputs.folder
        features |= {(folder / layer.file).resolve() for layer in mf.read(folder).layers}
    shipped = {p.resolve() for p in built.rglob("*.dds")}
    assert shipped, "the build shipped no DDS"
    unread = sorted(str(p.relative_to(built.resolve())) for p in shipped - read - features)
    assert not unread, f"shipped but read by no UsdUVTexture and no neural material: {unread}"


def test_each_diffuse_color_reads_a_file_in_out(built: Path) -> None:
    man = mfst.read(built)
    stage = Usd.Stage.Open(str(built / man.root_layer))
    checked = 0
    for m in man.built():
        if not any(t.input == "diffuseColor" for t in m.targets):
            continue
        material = UsdShade.Material(stage.GetPrimAtPath(m.path))
        surface, _, _ = material.ComputeSurfaceSource("")
        src, _, _ = surface.GetInput("diffuseColor").GetConnectedSource()
        asset = UsdShade.Shader(src.GetPrim()).GetInput("file").Get()
        neural = bool(mf.read(built / m.outputs.folder).layers)
        path = Path(asset.resolvedPath).resolve()
        assert neural or path.is_relative_to(built.resolve()), (m.path, asset.resolvedPath)
        checked += 1
    assert checked, "no built material reads a diffuseColor"


def test_a_colour_whose_channel_duplicates_another_files_is_read_from_out(tmp_path: Path) -> None:
    """u.png's r equals t.png's b: B's set then holds t.png:b and u.png:b, two generic channels both
    named ``generic.b``. Its outputs are mapped to channels by position, so B's diffuseColor reads
    its BC1 from slot r, g, b in order (before, r resolved to slot b and the DDS shipped unread)."""
    import numpy as np

    from test_build import pattern, write_png
    from test_reports import colour, quad_stage

    t = pattern(16, 3)
    u = pattern(16, 3, seed=2)  # its r is t's b
    write_png(tmp_path / "t.png", t)
    write_png(tmp_path / "u.png", u)
    scene = quad_stage(tmp_path, {"/World/Looks/A": colour("./t.png"), "/World/Looks/B": colour("./u.png"),
                                  "/World/Looks/C": colour("./t.png")})
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["build", str(scene), "-o", str(out), "--quality", "smoke", "--jobs", "1",
                                  "--threads", "1", "--no-cache"])
    assert r.exit_code == 0, r.output
    test_every_dds_is_read_by_a_usduvtexture_or_is_a_feature_texture(out)
    test_each_diffuse_color_reads_a_file_in_out(out)
    (b,) = [m for m in mfst.read(out).built() if m.path == "/World/Looks/B"]
    desc = mf.read(out / b.outputs.folder)
    assert [o.texel_channel for o in desc.outputs] == [0, 1, 2], desc.outputs
    assert np.array_equal(u[..., 0], t[..., 2])
