"""The bench's BC7 quality set and its sizes on disk (issue 52): the quality set's packing and
encode, the ASTC blocks astcenc writes, and disk bytes against an independent compressor (the zstd
command line, and python's zstandard decompressing back to the very blocks)."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_baselines import make_set, needs_astcenc  # noqa: E402

from bcfpipe.bench.cells import blocks_disk_bytes, texture_files  # noqa: E402
from bcfpipe.texset.baselines import (  # noqa: E402
    BC7_QUALITY, astc_mips, astcenc_path, encode_texture_set_baseline, pack_texture_set,
)
from bcfpipe.texset.metrics import compute_metrics  # noqa: E402
from bcfpipe.texset.texture_set import build_mip_chain  # noqa: E402

ZSTD_FRAME_SLACK = 8  # the CLI and the library may write the frame header a few bytes apart


def zstd_cli_bytes(data: bytes, tmp: Path) -> int:
    """``zstd -19 --no-check -c FILE | wc -c`` of ``data``."""
    f = tmp / "blob.bin"
    f.write_bytes(data)
    p = subprocess.run(["zstd", "-19", "--no-check", "-q", "-c", str(f)], capture_output=True, check=True)
    return len(p.stdout)


def test_quality_set_packs_bc1_as_bc7() -> None:
    ts = make_set()
    bc = pack_texture_set(ts, "bc")
    assert pack_texture_set(ts, BC7_QUALITY) == [("bc7" if f == "bc1" else f, idx) for f, idx in bc]
    assert [f for f, _ in pack_texture_set(ts, BC7_QUALITY)] == ["bc7", "bc5", "bc7", "bc4"]


def test_quality_set_encodes_bc7_at_twice_bc1s_bytes_and_no_worse() -> None:
    ts = make_set()
    ref = build_mip_chain(ts.data)
    bc_tex: list = []
    q_tex: list = []
    bc_dec, bc_size = encode_texture_set_baseline(ts, "bc", ref_mips=ref, textures=bc_tex)
    q_dec, q_size = encode_texture_set_baseline(ts, BC7_QUALITY, ref_mips=ref, textures=q_tex)
    blocks = sum([64, 16, 4, 1, 1, 1])  # 32, 16, 8, 4, 2, 1
    assert bc_size == blocks * (8 + 16 + 8 + 8) and q_size == blocks * (16 + 16 + 16 + 8)
    assert [f for f, _, _ in q_tex] == ["bc7", "bc5", "bc7", "bc4"]
    for (f, idx, lv), (fb, idxb, lvb) in zip(q_tex, bc_tex):
        assert idx == idxb and [(w, h) for _, w, h in lv] == [(w, h) for _, w, h in lvb]
        if f != "bc7":  # BC5 and BC4 are BC@R's own blocks
            assert all(np.array_equal(a, b) for (a, _, _), (b, _, _) in zip(lv, lvb))
    bc_m = compute_metrics(ref, bc_dec, ts.channels, ssim=False, flip=False)
    q_m = compute_metrics(ref, q_dec, ts.channels, ssim=False, flip=False)
    assert q_m.psnr_per_group["albedo"] > bc_m.psnr_per_group["albedo"] + 1.0
    assert q_m.psnr_per_group["normal"] == bc_m.psnr_per_group["normal"]
    # a half-size quality set: level 0 is reference mip 1, as BC's
    half: list = []
    encode_texture_set_baseline(ts, BC7_QUALITY, 16, ref_mips=ref, textures=half)
    assert [(w, h) for _, w, h in half[0][2]][0] == (16, 16)


@needs_astcenc
def test_astc_blocks_are_the_measured_texels(tmp_path: Path) -> None:
    """With ``blocks``, astcenc runs -cl then -dl: the same texels as -tl, and the .astc blocks; a
    level's file (`texture_files`) is byte for byte the one astcenc writes."""
    import OpenImageIO as oiio

    mips = build_mip_chain(make_set(32, 32).data[..., :3])  # 32 = 5 whole 6x6 blocks and a partial one
    plain, size = astc_mips(mips, "6x6", "-fast")
    blocks: list = []
    kept, size2 = astc_mips(mips, "6x6", "-fast", tmp_dir=str(tmp_path), blocks=blocks)
    assert size2 == size and all(np.array_equal(a, b) for a, b in zip(plain, kept))
    assert [(w, h) for _, w, h in blocks] == [(m.shape[1], m.shape[0]) for m in mips]
    assert [b.shape for b, _, _ in blocks] == [(-(-w // 6) * -(-h // 6), 16) for _, w, h in blocks]
    assert sum(b.nbytes for b, _, _ in blocks) == size
    png, out = tmp_path / "m1.png", tmp_path / "m1.astc"
    px = np.rint(np.clip(mips[1], 0, 1) * 255).astype(np.uint8)
    assert oiio.ImageBuf(np.ascontiguousarray(px)).write(str(png))
    subprocess.run([astcenc_path(), "-cl", str(png), str(out), "6x6", "-fast", "-silent"], check=True)
    assert texture_files([("astc", [0, 1, 2], blocks[1:2])], "6x6") == [out.read_bytes()]


@pytest.mark.skipif(shutil.which("zstd") is None, reason="needs the zstd command line")
def test_disk_bytes_against_the_zstd_command_line(tmp_path: Path) -> None:
    """Each texture as `formats.dds.write` writes it, compressed by ``zstd -19 --no-check``: the
    bench's disk bytes within a few bytes of frame header per file; zstandard gives the files back."""
    import zstandard

    from bcfpipe.formats import dds
    from bcfpipe.formats.bcn import DXGI, ClassicFormat

    ts = make_set(64, 64)
    ref = build_mip_chain(ts.data)
    textures: list = []
    encode_texture_set_baseline(ts, BC7_QUALITY, ref_mips=ref, textures=textures)
    files = []
    for k, (fmt, _, levels) in enumerate(textures):
        dds.write(tmp_path / f"{k}.dds", levels, dxgi_format=DXGI[ClassicFormat(fmt)])
        files.append((tmp_path / f"{k}.dds").read_bytes())
    assert texture_files(textures) == files
    cli = sum(zstd_cli_bytes(f, tmp_path) for f in files)
    ours = blocks_disk_bytes(textures)
    assert abs(ours - cli) <= ZSTD_FRAME_SLACK * len(files), (ours, cli)
    assert ours < sum(len(f) for f in files)  # zstd finds something to take
    z = zstandard.ZstdCompressor(level=19)
    assert all(zstandard.ZstdDecompressor().decompress(z.compress(f)) == f for f in files)
