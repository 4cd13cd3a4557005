"""What a user is told about each material (issue 32): `scan`, `plan` and `build` give one decision
and reason per material, MaterialX-only and unbuildable stages say so, `--material` picks
materials, and the variant selections that bind other materials are listed. No training here."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from bcfpipe.cli import main
from conftest import SHARED_SCENES

USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")

MTLX_SCENE = """#usda 1.0
(
    defaultPrim = "World"
)
def Xform "World"
{
    def Mesh "A" ( prepend apiSchemas = ["MaterialBindingAPI"] )
    {
        rel material:binding = </World/Looks/M1>
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    }
    def Mesh "B" ( prepend apiSchemas = ["MaterialBindingAPI"] )
    {
        rel material:binding = </World/Looks/M2>
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    }
    def Scope "Looks"
    {
        def Material "M1" ( prepend references = @./chess.mtlx@</MaterialX/Materials/M1> ) {}
        def Material "M2" ( prepend references = @./chess.mtlx@</MaterialX/Materials/M2> ) {}
        def Material "M3" ( prepend references = @./chess.mtlx@</MaterialX/Materials/M3> ) {}
    }
}
"""


#: the open chess set's shape: a Scope references the .mtlx document, so no Material prim exists and
#: every binding dangles
MTLX_SCOPE_SCENE = MTLX_SCENE.replace(
    """    def Scope "Looks"
    {
        def Material "M1" ( prepend references = @./chess.mtlx@</MaterialX/Materials/M1> ) {}
        def Material "M2" ( prepend references = @./chess.mtlx@</MaterialX/Materials/M2> ) {}
        def Material "M3" ( prepend references = @./chess.mtlx@</MaterialX/Materials/M3> ) {}
    }""",
    """    def Scope "Looks" ( prepend references = @./chess.mtlx@</MaterialX/Materials> ) {}""")


def _usd_files() -> list[Path]:
    if not SHARED_SCENES.is_dir():
        return []
    return sorted(p for p in SHARED_SCENES.rglob("*") if p.suffix in USD_SUFFIXES and "textures" not in p.parts)


def _decisions(runner: CliRunner, command: str, scene: Path) -> dict[str, tuple[str, str | None]] | str:
    """{material: (decision, reason)} from ``command --json``, or the one-line error it exited 2 with."""
    res = runner.invoke(main, [command, str(scene), "--json"])
    if res.exit_code == 2:
        return res.stderr.strip()
    assert res.exit_code == 0, (command, scene, res.output)
    return {m["path"]: (m["decision"], m["reason"]) for m in json.loads(res.stdout)["materials"]}


@pytest.mark.shared
@pytest.mark.skipif(not SHARED_SCENES.is_dir(), reason=f"needs the shared scenes at {SHARED_SCENES}")
def test_scan_and_plan_agree_on_every_shared_scene() -> None:
    """Over every USD file in ../shared/scenes, `scan --json` and `plan --json` give each
    material the same decision and reason, and every skip names its reason."""
    runner = CliRunner()
    files = _usd_files()
    assert len(files) > 50
    for scene in files:
        scanned, planned = _decisions(runner, "scan", scene), _decisions(runner, "plan", scene)
        assert scanned == planned, scene
        if isinstance(scanned, dict):
            assert all(r for d, r in scanned.values() if d == "skip"), scene


def _mtlx_scene(tmp_path: Path) -> Path:
    scene = tmp_path / "chess.usda"
    scene.write_text(MTLX_SCENE)
    return scene


def test_materialx_only_stage_concludes_and_builds_nothing_loudly(tmp_path: Path) -> None:
    """Materials defined in a .mtlx document (which USD cannot read here) are `materialx-only`;
    scan concludes that a build builds nothing, with one line for the repeated composition
    errors; build exits 0 and says on stderr that nothing was built, and why."""
    scene = _mtlx_scene(tmp_path)
    runner = CliRunner()
    res = runner.invoke(main, ["scan", str(scene)])
    assert res.exit_code == 0, res.output
    assert res.stdout.count("materialx-only") == 3
    errors = [line for line in res.stdout.splitlines() if line.startswith("composition error")]
    assert len(errors) == 1 and "(and 2 more like it)" in errors[0]
    assert "conclusion: a build builds nothing" in res.stdout and "MaterialX" in res.stdout.splitlines()[-1]

    res = runner.invoke(main, ["build", str(scene), "-o", str(tmp_path / "out"), "--no-cache"])
    assert res.exit_code == 0, res.output
    lines = res.stderr.strip().splitlines()
    assert lines and lines[-1].startswith("bcfpipe: nothing built") and "3 materialx-only" in lines[-1]


def test_materials_only_in_unopenable_mtlx_documents_conclude_so(tmp_path: Path) -> None:
    """As in the open chess set: the materials live in .mtlx documents this USD cannot open, so
    the stage has no Material prim and its bindings dangle; scan and build say why nothing is built."""
    scene = tmp_path / "chess.usda"
    scene.write_text(MTLX_SCOPE_SCENE)
    runner = CliRunner()
    res = runner.invoke(main, ["scan", str(scene)])
    assert res.exit_code == 0, res.output
    assert [line for line in res.stdout.splitlines() if "missing material" in line] == [
        "warning: binding to missing material /World/Looks/M1 (and 1 more missing material(s))"]
    assert "MaterialX document(s) (.mtlx) that this USD cannot open" in res.stdout.splitlines()[-1]
    res = runner.invoke(main, ["build", str(scene), "-o", str(tmp_path / "out"), "--no-cache"])
    assert res.exit_code == 0, res.output
    assert "nothing built" in res.stderr and "MaterialX" in res.stderr


def test_material_option_selects_on_scan_plan_and_build(tmp_path: Path) -> None:
    """`--material PRIM` (repeatable): the others are skipped as `not-selected` alike in scan,
    plan and build; a path that names no material is one line, exit 2."""
    scene = _mtlx_scene(tmp_path)
    runner = CliRunner()
    for command in ("scan", "plan"):
        res = runner.invoke(main, [command, str(scene), "--json", "--material", "/World/Looks/M2",
                                   "--material", "/World/Looks/M3"])
        assert res.exit_code == 0, res.output
        got = {m["path"]: m["reason"] for m in json.loads(res.stdout)["materials"]}
        assert got == {"/World/Looks/M1": "not-selected", "/World/Looks/M2": "materialx-only",
                       "/World/Looks/M3": "materialx-only"}, command
    res = runner.invoke(main, ["build", str(scene), "-o", str(tmp_path / "out"), "--no-cache", "--json",
                               "--material", "/World/Looks/M1"])
    assert res.exit_code == 0, res.output
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert {m["path"]: m["reason"] for m in manifest["materials"]} == {
        "/World/Looks/M1": "materialx-only", "/World/Looks/M2": "not-selected", "/World/Looks/M3": "not-selected"}
    for command in ("scan", "plan", "build"):
        res = runner.invoke(main, [command, str(scene), "--material", "/World/Looks/Nope"])
        assert res.exit_code == 2 and len(res.stderr.strip().splitlines()) == 1, (command, res.output)
        assert "/World/Looks/Nope" in res.stderr


@pytest.mark.shared
@pytest.mark.skipif(not SHARED_SCENES.is_dir(), reason=f"needs the shared scenes at {SHARED_SCENES}")
def test_scan_lists_the_variant_that_binds_the_textured_teapot() -> None:
    """The teapot's textured material is bound only under modelVariant = Fancy: scan says so, and
    the selection it suggests makes the material one to model."""
    runner = CliRunner()
    scene = SHARED_SCENES / "usdwg_teapot" / "Teapot.usd"
    res = runner.invoke(main, ["scan", str(scene), "--json"])
    data = json.loads(res.stdout)
    assert data["binding_variants"] == [{"set": "modelVariant", "value": "Fancy",
                                         "materials": ["/Teapot/Materials/PorcelainFlowers"]}]
    res = runner.invoke(main, ["scan", str(scene)])
    assert "add --variant modelVariant=Fancy" in res.stdout
    res = runner.invoke(main, ["scan", str(scene), "--json", "--variant", "modelVariant=Fancy"])
    data = json.loads(res.stdout)
    assert {m["path"]: m["decision"] for m in data["materials"]}["/Teapot/Materials/PorcelainFlowers"] == "model"
    assert data["binding_variants"] == [{"set": "modelVariant", "value": "Utah", "materials": ["/Teapot/Materials/Ceramic"]}]


@pytest.mark.shared
@pytest.mark.skipif(not SHARED_SCENES.is_dir(), reason=f"needs the shared scenes at {SHARED_SCENES}")
def test_texture_file_formats_opacity_from_missing_alpha_reads_one() -> None:
    """`opacity` read from `.a` of files without alpha (RGB, grey and CMYK JPEGs) is 1, as Hydra
    reads it: folded as `no-alpha` and authored, so the build plans nothing it cannot read."""
    runner = CliRunner()
    res = runner.invoke(main, ["plan", str(SHARED_SCENES / "usdwg_texture_file_formats" / "all_files.usda"), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    jpeg_opacity = [m for m in data["materials"] if "/jpeg/" in m["path"] and m["path"].endswith("WithOpacity")]
    assert len(jpeg_opacity) == 3
    for m in jpeg_opacity:
        assert m["decision"] == "model"
        assert [(f["channel"], f["reason"], f["value"]) for f in m["folded"] if f["reason"] == "no-alpha"] == \
            [("a", "no-alpha", 1.0)]
        assert [(c["target"], c["value"]) for c in m["constants"]] == [("opacity", 1.0)]
        assert all(t["file_channel"] != "a" for t in m["targets"])
