"""Issue 57, items 4-6: reports that agree. verify counts what the build built; scan refuses what
plan and build refuse; sizes, bytes and probe wording hold for non-square and tiny sets; one
warning format; packaged file names; shared sets named; a readable note column; the README's
set-up list. Each through the real CLI on small stages authored here (real USD, real images)."""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, UsdGeom, UsdUtils

from conftest import REPO
from test_build import add_material, new_stage, pattern, write_png
from test_user_input import bcfpipe, error_line

SMOKE = ["--quality", "smoke", "--jobs", "1", "--threads", "1"]


def quad_stage(folder: Path, textures: dict[str, dict], name: str = "scene.usda") -> Path:
    """One quad per material {path: textures} (test_build.add_material's form), uvs over [0, 1]²."""
    path = folder / name
    stage = new_stage(path)
    for k, (material, tex) in enumerate(textures.items()):
        mesh = UsdGeom.Mesh.Define(stage, f"/World/Mesh{k}")
        mesh.CreatePointsAttr([(k, 0, 0), (k + 1, 0, 0), (k + 1, 1, 0), (k, 1, 0)])
        mesh.CreateFaceVertexCountsAttr([4])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
        st.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
        add_material(stage, material, tex, mesh=f"/World/Mesh{k}")
    stage.Save()
    return path


def colour(file: str) -> dict:
    return {"diffuseColor": (file, "rgb", {"sourceColorSpace": "sRGB"})}


# ---------------------------------------------------------------------------------------------
# item 4: verify matches the build


def test_verify_lists_every_built_material_of_roughness_test(shared_scenes, tmp_path):
    scene = tmp_path / "RoughnessTest.usdz"
    shutil.copy(shared_scenes / "usdwg_roughness_test" / "RoughnessTest.usdz", scene)
    out = tmp_path / "out"
    proc = bcfpipe("build", scene, "-o", out, "--profile", "tiny", "--json", *SMOKE)
    assert proc.returncode == 0, proc.stderr
    built = [m["path"] for m in json.loads(proc.stdout)["materials"] if m["status"] == "built"]
    assert len(built) == 6
    proc = bcfpipe("verify", out, "--no-glsl")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith(("PASS ", "FAIL "))]
    assert [ln.split()[1] for ln in lines] == built, proc.stdout
    assert proc.stdout.strip().splitlines()[-1] == "6/6 material(s) passed"
    first = built[0]
    assert all(f"the texture set of {first}, checked with it" in ln for ln in lines[1:]), lines
    assert sum("constants" in ln for ln in lines) == 3  # Tex000, Tex033, Tex066 fold a constant roughness
    rep = json.loads(bcfpipe("verify", out, "--no-glsl", "--json").stdout)
    assert [m["name"] for m in rep["materials"]] == built
    assert [m["shares"] for m in rep["materials"]] == [None] + [first] * 5


def test_verify_reports_in_the_builds_order_when_a_shared_set_is_not_adjacent(tmp_path):
    write_png(tmp_path / "t.png", pattern(16, 3))
    write_png(tmp_path / "u.png", pattern(16, 3, seed=5))  # no channel equal to one of t.png's
    scene = quad_stage(tmp_path, {"/World/Looks/A": colour("./t.png"), "/World/Looks/B": colour("./u.png"),
                                  "/World/Looks/C": colour("./t.png")})
    out = tmp_path / "out"
    assert bcfpipe("build", scene, "-o", out, *SMOKE).returncode == 0
    proc = bcfpipe("verify", out, "--no-glsl")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("PASS ")]
    assert [ln.split()[1] for ln in lines] == ["/World/Looks/A", "/World/Looks/B", "/World/Looks/C"], lines
    assert "the texture set of /World/Looks/A, checked with it" in lines[2]
    assert proc.stdout.strip().splitlines()[-1] == "3/3 material(s) passed"


# ---------------------------------------------------------------------------------------------
# item 5: scan, plan and build agree


def write_exr(path: Path, data: np.ndarray) -> None:
    import OpenImageIO as oiio

    path.parent.mkdir(parents=True, exist_ok=True)
    assert oiio.ImageBuf(np.ascontiguousarray(data.astype(np.float32))).write(str(path), "half")


def test_scan_refuses_an_inf_texel_as_plan_and_build_do(tmp_path):
    a = pattern(32, 3).astype(np.float32)
    a[3, 5, 1] = np.inf
    write_exr(tmp_path / "a.exr", a)
    scene = quad_stage(tmp_path, {"/World/Looks/M": {"emissiveColor": ("./a.exr", "rgb", {"sourceColorSpace": "raw"})}})
    lines = {}
    for cmd in ("scan", "plan", "build"):
        proc = bcfpipe(cmd, scene, *(SMOKE if cmd == "build" else []))
        assert proc.returncode == 2, (cmd, proc.stdout, proc.stderr)
        lines[cmd] = error_line(proc)
    assert len(set(lines.values())) == 1, lines
    assert "a.exr: NaN/Inf texels in channel(s) G; use --fix-nonfinite" in lines["scan"]
    proc = bcfpipe("scan", scene)
    assert "conclusion: a build stops before training (exit 2)" in proc.stdout
    proc = bcfpipe("scan", scene, "--json")
    assert proc.returncode == 2 and json.loads(proc.stdout)["refused"] == [lines["scan"].removeprefix("Error: ")]
    assert not (tmp_path / "scene.bcf").exists()


def strip_stage(folder: Path) -> Path:
    y, x = np.mgrid[0:16, 0:2048] / np.array([16.0, 2048.0])[:, None, None]
    write_png(folder / "strip.png", np.stack([0.5 + 0.4 * np.sin(40 * x + k * y) for k in (1, 2, 3)], -1))
    return quad_stage(folder, {"/World/Looks/M": colour("./strip.png")})


def test_a_strip_is_w_by_h_and_its_probe_is_not_said_to_fit(tmp_path):
    scene = strip_stage(tmp_path)
    proc = bcfpipe("scan", scene)
    assert proc.returncode == 0, proc.stderr
    assert "2048×16" in proc.stdout and "2048²" not in proc.stdout, proc.stdout
    assert "probe 0.5k (the smallest profile: none fits within BC@R's bytes)" in proc.stdout, proc.stdout
    req = json.loads(bcfpipe("scan", scene, "--json").stdout)["materials"][0]["requirements"]
    assert (req["width"], req["height"], req["layout"]["probe_fits"]) == (2048, 16, False)
    proc = bcfpipe("plan", scene)
    assert "M  2048×16, profile 2k" in proc.stdout, proc.stdout
    assert "within its bytes" not in proc.stdout and "the largest profile" not in proc.stdout, proc.stdout
    assert re.search(r"a probe at 0\.5k \(the smallest profile; none fits within BC@R's \d+ KiB", proc.stdout)


def test_a_set_no_neural_layout_fits_trains_nothing_and_says_so(tmp_path):
    """16²: BC@R is 332 bytes, less than the smallest feature textures, so no probe trains; plan
    says so, and the build ships BC@R having trained nothing. Sizes read in bytes, not 0.00 MiB."""
    write_png(tmp_path / "t.png", pattern(16, 3))
    scene = quad_stage(tmp_path, {"/World/Looks/M": colour("./t.png")})
    for cmd in ("scan", "plan"):
        proc = bcfpipe(cmd, scene)
        assert proc.returncode == 0, proc.stderr
        assert "0.00" not in proc.stdout and "332 B" in proc.stdout, proc.stdout
        assert "no probe" in proc.stdout, proc.stdout
    scan = bcfpipe("scan", scene).stdout.strip().splitlines()[-1]
    assert scan.startswith("conclusion: a build trains 0 texture set(s) and encodes 1 as BC textures only"), scan
    plan = json.loads(bcfpipe("plan", scene, "--json").stdout)
    assert plan["jobs"][0]["prediction"]["probe"] is None
    proc = bcfpipe("build", scene, "--no-cache", *SMOKE)
    assert proc.returncode == 0, proc.stderr
    assert "0 KiB" not in proc.stdout and "348 B" in proc.stdout, proc.stdout  # BC@R and weights.bin's header
    assert "0 texture set(s) trained and 1 encoded as BC textures only" in proc.stdout, proc.stdout
    report = json.loads(bcfpipe("build", scene, "--json", "--no-cache", *SMOKE).stdout)
    (m,) = report["materials"]
    assert m["train_seconds"] in (None, 0.0) and m["layout"]["chosen"] == "all classic (BC@R)", m
    assert plan["predicted_bytes"]["min"] <= report["totals"]["total_bytes"] <= plan["predicted_bytes"]["max"]


def test_bytes_and_sizes_read_the_same_everywhere():
    from bcfpipe.formats.display import bytes_range, bytes_text, dims_text, file_name

    assert (dims_text(1024, 1024), dims_text(2048, 16)) == ("1024²", "2048×16")
    assert [bytes_text(n) for n in (332, 2892, 22_528, 3 * 2**20)] == ["332 B", "2.8 KiB", "22 KiB", "3.00 MiB"]
    assert bytes_range(17_000, 22_528) == "17–22 KiB" and bytes_range(5, 5) == "5 B"
    assert file_name("/a/b.usdz[0/roughness-spec.png]") == "roughness-spec.png" == file_name("x/roughness-spec.png")


# ---------------------------------------------------------------------------------------------
# item 6: smaller things


@pytest.mark.gl
def test_render_calls_a_material_reading_shipped_dds_classic(tmp_path):
    write_png(tmp_path / "t.png", pattern(16, 3))
    scene = quad_stage(tmp_path, {"/World/Looks/M": colour("./t.png")})
    out = tmp_path / "out"
    assert bcfpipe("build", scene, "-o", out, *SMOKE).returncode == 0
    proc = bcfpipe("render", out, "-o", tmp_path / "f.png", "--size", "64x48", "--json")
    if proc.returncode == 2 and "OpenGL" in proc.stderr:
        pytest.skip(proc.stderr.strip())
    rep = json.loads(proc.stdout)
    assert rep["classic_materials"] == ["/World/Looks/M"] and rep["original_materials"] == [], rep
    proc = bcfpipe("render", out, "-o", tmp_path / "g.png", "--size", "64x48")
    assert "0 neural, 1 classic (shipped BC textures), 0 original material(s)" in proc.stdout, proc.stdout


def test_one_warning_format_logged_or_printed(tmp_path):
    """A logged warning (a build replacing another scene's, --force) and a printed one (roughness
    read from an sRGB texture) read alike."""
    write_png(tmp_path / "t.png", pattern(16, 3))
    a = quad_stage(tmp_path, {"/World/Looks/M": {**colour("./t.png"),
                                                 "roughness": ("./t.png", "r", {"sourceColorSpace": "sRGB"})}},
                   name="a.usda")
    b = quad_stage(tmp_path, {"/World/Looks/M": colour("./t.png")}, name="b.usda")
    out = tmp_path / "out"
    first = bcfpipe("build", a, "-o", out, *SMOKE)
    second = bcfpipe("build", b, "-o", out, "--force", *SMOKE)
    assert first.returncode == 0 and second.returncode == 0, first.stderr + second.stderr
    warnings = [ln for p in (first, second) for ln in p.stderr.splitlines() if "warning" in ln.lower()]
    assert any("non-colour data" in ln for ln in warnings) and any("replacing the build of" in ln for ln in warnings)
    assert all(ln.startswith("bcfpipe: warning: ") for ln in warnings), warnings


def test_a_packaged_file_prints_without_a_stray_bracket(tmp_path):
    rgb = pattern(32, 3)
    rgb[..., 2] = rgb[..., 1]  # blue equals green: folded as a duplicate, named by scan
    write_png(tmp_path / "tex" / "c.png", rgb)
    scene = quad_stage(tmp_path, {"/World/Looks/M": colour("./tex/c.png")})
    usdz = tmp_path / "scene.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(scene)), str(usdz))
    proc = bcfpipe("scan", usdz)
    assert proc.returncode == 0, proc.stderr
    assert "folded c.png:b duplicate = c.png:g" in proc.stdout, proc.stdout
    assert "]" not in proc.stdout.replace("[bold]", ""), proc.stdout


def test_shared_sets_name_their_material_and_the_note_column_stays_short(tmp_path):
    """Two materials read one image: the table's note says it is shared, in a few words; the lines
    under the table name the texture set and the material it was trained for, and the layout and
    USD wiring in full."""
    write_png(tmp_path / "t.png", pattern(16, 3))
    scene = quad_stage(tmp_path, {"/World/Looks/MainMaterial": colour("./t.png"),
                                  "/World/Other/MainMaterial_3": colour("./t.png")})
    proc = bcfpipe("build", scene, *SMOKE)
    assert proc.returncode == 0, proc.stderr
    rows = [ln for ln in proc.stdout.splitlines() if ln.startswith("│")]
    assert len(rows) == 2, proc.stdout  # one line per material: no note wraps
    assert all("shared by 2" in r and "USD:" not in r for r in rows), rows
    notes = proc.stdout.split("\nnotes:\n", 1)[1].splitlines()
    assert notes[0].startswith("  /World/Looks/MainMaterial: texture set MainMaterial shared by 2 materials;")
    assert notes[1].startswith("  /World/Other/MainMaterial_3: texture set MainMaterial shared by 2 materials, "
                               "trained for /World/Looks/MainMaterial;"), notes
    assert all("layout: BC@R" in n and "USD: 1 UsdUVTexture" in n for n in notes[:2]), notes


def test_the_readme_lists_what_setup_installs():
    setup = (REPO / "scripts" / "setup.sh").read_text()
    packages = re.search(r'APT_PKGS="([^"]+)"', setup).group(1).split()
    readme = (REPO / "README.md").read_text()
    quick = readme.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    rows = [ln for ln in quick.splitlines() if ln.startswith("| `")]
    listed = {p for ln in rows for p in re.findall(r"`([^`]+)`", ln.split("|")[1])}
    assert listed == set(packages), (listed, packages)
    assert all(ln.split("|")[2].strip() for ln in rows), "each package says why"


def test_a_failure_message_goes_under_the_table_not_into_the_note_column():
    from bcfpipe.cli.build import material_notes
    from bcfpipe.formats import manifest as mfst
    from bcfpipe.formats import report as rep

    why = "worker process died (signal 9) while training; the texture set may need more memory than is free"
    m = mfst.Material("/World/Looks/M", "failed", reason=why, job="M")
    r = rep.MaterialReport("/World/Looks/M", "failed", why, "M", None, None, None, None, None, None, ())
    short, detail = material_notes(m, r, {"M": ("/World/Looks/M",)}, None)
    assert short == ["why: below"] and detail == [why]
    skipped = mfst.Material("/World/Looks/S", "skipped", reason="no-textures")
    assert material_notes(skipped, replace_status(r, "skipped", "no-textures"), {}, None) == (["no-textures"], [])


def replace_status(r, status: str, reason: str):
    from dataclasses import replace

    return replace(r, status=status, reason=reason)
