"""`--t0 pca` (the bc7 default, issue 29): T_0 holds the set's principal components in BC7 blocks of
any mode, encoded once and fixed; the other layers are trained mode-6 blocks. The files say so,
every reader decodes them, verify passes, and the same inputs give the same bytes."""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np

from cli_run import run_cli
from bcfpipe.bc7 import anymode, mode6
from bcfpipe.formats import dds
from bcfpipe.formats import material as mf

SRC = Path(__file__).resolve().parents[1] / "samples" / "textures"
BASE = ["train", f"albedo={SRC / 'bricks_albedo.png'}:rgb",
        f"roughness={SRC / 'bricks_roughness.png'}:r", "--profile", "tiny", "--quality", "smoke", "--features", "bc7",
        "--layout", "neural"]


def _train(out: Path, *extra: str) -> subprocess.CompletedProcess:
    return run_cli(*BASE, "-o", out, "--json", *extra)


def test_bc7_default_keeps_a_fixed_t0_in_any_mode_and_verifies(tmp_path):
    r = _train(tmp_path / "m")
    assert r.returncode == 0, r.stderr[-2000:]
    desc = mf.read(tmp_path / "m")
    assert desc.format_version == 5 and desc.bc7 is not None
    assert desc.layers[0].blocks == mf.ANY_BC7_MODE and all(layer.blocks is None for layer in desc.layers[1:])
    t0 = dds.read(tmp_path / "m" / desc.layers[0].file)
    modes = np.concatenate([anymode.block_modes(b) for b, _, _ in t0.levels])
    assert (modes < 8).all() and len(np.unique(modes)) > 1  # ISPC picks per block
    for layer in desc.layers[1:]:
        assert all(mode6.is_mode6(b).all() for b, _, _ in dds.read(tmp_path / "m" / layer.file).levels)
    v = run_cli("verify", tmp_path / "m", "--json")
    assert v.returncode == 0, v.stdout[-3000:] + v.stderr[-2000:]
    checks = {c["name"]: c["passed"] for c in json.loads(v.stdout)["materials"][0]["checks"]}
    assert checks["files"] and checks["openimageio"] and checks["glsl"] in (True, None)


def test_the_same_inputs_give_the_same_bytes(tmp_path):
    for name in ("a", "b"):
        assert _train(tmp_path / name).returncode == 0
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert files == sorted(p.name for p in (tmp_path / "b").iterdir())
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f


def test_t0_pca_is_a_bc7_choice_refused_in_one_line_with_bc6h(tmp_path):
    args = [a if a != "bc7" else "bc6h" for a in BASE] + ["-o", str(tmp_path / "x"), "--t0", "pca"]
    r = run_cli(*args)
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "--t0 pca" in r.stderr
    assert not (tmp_path / "x").exists()


def test_a_changed_fixed_level_fails_verify(tmp_path):
    """A flipped index bit decodes differently on every decoder; the digest catches it first."""
    assert _train(tmp_path / "m").returncode == 0
    path = tmp_path / "m" / "T0.dds"
    data = bytearray(path.read_bytes())
    data[-1] ^= 0x80
    path.write_bytes(bytes(data))
    v = run_cli("verify", tmp_path / "m")
    assert v.returncode != 0


def test_the_probes_t0_profile_gives_basics_blocks_with_live_alpha_and_is_the_one_used():
    """`alpha_modes`, the layout's probe's T_0 encode (issue 58): with four live channels, as principal
    components fill a layer, the very blocks of `basic`; on an opaque image, where the opaque modes 0-3
    win, other blocks: the profile is what encodes."""
    from bcfpipe.texset.texture_set import build_mip_chain
    from bcfpipe.train.fixed_t0 import encoded_levels

    yy, xx = np.mgrid[0:64, 0:64] / 64.0
    live = np.stack([0.5 + 0.4 * np.sin(6.3 * xx), 0.5 + 0.4 * np.cos(9.4 * yy), 0.5 + 0.3 * np.sin(6.3 * (xx + yy)),
                     0.5 + 0.4 * np.sin(12.6 * xx * yy)], -1).astype(np.float32)
    opaque = live.copy()
    opaque[..., 3] = 1.0
    for image, same in ((live, True), (opaque, False)):
        levels = build_mip_chain(image)[:5]  # down to 4x4, as a feature texture's mips
        basic, alpha = encoded_levels(levels), encoded_levels(levels, profile="alpha_modes")
        assert all(np.array_equal(a.blocks, b.blocks) for a, b in zip(basic, alpha)) == same
