"""Texels that no mesh reads (issue #18, item 4): the coverage mask, and training and quality on it."""
from __future__ import annotations
from bcfpipe.builder import Execution, Selection

import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, UsdGeom, UsdShade

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_build import FAST, add_material, new_stage, pattern, write_png  # noqa: E402

from bcfpipe.builder import build, plan  # noqa: E402
from bcfpipe.scan import coverage as cov  # noqa: E402


def test_rasterize_a_quarter_and_its_mips():
    tris = np.array([[(0, 0.5), (0.5, 0.5), (0.5, 1.0)], [(0, 0.5), (0.5, 1.0), (0, 1.0)]], float)  # st
    m = cov.rasterize(tris, 64, 64)
    # st t in [0.5, 1] is the top half of the image: rows 0..31 in bcfpipe's uv (v = 1 - t)
    assert m[:32, :32].all() and not m[33:, :].any() and not m[:, 33:].any()
    chain = cov.mask_mips(m, 7)
    assert [c.shape for c in chain] == [(64 >> k,) * 2 for k in range(7)]
    assert 0.25 < chain[0].mean() < 0.30 and chain[-1].all()
    assert np.array_equal(cov.unpack(cov.pack(m), 64, 64), m)


def test_rasterize_wraps_for_repeat_and_clips_for_clamp():
    tri = np.array([[(0.9, 0.0), (1.1, 0.0), (1.1, 0.2)]], float)
    rep, clamp = cov.rasterize(tri, 32, 32, "repeat"), cov.rasterize(tri, 32, 32, "clamp")
    assert rep[:, :2].any() and rep[:, -2:].any()  # the part beyond u = 1 lands at u = 0
    assert not clamp[:, :2].any() and clamp[:, -2:].any()


def test_each_axis_folds_by_its_own_mode():
    """A triangle past the right edge (st u in [1.1, 1.3]): repeat S finds it at u - 1, mirror S at
    2 - u (the columns reversed), clamp S leaves it out; T repeats in all three. Dilation wraps only
    along a repeat axis."""
    tri = np.array([[[1.13, 0.41], [1.31, 0.43], [1.22, 0.67]]])
    rep = cov.rasterize(tri, 20, 20, ("repeat", "repeat"))
    assert rep.any() and rep[:, :10].any() and not rep[:, 10:].any()
    assert np.array_equal(cov.rasterize(tri, 20, 20, ("mirror", "repeat")), rep[:, ::-1])
    assert not cov.rasterize(tri, 20, 20, ("clamp", "repeat")).any()
    assert np.array_equal(cov.rasterize(tri - [0.0, 1.0], 20, 20, ("repeat", "repeat")), rep)  # T wraps too
    corner = np.zeros((8, 8), bool)
    corner[0, 0] = True
    m = cov.mask_mips(corner, 1, ("repeat", "clamp"))[0]
    assert m[0, 7] and m[1, 7] and not m[7, 0] and not m[7, 7]  # wraps along S only
    assert np.array_equal(cov.mask_mips(corner, 1, "mirror")[0], cov.mask_mips(corner, 1, "clamp")[0])


def test_tiny_triangles_still_count():
    tri = np.array([[(0.5001, 0.5001), (0.5002, 0.5001), (0.5001, 0.5002)]], float)
    assert cov.rasterize(tri, 16, 16).sum() == 1


def quarter_scene(root: Path, n: int = 64) -> Path:
    """One quad whose uvs cover [0, 0.5]² of a texture."""
    write_png(root / "tex" / "c.png", pattern(n))
    stage = new_stage(root / "scene.usda")
    mat = add_material(stage, "/World/Looks/M", {"diffuseColor": ("./tex/c.png", "rgb", {})})
    mesh = UsdGeom.Mesh.Define(stage, "/World/Quad")
    mesh.GetPointsAttr().Set([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
        [(0, 0), (0.5, 0), (0.5, 0.5), (0, 0.5)])
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    stage.Save()
    return root / "scene.usda"


def test_coverage_enters_the_job_and_its_key(tmp_path):
    scene = quarter_scene(tmp_path)
    on, off = plan(scene, **FAST), plan(scene, selection=Selection(coverage=False), **FAST)
    assert on.jobs[0].coverage is not None and 0.25 < on.jobs[0].covered_fraction < 0.32
    assert off.jobs[0].coverage is None and on.jobs[0].content_hash != off.jobs[0].content_hash
    # the sample scene's quads read every texel: no mask, keys as before
    from test_build import SAMPLES
    assert all(j.coverage is None for j in plan(SAMPLES / "sample_scene.usda", **FAST).jobs)


def test_build_reports_quality_over_covered_texels_and_keeps_the_rest_valid(tmp_path):
    from bcfpipe.export import writer as E
    from bcfpipe.formats import manifest as mfst

    scene = quarter_scene(tmp_path)
    build(scene, execution=Execution(jobs=1), out=tmp_path / "out", **FAST)
    m = mfst.read(tmp_path / "out")
    (mat,) = m.built()
    q = mat.metrics.detail
    assert 0.25 < q.covered_fraction < 0.32 and len(q.psnr_per_mip_covered) == len(q.psnr_per_mip)
    assert q.psnr_covered > q.psnr  # training went to the covered texels
    (dec,) = E.decode_mips(E.load(tmp_path / "out" / mat.outputs.folder), [(64, 64)])
    assert np.isfinite(dec).all() and dec.min() >= 0 and dec.max() <= 1  # uncovered texels: valid data
