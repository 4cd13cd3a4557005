"""Issue 11, faults: a full disk, a read-only OUT, OUT pointing at a file, OUT inside the input
folder. Each ends with one clear line and leaves no half-written OUT and no changed input.
The disk and read-only cases mount a small tmpfs (root only; skipped otherwise)."""
from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from test_build import copy_samples
from test_incremental import small_scene, tree

CLI_FAST = ["--profile", "tiny", "--quality", "smoke", "--seed", "0", "--layout", "neural"]


def bcf(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bcfpipe", "-q", *args], capture_output=True, text=True,
                          timeout=900)


@contextlib.contextmanager
def tmpfs(path: Path, size: str, readonly: bool = False):
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    path.mkdir(parents=True, exist_ok=True)
    opts = f"size={size}" + (",ro" if readonly else "")
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(path)], capture_output=True, text=True)
    if p.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {p.stderr.strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


def one_clear_line(p: subprocess.CompletedProcess) -> str:
    assert "Traceback" not in p.stderr, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.startswith("Error:")]
    assert len(lines) == 1, p.stderr
    return lines[0]


def test_disk_full(tmp_path):
    scene = small_scene(tmp_path / "in")
    before = tree(tmp_path / "in")
    with tmpfs(tmp_path / "disk", "40k") as disk:
        p = bcf("build", str(scene), "-o", str(disk / "out"), "--no-cache", *CLI_FAST)
        assert p.returncode == 1
        assert "No space left on device" in one_clear_line(p)
        assert os.listdir(disk) == [], "no half-written OUT or staging folder is left"
    # a full cache costs a retrain later, never this build
    with tmpfs(tmp_path / "cachedisk", "8k") as disk:
        p = bcf("build", str(scene), "-o", str(tmp_path / "out"), "--cache", str(disk), *CLI_FAST)
        assert p.returncode == 0, p.stderr
        assert "could not store" in p.stderr
    assert tree(tmp_path / "in") == before


def test_read_only_out(tmp_path):
    scene = small_scene(tmp_path / "in")
    with tmpfs(tmp_path / "ro", "1m", readonly=True) as ro:
        p = bcf("build", str(scene), "-o", str(ro / "out"), "--no-cache", *CLI_FAST)
        # refused before any work, nothing written: a refused OUT is 2 (README's exit codes, issue 50)
        assert p.returncode == 2 and "Read-only file system" in one_clear_line(p)
        assert not any(ro.iterdir())


def test_out_is_a_file(tmp_path):
    scene = small_scene(tmp_path / "in")
    (tmp_path / "afile").write_text("keep me")
    p = bcf("build", str(scene), "-o", str(tmp_path / "afile"), *CLI_FAST)
    assert p.returncode == 2 and "is a file" in one_clear_line(p)
    assert (tmp_path / "afile").read_text() == "keep me"


def test_out_inside_the_input_folder(tmp_path):
    """The default OUT sits next to the scene, inside its folder: allowed, and the inputs are
    unchanged. An OUT that would contain the scene is refused."""
    scene = copy_samples(tmp_path / "in")
    before = tree(tmp_path / "in")
    p = bcf("build", str(scene), "-o", str(tmp_path / "in" / "sub" / "out"), *CLI_FAST)
    assert p.returncode == 0, p.stderr
    after = {k: v for k, v in tree(tmp_path / "in").items() if not k.startswith("sub/")}
    assert after == before
    p = bcf("build", str(scene), "-o", str(tmp_path / "in"), "--force", *CLI_FAST)
    assert p.returncode == 2 and "contains the input" in one_clear_line(p)
    assert {k: v for k, v in tree(tmp_path / "in").items() if not k.startswith("sub/")} == before
