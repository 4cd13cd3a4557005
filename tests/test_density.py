"""Texel density from the meshes (issue #18, item 3), on generated scenes with known geometry and
on the teapot."""
from __future__ import annotations
from bcfpipe.builder import Selection

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_build import FAST, add_material, new_stage, pattern, write_png  # noqa: E402

from bcfpipe.builder import plan  # noqa: E402
from bcfpipe.scan.stage import scan_stage  # noqa: E402
from bcfpipe.scan.grouping import group_materials  # noqa: E402


def quad_scene(root: Path, mpu: float = 1.0, scale: float = 1.0, faces_uv: str = "vertex", st: bool = True,
               animated: bool = False) -> Path:
    """A 2 x 1 (scene units) quad with uvs over [0, 1]², a 1024² texture, optional parent scale."""
    write_png(root / "tex" / "c.png", pattern(1024))
    stage = new_stage(root / "scene.usda")
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    xf = UsdGeom.Xform.Define(stage, "/World/Group")
    if scale != 1.0:
        xf.AddScaleOp().Set(Gf.Vec3f(scale, scale, scale))
    mat = add_material(stage, "/World/Looks/M", {"diffuseColor": ("./tex/c.png", "rgb", {})})
    mesh = UsdGeom.Mesh.Define(stage, "/World/Group/Quad")
    pts = [(0, 0, 0), (2, 0, 0), (2, 1, 0), (0, 1, 0)]
    if animated:
        mesh.GetPointsAttr().Set(pts, 1.0)
        mesh.GetPointsAttr().Set([(x * 2, y, z) for x, y, z in pts], 2.0)
    else:
        mesh.GetPointsAttr().Set(pts)
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    if st:
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                     UsdGeom.Tokens.faceVarying if faces_uv == "faceVarying"
                                                     else UsdGeom.Tokens.vertex)
        pv.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    from pxr import UsdShade

    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    stage.Save()
    return root / "scene.usda"


def _density(scene: Path):
    result = scan_stage(scene)
    g = group_materials(scene, {}, result.materials, digest=False)
    (mm,) = [m for grp in g.groups for m in grp.models]
    return mm.density


@pytest.mark.parametrize("interp", ["vertex", "faceVarying"])
def test_quad_density_is_1024_over_sqrt2(tmp_path, interp):
    d = _density(quad_scene(tmp_path, faces_uv=interp))
    assert d.world_area_m2 == pytest.approx(2.0) and d.uv_area == pytest.approx(1.0)
    assert d.density() == pytest.approx(1024 / math.sqrt(2), rel=0.01)  # 724 px/m


@pytest.mark.parametrize("mpu, scale, factor", [(0.01, 1.0, 100.0), (1.0, 2.0, 0.5), (0.01, 10.0, 10.0)])
def test_transforms_and_meters_per_unit_scale_the_density(tmp_path, mpu, scale, factor):
    d = _density(quad_scene(tmp_path, mpu=mpu, scale=scale))
    assert d.density() == pytest.approx(1024 / math.sqrt(2) * factor, rel=0.01)


@pytest.mark.parametrize("kind, note", [("no st", "no 'st' primvar"), ("animated", "time-sampled points")])
def test_meshes_without_figures_get_a_note_and_no_cap(tmp_path, kind, note):
    scene = quad_scene(tmp_path, st=kind != "no st", animated=kind == "animated")
    d = _density(scene)
    assert d.density() is None and any(note in n for n in d.notes), d.notes
    p = plan(scene, selection=Selection(texel_density=100.0), **FAST)
    assert p.jobs[0].options.resolution is None  # never an error, never a cap


def test_texel_density_caps_the_resolution_never_above_the_source(tmp_path):
    scene = quad_scene(tmp_path)
    base = plan(scene, **FAST)
    assert base.jobs[0].options.resolution is None
    # 724 px/m at 1024²: 300 px/m needs 1024 * 300 / 724 = 424 -> 512
    p = plan(scene, selection=Selection(texel_density=300.0), **FAST)
    assert p.jobs[0].options.resolution == 512 and p.jobs[0].content_hash != base.jobs[0].content_hash
    assert plan(scene, selection=Selection(texel_density=5000.0), **FAST).jobs[0].options.resolution is None
    assert plan(scene, **FAST).jobs[0].content_hash == base.jobs[0].content_hash  # no option: unchanged


@pytest.mark.shared
def test_teapot_density_is_1360_px_per_m(shared_scenes):
    scene = shared_scenes / "usdwg_teapot" / "Teapot.usd"
    result = scan_stage(scene, {"modelVariant": "Fancy"})
    g = group_materials(scene, {"modelVariant": "Fancy"}, result.materials, digest=False)
    (mm,) = [m for grp in g.groups for m in grp.models]
    assert mm.density.source_size == (2048, 2048)
    assert mm.density.density() == pytest.approx(1360, rel=0.02)
    assert np.isclose(mm.density.world_area_m2, 0.60, rtol=0.02) and np.isclose(mm.density.uv_area, 0.26, rtol=0.02)


def test_plan_cli_json_names_every_job_with_its_capped_options(tmp_path):
    import json

    from click.testing import CliRunner

    from bcfpipe.cli import main

    scene = quad_scene(tmp_path)
    res = CliRunner().invoke(main, ["plan", str(scene), "--texel-density", "300", "--profile", "tiny",
                                    "--quality", "smoke", "--json"])
    assert res.exit_code == 0, res.output
    d = json.loads(res.stdout)
    (job,) = d["jobs"]
    assert job["options"]["resolution"] == 512 and job["options"]["texel_density"] == 300.0
    assert len(job["content_hash"]) == 32 and "coverage" not in job and job["covered_fraction"] is None
    assert all(len(s["xxh3_128"]) == 32 for s in job["sources"])
    res = CliRunner().invoke(main, ["plan", str(tmp_path / "missing.usda")])
    assert res.exit_code == 2 and "\n" not in res.output.strip()
