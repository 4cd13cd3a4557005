"""Issue 50, items 5 and 6: a moved OUT, suspect input and options, and exit codes, each through
the real CLI on real files (small authored stages; the neural path at the tiny profile and the smoke
preset, so that nothing waits on a layout's BC encodes).

Every refusal is one line on stderr with the README's exit code and writes nothing.
"""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, UsdGeom

from cli_run import run_cli
from test_build import add_material, new_stage, pattern, write_png

FAST = ["--profile", "tiny", "--quality", "smoke", "--layout", "neural", "--jobs", "1", "--threads", "1"]


def bcfpipe(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """The real CLI, in this process (`cli_run`): every check here reads its exit code and output."""
    return run_cli(*args, cwd=cwd)


def error_line(proc: subprocess.CompletedProcess) -> str:
    """The one line a refusal prints (no traceback)."""
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert "Traceback" not in proc.stderr, proc.stderr
    assert len(lines) == 1, proc.stderr
    return lines[0]


def textured_stage(folder: Path, *, normal: np.ndarray | None = None, variants: bool = False) -> Path:
    """One textured material on a mesh: an albedo, and a normal map when ``normal`` is given (any
    channel count). With ``variants``, a variant set ``look`` whose values ``a`` and ``b`` both bind it."""
    folder.mkdir(parents=True, exist_ok=True)
    write_png(folder / "albedo.png", pattern(32, 3))
    textures = {"diffuseColor": ("./albedo.png", "rgb", {"sourceColorSpace": "sRGB"})}
    if normal is not None:
        write_png(folder / "normal.png", normal)
        textures["normal"] = ("./normal.png", "rgb", {"sourceColorSpace": "raw", "scale": (2, 2, 2, 1),
                                                     "bias": (-1, -1, -1, 0)})
    path = folder / "scene.usda"
    stage = new_stage(path)
    mesh = UsdGeom.Mesh.Define(stage, "/World/Mesh")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    add_material(stage, "/World/Looks/Mat", textures, mesh="/World/Mesh")
    if variants:
        vset = stage.GetPrimAtPath("/World").GetVariantSets().AddVariantSet("look")
        for v in ("a", "b"):
            vset.AddVariant(v)
        vset.SetVariantSelection("a")
    stage.Save()
    return path


def tree(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


# ---------------------------------------------------------------------------------------------
# item 5: a moved OUT


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("moved")
    scene = textured_stage(root / "project")
    out = root / "project" / "scene.bcf"
    proc = bcfpipe("build", scene, "-o", out, *FAST)
    assert proc.returncode == 0, proc.stderr
    return scene, out


def test_a_moved_out_is_said_by_verify_render_and_a_rebuild(built, tmp_path: Path) -> None:
    scene, out = built
    moved = tmp_path / "one" / "deeper" / "scene.bcf"
    shutil.copytree(out, moved)
    before = tree(moved)
    proc = bcfpipe("verify", moved, "--no-glsl")
    assert proc.returncode == 2
    line = error_line(proc)
    assert "@../scene.usda@ does not resolve" in line and "moved" in line, line
    proc = bcfpipe("verify", moved, "--no-glsl", "--json")
    assert proc.returncode == 2 and "does not resolve" in json.loads(proc.stdout)["input_error"]
    proc = bcfpipe("render", moved, "-o", tmp_path / "frame.png", "--size", "64x48")
    assert proc.returncode == 2
    line = error_line(proc)
    assert "does not resolve" in line and "no visible mesh" not in line, line
    assert not (tmp_path / "frame.png").exists()
    # a rebuild into the moved folder names the scene it lost, not "another scene"
    proc = bcfpipe("build", scene, "-o", moved, *FAST)
    assert proc.returncode == 2
    line = error_line(proc)
    assert "does not exist" in line and "moved" in line and "another scene" not in line, line
    assert tree(moved) == before, "a refused build writes nothing"
    # where it was built, with its scene beside it, the same files verify
    assert bcfpipe("verify", out, "--no-glsl").returncode == 0


# ---------------------------------------------------------------------------------------------
# item 6: suspect input and options


def test_a_greyscale_normal_map_is_a_warning_naming_the_file(tmp_path: Path) -> None:
    y, x = np.mgrid[0:32, 0:32] / 32
    grey = (0.5 + 0.3 * np.sin(6 * x + 4 * y))[..., None]  # one channel: x, y and z read the same
    scene = textured_stage(tmp_path, normal=grey)
    import OpenImageIO as oiio

    assert oiio.ImageInput.open(str(tmp_path / "normal.png")).spec().nchannels == 1
    for cmd in (["scan"], ["plan"]):
        proc = bcfpipe(*cmd, scene)
        assert proc.returncode == 0, proc.stderr
        assert "normal.png is a single-channel (greyscale) image" in proc.stdout, proc.stdout
    proc = bcfpipe("build", scene, *FAST)
    assert proc.returncode == 0, proc.stderr
    warn = [ln for ln in proc.stderr.splitlines() if "warning" in ln and "normal.png" in ln]
    assert len(warn) == 1 and "/World/Looks/Mat" in warn[0], proc.stderr
    # an RGB normal map says nothing of the kind
    rgb = textured_stage(tmp_path / "rgb", normal=pattern(32, 3))
    proc = bcfpipe("scan", rgb)
    assert proc.returncode == 0 and "single-channel" not in proc.stdout


def test_two_values_for_one_variant_set_are_refused(tmp_path: Path) -> None:
    scene = textured_stage(tmp_path, variants=True)
    for cmd in ("scan", "plan", "build"):
        proc = bcfpipe(cmd, scene, "--variant", "look=a", "--variant", "look=b", *(FAST if cmd == "build" else []))
        assert proc.returncode == 2, (cmd, proc.stderr)
        assert "two values for variant set 'look' ('a' and 'b')" in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr
    assert not (tmp_path / "scene.bcf").exists()
    proc = bcfpipe("scan", scene, "--variant", "look=a", "--variant", "look=a")  # the same value twice is one
    assert proc.returncode == 0, proc.stderr
    assert "add --variant look=" not in proc.stdout


def test_an_out_that_cannot_be_written_is_refused_with_2(tmp_path: Path) -> None:
    scene = textured_stage(tmp_path / "s")
    blocker = tmp_path / "a-file"
    blocker.write_text("mine")
    proc = bcfpipe("build", scene, "-o", blocker / "out", *FAST)
    assert proc.returncode == 2
    assert "cannot write" in error_line(proc)
    assert blocker.read_text() == "mine"
    # a read-only filesystem (a real read-only tmpfs): tests/test_faults.py::test_read_only_out


def test_scan_exits_2_on_an_empty_texture_as_the_build_does(tmp_path: Path) -> None:
    scene = textured_stage(tmp_path)
    (tmp_path / "albedo.png").write_bytes(b"")
    proc = bcfpipe("scan", scene)
    assert proc.returncode == 2, proc.stdout
    assert "albedo.png: the file is empty (0 bytes)" in proc.stdout
    assert proc.stdout.strip().splitlines()[-1].startswith("conclusion: a build stops before training (exit 2)")
    proc = bcfpipe("scan", scene, "--json")
    assert proc.returncode == 2 and json.loads(proc.stdout)["unreadable"]
    proc = bcfpipe("build", scene, *FAST)
    assert proc.returncode == 2 and "albedo.png: the file is empty" in error_line(proc)


def test_help_says_what_runs() -> None:
    """The features' default format and what smoke costs, as measured (README's preset table)."""
    from bcfpipe.config import DEFAULT_FEATURES

    top = bcfpipe("--help").stdout
    assert "BC7 by default" in top and DEFAULT_FEATURES.value == "bc7"
    build = " ".join(bcfpipe("build", "--help").stdout.split())
    assert "about 1 s" not in build and "[default: bc7]" in build
    assert "BC1, BC4, BC5" in " ".join(bcfpipe("dds", "--help").stdout.split())
