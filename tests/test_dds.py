"""DDS container: round trips, header fields, and clear errors on bad files."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from bcfpipe.formats import dds


def _chain(w, h, n=None, seed=0):
    rng = np.random.default_rng(seed)
    n = n or dds.max_mip_count(w, h)
    return [(rng.integers(0, 256, (dds.block_count(*dds.mip_dims(w, h, k)), 16), dtype=np.uint8),
             *dds.mip_dims(w, h, k)) for k in range(n)]


@pytest.mark.parametrize("w,h,signed", [(64, 64, False), (20, 8, True), (4, 4, False), (1, 1, False), (256, 32, True)])
def test_round_trip_full_chain(tmp_path, w, h, signed):
    levels = _chain(w, h)
    p = tmp_path / "t.dds"
    dds.write(p, levels, signed=signed)
    tex = dds.read(p)
    fmt, width, height, got = tex
    assert fmt == (96 if signed else 95) and (width, height) == (w, h) and tex.signed == signed
    assert len(got) == len(levels) == dds.max_mip_count(w, h)
    for (a, wa, ha), (b, wb, hb) in zip(levels, got):
        assert (wa, ha) == (wb, hb) and np.array_equal(a, b)
    # levels smaller than 4x4 occupy one block
    assert got[-1][0].shape == (1, 16)
    assert p.stat().st_size == 148 + 16 * sum(b.shape[0] for b, _, _ in levels)


def test_header_fields(tmp_path):
    p = tmp_path / "t.dds"
    dds.write(p, _chain(64, 32))
    raw = p.read_bytes()
    size, flags, height, width, linear, _depth, mips = struct.unpack_from("<7I", raw, 4)
    assert (size, height, width, mips) == (124, 32, 64, 7)
    assert linear == 16 * 16 * 8  # top level bytes
    assert flags & dds.DDSD_LINEARSIZE and flags & dds.DDSD_MIPMAPCOUNT and not flags & 0x8  # no pitch flag
    caps = struct.unpack_from("<I", raw, 4 + 104)[0]
    assert caps == dds.DDSCAPS_TEXTURE | dds.DDSCAPS_COMPLEX | dds.DDSCAPS_MIPMAP
    assert raw[84:88] == b"DX10"
    assert struct.unpack_from("<5I", raw, 128) == (95, 3, 0, 1, 0)


def test_single_level_has_no_mipmap_caps(tmp_path):
    p = tmp_path / "t.dds"
    dds.write(p, _chain(16, 16, n=1))
    assert struct.unpack_from("<I", p.read_bytes(), 4 + 104)[0] == dds.DDSCAPS_TEXTURE


def test_openimageio_reads_header(tmp_path):
    oiio = pytest.importorskip("OpenImageIO")
    p = tmp_path / "t.dds"
    dds.write(p, _chain(32, 16), signed=True)
    inp = oiio.ImageInput.open(str(p))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    assert (spec.width, spec.height, spec.nchannels) == (32, 16, 3)
    assert spec.get_string_attribute("compression").upper().startswith("BC6H")
    nmips = 0
    while inp.seek_subimage(0, nmips):
        nmips += 1
    assert nmips == 6
    inp.close()


@pytest.mark.parametrize("cut", [0, 3, 100, 140, 148, 148 + 16 * 5])
def test_truncated_file_is_a_clear_error(tmp_path, cut):
    p = tmp_path / "t.dds"
    dds.write(p, _chain(16, 16))
    p.write_bytes(p.read_bytes()[:cut])
    with pytest.raises(dds.DdsError, match="t.dds: "):
        dds.read(p)


def test_trailing_bytes_and_bad_fields(tmp_path):
    p = tmp_path / "t.dds"
    dds.write(p, _chain(16, 16))
    good = p.read_bytes()
    p.write_bytes(good + b"\0" * 16)
    with pytest.raises(dds.DdsError, match="trailing"):
        dds.read(p)
    bad = bytearray(good); struct.pack_into("<I", bad, 128, 77)  # BC3
    p.write_bytes(bytes(bad))
    with pytest.raises(dds.DdsError, match="DXGI format 77 is not one bcfpipe reads"):
        dds.read(p)
    bad = bytearray(good); struct.pack_into("<I", bad, 4 + 24, 9)  # 9 mips for 16x16
    p.write_bytes(bytes(bad))
    with pytest.raises(dds.DdsError, match="exceed"):
        dds.read(p)
    bad = bytearray(good); bad[84:88] = b"DXT1"
    p.write_bytes(bytes(bad))
    with pytest.raises(dds.DdsError, match="DX10"):
        dds.read(p)
    bad = bytearray(good); struct.pack_into("<I", bad, 128 + 12, 6)  # array of 6
    p.write_bytes(bytes(bad))
    with pytest.raises(dds.DdsError, match="single 2D"):
        dds.read(p)
    with pytest.raises(dds.DdsError, match="cannot read"):
        dds.read(tmp_path / "missing.dds")


def test_write_validates_levels(tmp_path):
    levels = _chain(16, 16)
    with pytest.raises(ValueError, match="level 1"):
        dds.write(tmp_path / "a.dds", [levels[0], levels[2]])
    with pytest.raises(ValueError, match="uint8 blocks"):
        dds.write(tmp_path / "a.dds", [(levels[0][0][:3], 16, 16)])
    with pytest.raises(ValueError, match="at least one"):
        dds.write(tmp_path / "a.dds", [])
    assert not list(tmp_path.iterdir())  # nothing half-written
