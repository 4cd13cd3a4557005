"""BC6H decoder: bit-exactness against two independent decoders, known answers, edge cases.

Oracles
-------
A. Mesa's OpenGL driver (llvmpipe through EGL; tests/gl_oracle.py), which
   decodes BPTC float with its own code (src/util/format/texcompress_bptc_tmp.h).
B. OpenImageIO's DDS reader (BC6H through the vendored bcdec decoder).

Known oracle quirk (A, signed only): Mesa's ``finish_signed_unquantize``
returns ``(-v * 31 / 32) | 0x8000`` for every negative interpolated value v,
so v == -1 (whose magnitude rounds to 0) gives -0.0 (0x8000).  The D3D11
spec's ``finish_unquantize`` negates the rounded value first and only sets the
sign bit if it is still negative, giving +0.0 (0x0000).  We follow the spec
(as do OpenImageIO/bcdec and DirectXTex); the Mesa comparison therefore
accepts exactly the pairs (ours 0x0000, Mesa 0x8000) and nothing else.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from bcfpipe.bc6h import decode
from bcfpipe.bc6h.decode import block_modes, decode_to_u16
from bcfpipe.bc6h.tables import ANCHOR2, MODES, PARTITIONS2, RESERVED_MODE_VALUES, WEIGHTS3, WEIGHTS4

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gl_oracle  # noqa: E402

PER_MODE = 7200  # x 14 modes = 100,800 uniformly random blocks per signedness
EXTREME_PER_MODE = 2000  # x 14 modes = 28,000 more with many 0x00/0xFF bytes
RESERVED_PER_VALUE = 64  # x 4 reserved mode values


def random_blocks(seed: int, per_mode: int = PER_MODE, reserved_per_value: int = 0,
                  extreme: bool = False) -> np.ndarray:
    """Random blocks, ``per_mode`` for each of the 14 modes (mode bits forced), shuffled.

    ``extreme``: each byte is 0x00 or 0xFF with probability 1/3 each, so that
    endpoint fields often hit 0 / all-ones (the unquantize special cases,
    signed saturation, delta wraparound).
    """
    rng = np.random.default_rng(seed)
    values = [(m.value, m.mode_bits) for m in MODES] + [(v, 5) for v in RESERVED_MODE_VALUES]
    counts = [per_mode] * len(MODES) + [reserved_per_value] * len(RESERVED_MODE_VALUES)
    parts = []
    for (value, nbits), count in zip(values, counts):
        b = rng.integers(0, 256, (count, 16), dtype=np.uint8)
        if extreme:
            pick = rng.integers(0, 3, (count, 16))
            b = np.where(pick == 0, 0, np.where(pick == 1, 255, b)).astype(np.uint8)
        mask = (1 << nbits) - 1
        b[:, 0] = (b[:, 0] & ~np.uint8(mask)) | np.uint8(value)
        parts.append(b)
    blocks = np.concatenate(parts)
    return blocks[rng.permutation(len(blocks))]


def blocks_as_image(blocks: np.ndarray, blocks_per_row: int = 256) -> tuple[np.ndarray, int, int]:
    """Pad with zero blocks to a full grid; returns (blocks, width, height)."""
    n = len(blocks)
    bh = -(-n // blocks_per_row)
    padded = np.zeros((bh * blocks_per_row, 16), dtype=np.uint8)
    padded[:n] = blocks
    return padded, blocks_per_row * 4, bh * 4


def image_to_block_texels(img_u16: np.ndarray, n: int) -> np.ndarray:
    """(H, W, 3) texels of a full block grid -> (n, 16, 3) per block, row-major texels."""
    h, w, _ = img_u16.shape
    bh, bw = h // 4, w // 4
    return img_u16.reshape(bh, 4, bw, 4, 3).transpose(0, 2, 1, 3, 4).reshape(bh * bw, 16, 3)[:n]


@pytest.fixture(scope="module", params=[False, True], ids=["unsigned", "signed"])
def random_case(request):
    signed = request.param
    blocks = np.concatenate([
        random_blocks(seed=1000 + signed, reserved_per_value=RESERVED_PER_VALUE),
        random_blocks(seed=2000 + signed, per_mode=EXTREME_PER_MODE, extreme=True),
    ])
    return signed, blocks, decode_to_u16(blocks, signed)


# --------------------------------------------------------------------------- tables


def test_tables_shapes_and_invariants():
    assert PARTITIONS2.shape == (32, 16) and PARTITIONS2.dtype == np.uint8
    assert ANCHOR2.shape == (32,) and ANCHOR2.dtype == np.uint8
    assert set(np.unique(PARTITIONS2)) == {0, 1}
    assert (PARTITIONS2[:, 0] == 0).all(), "texel 0 is subset 0's anchor in every shape"
    assert (PARTITIONS2[np.arange(32), ANCHOR2] == 1).all(), "the anchor of subset 1 lies in subset 1"
    assert len({r.tobytes() for r in PARTITIONS2}) == 32
    assert WEIGHTS3.tolist() == [0, 9, 18, 27, 37, 46, 55, 64]
    assert WEIGHTS4.tolist() == [0, 4, 9, 13, 17, 21, 26, 30, 34, 38, 43, 47, 51, 55, 60, 64]
    assert len(MODES) == 14 and len({m.value for m in MODES}) == 14


def test_block_modes():
    blocks = random_blocks(seed=5, per_mode=10, reserved_per_value=3)
    modes = block_modes(blocks)
    assert np.bincount(modes, minlength=15).tolist() == [12] + [10] * 14


# --------------------------------------------------------------------------- known answers


def _bits(value: int, hi: int, lo: int) -> list[int]:
    """Bits of ``value`` for a spec range ``[hi:lo]``, in stream order (lo first; reversed if lo > hi)."""
    step = 1 if hi >= lo else -1
    return [(value >> b) & 1 for b in range(lo, hi + step, step)]


def _pack(stream: list[int]) -> np.ndarray:
    assert len(stream) == 128, len(stream)
    v = sum(bit << i for i, bit in enumerate(stream))
    return np.frombuffer(v.to_bytes(16, "little"), dtype=np.uint8).reshape(1, 16).copy()


def _unq_unsigned(v: int, bits: int) -> int:
    if bits >= 15:
        return v
    if v == 0:
        return 0
    if v == (1 << bits) - 1:
        return 0xFFFF
    return ((v << 16) + 0x8000) >> bits


def _interp(a: int, b: int, w: int) -> int:
    return (a * (64 - w) + b * w + 32) >> 6  # Python >> floors, like the spec's arithmetic shift


def _finish_signed(v: int) -> int:
    v = -(((-v) * 31) >> 5) if v < 0 else (v * 31) >> 5
    return (0x8000 | -v) if v < 0 else v


def test_known_answer_mode_11110_unsigned():
    """Mode 10 (11110): 6-bit untransformed endpoints, shape 0, hand-packed from the spec layout."""
    # endpoints [w, x, y, z] per channel; subset 0 uses w/x, subset 1 uses y/z
    r = [0, 63, 10, 30]
    g = [32, 63, 20, 20]
    b = [63, 0, 30, 10]
    (rw, rx, ry, rz), (gw, gx, gy, gz), (bw, bx, by, bz) = r, g, b
    shape = 0
    idx = [0, 1, 2, 3, 4, 5, 6, 7, 7, 6, 5, 4, 3, 2, 1, 3]  # texels 0 and 15 are anchors (< 4)
    stream = (
        _bits(0b11110, 4, 0) + _bits(rw, 5, 0) + _bits(gz, 4, 4) + _bits(bz, 0, 0) + _bits(bz, 1, 1)
        + _bits(by, 4, 4) + _bits(gw, 5, 0) + _bits(gy, 5, 5) + _bits(by, 5, 5) + _bits(bz, 2, 2)
        + _bits(gy, 4, 4) + _bits(bw, 5, 0) + _bits(gz, 5, 5) + _bits(bz, 3, 3) + _bits(bz, 5, 5)
        + _bits(bz, 4, 4) + _bits(rx, 5, 0) + _bits(gy, 3, 0) + _bits(gx, 5, 0) + _bits(gz, 3, 0)
        + _bits(bx, 5, 0) + _bits(by, 3, 0) + _bits(ry, 5, 0) + _bits(rz, 5, 0) + _bits(shape, 4, 0)
    )
    assert len(stream) == 82
    for t in range(16):
        stream += _bits(idx[t], 1 if t in (0, 15) else 2, 0)
    block = _pack(stream)

    part = [0, 0, 1, 1] * 4  # shape 0
    expected = np.zeros((16, 3), dtype=np.uint16)
    for t in range(16):
        s = part[t]
        for c, ch in enumerate((r, g, b)):
            e0 = _unq_unsigned(ch[2 * s], 6)
            e1 = _unq_unsigned(ch[2 * s + 1], 6)
            expected[t, c] = (_interp(e0, e1, [0, 9, 18, 27, 37, 46, 55, 64][idx[t]]) * 31) >> 6
    # a few values worked by hand: texel 0 = endpoint w exactly
    assert expected[0].tolist() == [0, (33280 * 31) >> 6, (0xFFFF * 31) >> 6] == [0, 16120, 31743]
    got = decode_to_u16(block, signed=False)[0]
    np.testing.assert_array_equal(got, expected)
    img = decode(block, 4, 4).view(np.uint16)
    np.testing.assert_array_equal(img.reshape(16, 3), expected)


def test_known_answer_mode_01111_signed():
    """Mode 14 (01111), signed: 16-bit endpoint w, 4-bit deltas; covers -1 -> +0, -32768 -> -inf, wraparound."""
    w = [0xFFFF, 0x8000, 0x7FFF]     # -1, -32768, 32767 as 16-bit two's complement
    d = [0x1, 0xF, 0x8]              # deltas +1, -1, -8 (4-bit)
    idx = [0] + [(t * 5) % 16 for t in range(1, 16)]
    stream = _bits(0b01111, 4, 0) + _bits(w[0], 9, 0) + _bits(w[1], 9, 0) + _bits(w[2], 9, 0)
    for c in range(3):
        stream += _bits(d[c], 3, 0) + _bits(w[c], 10, 15)  # rw[10:15] is stored MSB first
    assert len(stream) == 65
    for t in range(16):
        stream += _bits(idx[t], 2 if t == 0 else 3, 0)
    block = _pack(stream)

    def sext(v, n):
        return v - (1 << n) if v & (1 << (n - 1)) else v

    e0 = [sext(v, 16) for v in w]                                         # [-1, -32768, 32767]
    e1 = [sext((sext(dv, 4) + a) & 0xFFFF, 16) for dv, a in zip(d, e0)]   # [0, 32767, 32759]
    assert e0 == [-1, -32768, 32767] and e1 == [0, 32767, 32759]
    expected = np.array(
        [[_finish_signed(_interp(e0[c], e1[c], WEIGHTS4[idx[t]])) for c in range(3)] for t in range(16)],
        dtype=np.uint16,
    )
    assert expected[0].tolist() == [0x0000, 0xFC00, 0x7BFF]  # +0 (not -0), -inf, max finite
    np.testing.assert_array_equal(decode_to_u16(block, signed=True)[0], expected)


@pytest.mark.parametrize("signed", [False, True])
def test_reserved_modes_decode_to_zero(signed):
    rng = np.random.default_rng(7)
    blocks = rng.integers(0, 256, (4 * 50, 16), dtype=np.uint8)
    blocks[:, 0] = (blocks[:, 0] & 0xE0) | np.repeat(np.array(RESERVED_MODE_VALUES, dtype=np.uint8), 50)
    assert (decode_to_u16(blocks, signed) == 0).all()


def test_output_value_ranges(random_case):
    """Unsigned: no sign bit, no inf/NaN (max 0x7BFF). Signed: never NaN, never -0; inf only as -inf."""
    signed, _, ours = random_case
    exp_all_ones = (ours & 0x7C00) == 0x7C00
    if not signed:
        assert not (ours & 0x8000).any()
        assert not exp_all_ones.any()
    else:
        assert (ours[exp_all_ones] == 0xFC00).all()
        assert not (ours == 0x8000).any()


# --------------------------------------------------------------------------- edge cases


@pytest.mark.parametrize("w,h", [(1, 1), (5, 7), (13, 4), (4, 9), (16, 16)])
def test_crop_matches_full_decode(w, h):
    bw, bh = -(-w // 4), -(-h // 4)
    blocks = random_blocks(seed=w * 100 + h, per_mode=2)[: bw * bh]
    full = decode(blocks, bw * 4, bh * 4, signed=True)
    part = decode(blocks, w, h, signed=True)
    assert part.shape == (h, w, 3) and part.dtype == np.float16
    np.testing.assert_array_equal(part.view(np.uint16), full[:h, :w].view(np.uint16))
    # block (bx, by) texel (x, y) lands at image (4*by + y, 4*bx + x)
    per_block = decode_to_u16(blocks, signed=True)
    np.testing.assert_array_equal(full.view(np.uint16)[4 * (bh - 1) + 1, 4 * (bw - 1) + 2],
                                  per_block[bw * bh - 1, 4 * 1 + 2])


def test_invalid_inputs():
    good = np.zeros((4, 16), dtype=np.uint8)
    with pytest.raises(ValueError, match="dtype uint8"):
        decode(good.astype(np.int16), 8, 8)
    with pytest.raises(ValueError, match=r"shape \(n, 16\)"):
        decode(good.reshape(8, 8), 8, 8)
    with pytest.raises(ValueError, match=r"shape \(n, 16\)"):
        decode_to_u16(good.reshape(-1))
    with pytest.raises(ValueError, match="numpy array"):
        decode(good.tolist(), 8, 8)
    with pytest.raises(ValueError, match="needs 2x2 = 4 blocks, got 3"):
        decode(good[:3], 8, 8)
    with pytest.raises(ValueError, match="needs 3x1 = 3 blocks, got 4"):
        decode(good, 9, 4)
    for bad in (0, -4, 4.0, True):
        with pytest.raises(ValueError, match="width must be a positive integer"):
            decode(good, bad, 8)
    with pytest.raises(ValueError, match="height must be a positive integer"):
        decode(good, 8, None)
    # non-contiguous input is accepted
    strided = np.zeros((4, 32), dtype=np.uint8)[:, ::2]
    assert decode(strided, 8, 8).shape == (8, 8, 3)


# --------------------------------------------------------------------------- oracle A: Mesa OpenGL


def _compare_with_mesa(ours: np.ndarray, theirs: np.ndarray, signed: bool) -> tuple[int, int]:
    """Return (strict mismatching halves, of which Mesa's -0 quirk); assert nothing else differs."""
    diff = ours != theirs
    if not signed:
        return int(diff.sum()), 0
    quirk = diff & (ours == 0x0000) & (theirs == 0x8000)
    other = diff & ~quirk
    if other.any():
        i = np.argwhere(other)[0]
        raise AssertionError(f"{int(other.sum())} halves differ from Mesa beyond the -0 quirk; first at "
                             f"block/texel/channel {i.tolist()}: ours 0x{ours[tuple(i)]:04X}, "
                             f"Mesa 0x{theirs[tuple(i)]:04X}")
    return int(diff.sum()), int(quirk.sum())


@pytest.mark.gl
def test_random_blocks_match_mesa_gl(random_case, record_property):
    signed, blocks, ours = random_case
    theirs = gl_oracle.gl_decode_blocks(blocks, signed)
    mismatches, quirk = _compare_with_mesa(ours, theirs, signed)
    record_property("blocks", len(blocks))
    record_property("mismatching_halves", mismatches)
    print(f"\n[Mesa GL, {'signed' if signed else 'unsigned'}] {len(blocks)} blocks, "
          f"{mismatches} mismatching halves ({quirk} are Mesa's -0 for spec +0); {gl_oracle.renderer()}")
    if not signed:
        assert mismatches == 0
    # coverage: all 14 modes and all 32 shapes were exercised
    modes = block_modes(blocks)
    assert (np.bincount(modes, minlength=15)[1:] == PER_MODE + EXTREME_PER_MODE).all()
    two = np.isin(modes, [m.number for m in MODES if m.regions == 2])
    shapes = (blocks[two, 9] >> 5) | ((blocks[two, 10] & 3) << 3)  # d[4:0] = block bits 77..81
    assert len(np.unique(shapes)) == 32


@pytest.mark.gl
@pytest.mark.parametrize("signed", [False, True])
def test_mip_chain_and_odd_sizes_match_mesa_gl(signed):
    w0, h0 = 37, 23
    levels = []
    for k in range(max(w0, h0).bit_length()):
        w, h = max(1, w0 >> k), max(1, h0 >> k)
        n = (-(-w // 4)) * (-(-h // 4))
        levels.append((random_blocks(seed=300 + 10 * k + signed, per_mode=5)[:n].copy(), w, h))
    theirs = gl_oracle.gl_decode_bc6h_mips(levels, signed)
    for (blocks, w, h), t in zip(levels, theirs):
        ours = decode(blocks, w, h, signed)
        assert ours.shape == t.shape == (h, w, 3)
        a, b = ours.view(np.uint16), t.view(np.uint16)
        if signed:
            b = np.where((a == 0) & (b == 0x8000), 0, b)  # Mesa's -0 quirk, see module docstring
        np.testing.assert_array_equal(a, b, err_msg=f"level {w}x{h}")


# --------------------------------------------------------------------------- oracle B: OpenImageIO


def _write_dds(path, levels, signed):
    from bcfpipe.formats import dds

    dds.write(path, levels, signed=signed)


def _oiio_read_levels(path) -> tuple[str, list[np.ndarray]]:
    oiio = pytest.importorskip("OpenImageIO")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        pytest.skip(f"OpenImageIO cannot open BC6H DDS: {oiio.geterror()}")
    try:
        compression = inp.spec().get_string_attribute("compression")
        out, level = [], 0
        while inp.seek_subimage(0, level):
            img = inp.read_image(format="half")
            assert img is not None, inp.geterror()
            out.append(np.ascontiguousarray(img.reshape(inp.spec().height, inp.spec().width, -1)[..., :3]))
            level += 1
        return compression, out
    finally:
        inp.close()


def test_random_blocks_match_openimageio(random_case, tmp_path, record_property):
    signed, blocks, ours = random_case
    padded, w, h = blocks_as_image(blocks)
    path = tmp_path / "random.dds"
    _write_dds(path, [(padded, w, h)], signed)
    compression, (img,) = _oiio_read_levels(path)
    assert compression == ("BC6HS" if signed else "BC6HU")
    theirs = image_to_block_texels(img.view(np.uint16), len(blocks))
    mismatches = int((theirs != ours).sum())
    record_property("blocks", len(blocks))
    record_property("mismatching_halves", mismatches)
    print(f"\n[OpenImageIO, {'signed' if signed else 'unsigned'}] {len(blocks)} blocks, "
          f"{mismatches} mismatching halves")
    assert mismatches == 0


@pytest.mark.parametrize("signed", [False, True])
def test_mip_chain_and_odd_sizes_match_openimageio(signed, tmp_path):
    w0, h0 = 29, 6
    levels = []
    for k in range(max(w0, h0).bit_length()):
        w, h = max(1, w0 >> k), max(1, h0 >> k)
        n = (-(-w // 4)) * (-(-h // 4))
        levels.append((random_blocks(seed=500 + 10 * k + signed, per_mode=3)[:n].copy(), w, h))
    path = tmp_path / "mips.dds"
    _write_dds(path, levels, signed)
    _, imgs = _oiio_read_levels(path)
    assert len(imgs) == len(levels)
    for (blocks, w, h), img in zip(levels, imgs):
        assert img.shape == (h, w, 3)
        np.testing.assert_array_equal(decode(blocks, w, h, signed).view(np.uint16), img.view(np.uint16),
                                      err_msg=f"level {w}x{h}")


def test_known_answer_blocks_match_openimageio(tmp_path):
    """The -1 -> +0 and -32768 -> -inf corner cases agree with OpenImageIO (bcdec) too."""
    # mode 14 signed, every endpoint channel w = 0xFFFF / 0x8000 / 0x7FFF, all indices 0
    stream = _bits(0b01111, 4, 0) + _bits(0xFFFF, 9, 0) + _bits(0x8000, 9, 0) + _bits(0x7FFF, 9, 0)
    for v in (0xFFFF, 0x8000, 0x7FFF):
        stream += _bits(0, 3, 0) + _bits(v, 10, 15)
    stream += [0] * 63
    block = _pack(stream)
    path = tmp_path / "kat.dds"
    _write_dds(path, [(block, 4, 4)], True)
    _, (img,) = _oiio_read_levels(path)
    ours = decode(block, 4, 4, signed=True).view(np.uint16)
    assert (ours.reshape(16, 3) == [0x0000, 0xFC00, 0x7BFF]).all()
    np.testing.assert_array_equal(ours, img.view(np.uint16))
    assert math.isinf(float(decode(block, 4, 4, signed=True)[0, 0, 1]))


@pytest.mark.slow
@pytest.mark.gl
@pytest.mark.parametrize("signed", [False, True])
def test_million_blocks_match_both_oracles(signed, tmp_path):
    """1,000,006 random blocks (71,429 per mode, half of them 'extreme') against Mesa and OpenImageIO."""
    blocks = np.concatenate([random_blocks(seed=9000 + signed, per_mode=35715),
                             random_blocks(seed=9100 + signed, per_mode=35714, extreme=True)])
    ours = decode_to_u16(blocks, signed)
    gl = gl_oracle.gl_decode_blocks(blocks, signed, blocks_per_row=1024)
    mismatches, quirk = _compare_with_mesa(ours, gl, signed)
    padded, w, h = blocks_as_image(blocks, blocks_per_row=1024)
    _write_dds(tmp_path / "big.dds", [(padded, w, h)], signed)
    _, (img,) = _oiio_read_levels(tmp_path / "big.dds")
    oiio_mismatches = int((image_to_block_texels(img.view(np.uint16), len(blocks)) != ours).sum())
    print(f"\n[1M, {'signed' if signed else 'unsigned'}] {len(blocks)} blocks: Mesa {mismatches} mismatching "
          f"halves ({quirk} -0 quirk), OpenImageIO {oiio_mismatches}")
    assert oiio_mismatches == 0 and mismatches == quirk
