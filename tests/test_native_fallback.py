"""A compiled kernel that cannot build (issue 50): training falls back to numba (the step) and torch
(the first encode) with one line on stderr, once per build, never a traceback. The compiler is
really run and really fails: $CXX is g++ told to include a header that does not exist, the case of
a machine whose toolchain lacks one."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_build import add_material, new_stage, pattern, write_png  # noqa: E402

BCF = str(Path(sys.executable).with_name("bcfpipe"))
MISSING = "bcfpipe_missing_header.h"


@pytest.fixture
def failing_cxx(tmp_path) -> Path:
    """A C++ compiler that answers --version and fails every compile on a missing header."""
    gxx = shutil.which("g++")
    if gxx is None:
        pytest.skip("needs g++ (scripts/setup.sh installs it)")
    cxx = tmp_path / "bin" / "g++-missing-header"
    cxx.parent.mkdir()
    cxx.write_text(f'#!/bin/sh\nexec {gxx} -include {MISSING} "$@"\n')
    cxx.chmod(0o755)
    return cxx


def test_load_says_why_in_one_line(failing_cxx, monkeypatch):
    """native.load() turns the compiler's failure into NativeUnavailable naming its first error."""
    from bcfpipe.train.fused import native

    monkeypatch.setenv("CXX", str(failing_cxx))
    monkeypatch.setattr(native, "_lib", None)
    with pytest.raises(native.NativeUnavailable) as e:
        native.load()
    assert str(e.value).startswith("building the fused kernel failed: ") and MISSING in str(e.value)
    assert "\n" not in str(e.value)


def test_a_build_whose_kernel_cannot_compile_trains_in_numba_and_says_so_once(failing_cxx, tmp_path):
    """Two materials on two workers (--jobs 2), each of which tries the compiler and fails: the
    build exits 0, both materials are built and pass their checks, and stderr has exactly one line
    about the fallback (naming the missing header), no traceback."""
    stage = new_stage(tmp_path / "scene.usda")
    for i, name in enumerate(("A", "B")):
        tex = write_png(tmp_path / "tex" / f"{name}.png", pattern(64, 3, seed=i))
        add_material(stage, f"/World/Looks/{name}", {"diffuseColor": (str(tex), "rgb", {})}, mesh=f"/World/M{name}")
    stage.Save()
    env = dict(os.environ, CXX=str(failing_cxx))
    p = subprocess.run([BCF, "build", str(tmp_path / "scene.usda"), "-o", str(tmp_path / "out"), "--no-cache",
                        "--jobs", "2", "--quality", "smoke", "--profile", "tiny", "--layout", "neural", "--kernel",
                        "fused", "--verify", "--json"],
                       capture_output=True, text=True, env=env, timeout=1200)
    assert p.returncode == 0, p.stderr[-3000:]
    assert "Traceback" not in p.stderr
    said = [ln for ln in p.stderr.splitlines() if "fused kernel" in ln]
    assert len(said) == 1, p.stderr[-3000:]
    assert MISSING in said[0] and "numba" in said[0] and "torch" in said[0]
    report = json.loads(p.stdout)
    assert sorted(m["status"] for m in report["materials"]) == ["built", "built"], report["materials"]
    cache = Path(os.environ["BCFPIPE_CACHE"])  # tests/conftest.py's private cache: the build's default
    assert not list((tmp_path / "out").rglob(".said-*")) and not list(cache.rglob(".said-*"))
