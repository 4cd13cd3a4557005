"""Encoded features through the DDS writer read back identically in both oracles, and the
`bcfpipe dds` commands."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import sys
from pathlib import Path

from bcfpipe.formats import dds
from bcfpipe.bc6h import decode
from bcfpipe.bc6h.encode import encode
from bcfpipe.cli import main

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _features(size, signed, seed=0):
    """A smooth-plus-noise 3-channel feature pyramid, encoded level by level."""
    rng = np.random.default_rng(seed)
    levels = []
    for k in range(size.bit_length() - 2):  # down to 4x4
        r = size >> k
        y, x = np.mgrid[0:r, 0:r] / r
        img = np.stack([np.sin(7 * x) * 1.5, x * y * 3, np.cos(5 * y)], -1) + rng.normal(0, 0.1, (r, r, 3))
        img = img if signed else np.abs(img)
        levels.append((encode(img.astype(np.float32), signed=signed), r, r))
    return levels


def _oiio_mips(path):
    oiio = pytest.importorskip("OpenImageIO")
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    out, k = [], 0
    while inp.seek_subimage(0, k):
        out.append(np.asarray(inp.read_image(format="half")))
        k += 1
    inp.close()
    return out


@pytest.mark.parametrize("signed", [False, True])
def test_encoded_features_read_back_identically_in_openimageio(tmp_path, signed):
    levels = _features(64, signed)
    p = tmp_path / "f.dds"
    dds.write(p, levels, signed=signed)
    ours = [decode(b, w, h, signed) for b, w, h in dds.read(p).levels]
    theirs = _oiio_mips(p)
    assert len(theirs) == len(ours) == len(levels)
    for a, b in zip(ours, theirs):
        assert np.array_equal(a.view(np.uint16), b.view(np.uint16))


@pytest.mark.gl
@pytest.mark.parametrize("signed", [False, True])
def test_encoded_features_read_back_identically_in_mesa(signed):
    from gl_oracle import gl_decode_bc6h_mips

    levels = _features(64, signed, seed=1)
    gl = gl_decode_bc6h_mips(levels, signed)
    for (b, w, h), g in zip(levels, gl):
        ours = decode(b, w, h, signed).view(np.uint16)
        g = g.view(np.uint16)
        # Mesa writes -0 where the D3D11 spec (and we, and OpenImageIO) write +0 for signed -1
        # interpolants (see test_bc6h_decode); every other half must be identical.
        diff = ours != g
        assert np.all(ours[diff] == 0) and np.all(g[diff] == 0x8000)
        if not signed:
            assert not diff.any()


def test_dds_decode_command_matches_decoder(tmp_path):
    oiio = pytest.importorskip("OpenImageIO")
    levels = _features(32, False, seed=2)
    p = tmp_path / "f.dds"
    dds.write(p, levels)
    for mip in (0, 2):
        out = tmp_path / f"m{mip}.exr"
        r = CliRunner().invoke(main, ["dds", "decode", str(p), "-o", str(out), "--mip", str(mip)])
        assert r.exit_code == 0, r.output
        buf = oiio.ImageBuf(str(out))
        img = buf.get_pixels(oiio.HALF)
        b, w, h = levels[mip]
        assert np.array_equal(img.view(np.uint16), decode(b, w, h).view(np.uint16))
    r = CliRunner().invoke(main, ["dds", "decode", str(p), "-o", str(tmp_path / "m0.exr")])
    assert r.exit_code == 2 and "exists" in r.output  # no silent overwrite
    r = CliRunner().invoke(main, ["dds", "decode", str(p), "-o", str(tmp_path / "x.exr"), "--mip", "9"])
    assert r.exit_code == 2 and "out of range" in r.output


def test_dds_info_command(tmp_path):
    levels = _features(16, False, seed=3)
    p = tmp_path / "f.dds"
    dds.write(p, levels)
    r = CliRunner().invoke(main, ["dds", "info", str(p), "--json"])
    assert r.exit_code == 0, r.output
    info = json.loads(r.output)
    assert info["format"] == "BC6H_UF16" and info["mip_count"] == 3 and info["width"] == 16
    img = decode(*levels[0]).astype(np.float32)
    assert info["mips"][0]["max"] == pytest.approx(img.reshape(-1, 3).max(0).tolist())
    r = CliRunner().invoke(main, ["dds", "info", str(p)])
    assert r.exit_code == 0 and "BC6H_UF16" in r.output
    (tmp_path / "bad.dds").write_bytes(p.read_bytes()[:200])
    r = CliRunner().invoke(main, ["dds", "info", str(tmp_path / "bad.dds")])
    assert r.exit_code == 2 and "truncated" in r.output and "Traceback" not in r.output
