"""Mode-10 (mode bits 11110) pack/unpack and the BC6H encoder."""

from __future__ import annotations

import importlib
import time

import numpy as np
import pytest

from bcfpipe.bc6h import mode10
from bcfpipe.bc6h.decode import decode, decode_to_u16
from bcfpipe.bc6h.tables import ANCHOR2, PARTITIONS2

# the package re-exports the function ``encode`` under the submodule's name
enc = importlib.import_module("bcfpipe.bc6h.encode")

# ---------------------------------------------------------------------------
# pack / unpack
# ---------------------------------------------------------------------------

# Header of mode 11110 in the order iOrange/bcdec reads it (field, first bit, count),
# transcribed independently of bcfpipe's own table: endpoints w, x, y, z = 0..3.
_BCDEC_ORDER = [
    ("r0", 0, 6), ("g3", 4, 1), ("b3", 0, 1), ("b3", 1, 1), ("b2", 4, 1), ("g0", 0, 6),
    ("g2", 5, 1), ("b2", 5, 1), ("b3", 2, 1), ("g2", 4, 1), ("b0", 0, 6), ("g3", 5, 1),
    ("b3", 3, 1), ("b3", 5, 1), ("b3", 4, 1), ("r1", 0, 6), ("g2", 0, 4), ("g1", 0, 6),
    ("g3", 0, 4), ("b1", 0, 6), ("b2", 0, 4), ("r2", 0, 6), ("r3", 0, 6), ("d", 0, 5),
]


def test_header_layout_matches_references():
    expect = []
    for name, first, count in _BCDEC_ORDER:
        field = 12 if name == "d" else 3 * int(name[1]) + "rgb".index(name[0])
        expect += [[field, first + i] for i in range(count)]
    assert mode10.HEADER_LAYOUT.tolist() == expect
    from bcfpipe.bc6h import tables

    if hasattr(tables, "LAYOUTS"):  # the shared D3D table of the decoder
        assert tables.LAYOUTS[10][5:].tolist() == expect


def _random_params(rng, n, signed=False):
    lo, hi = (-32, 31) if signed else (0, 63)
    return rng.integers(lo, hi + 1, (n, 4, 3)), rng.integers(0, 8, (n, 16)), rng.integers(0, 32, n)


@pytest.mark.parametrize("signed", [False, True])
def test_pack_unpack_roundtrip_and_decode(signed):
    rng = np.random.default_rng(10 + signed)
    e, idx, part = _random_params(rng, 5000, signed)
    blocks = mode10.pack(e, idx, part, signed=signed)
    assert blocks.dtype == np.uint8 and blocks.shape == (5000, 16)
    assert np.all(blocks[:, 0] & 0x1F == 0b11110)
    e2, i2, p2 = mode10.unpack(blocks, signed=signed)
    assert np.array_equal(p2, part)
    ec, ic, _ = mode10.canonicalize(e, idx, part)
    assert np.array_equal(e2, ec) and np.array_equal(i2, ic)
    # packed blocks decode (independent decoder) to the values the parameters describe
    want = mode10.decode_params(e, idx, part, signed=signed).view(np.uint16)
    assert np.array_equal(decode_to_u16(blocks, signed=signed), want)
    assert np.array_equal(mode10.pack(e2, i2, p2, signed=signed), blocks)


def test_known_values():
    # e = 0 -> 0, e = 63 -> 0xFFFF -> 65504, e = 32 -> (32*1024 + 512)*31 >> 6 = 16120 = 0x3EF8
    e = np.zeros((1, 4, 3), int)
    e[0, 1] = 63
    e[0, 2] = 32
    e[0, 3] = 32
    idx = np.zeros((1, 16), int)
    idx[0, 3] = 7
    img = decode(mode10.pack(e, idx, [0]), 4, 4).astype(np.float32)
    assert img[0, 0].tolist() == [0.0, 0.0, 0.0]  # texel 0: subset 0, index 0
    assert img[0, 3].tolist() == [1.7421875] * 3  # texel 3: subset 1 (shape 0), endpoints 32/32
    assert np.float16(1.7421875).view(np.uint16) == 0x3EF8
    idx[0, 1] = 7  # texel 1: subset 0, index 7 -> endpoint 63 -> 65504
    img = decode(mode10.pack(e, idx, [0]), 4, 4).astype(np.float32)
    assert img[0, 1].tolist() == [65504.0] * 3
    # signed: -31 -> -0x7FFF -> -(0x7FFF*31 >> 5) = -31743 -> -65504
    es = np.full((1, 4, 3), -31)
    imgs = decode(mode10.pack(es, np.zeros((1, 16), int), [5], signed=True), 4, 4, signed=True)
    assert np.all(imgs.astype(np.float32) == -65504.0)


def test_anchor_rule():
    e = np.arange(12).reshape(1, 4, 3) + 10
    part = np.array([17])  # anchor of subset 1 is texel 2
    assert ANCHOR2[17] == 2
    idx = np.zeros((1, 16), int)
    idx[0, 0] = 6  # subset-0 anchor with MSB set
    idx[0, 2] = 5  # subset-1 anchor with MSB set
    idx[0, 3] = 1
    blocks = mode10.pack(e, idx, part)
    e2, i2, p2 = mode10.unpack(blocks)
    assert e2[0, 0].tolist() == e[0, 1].tolist() and e2[0, 1].tolist() == e[0, 0].tolist()
    assert e2[0, 2].tolist() == e[0, 3].tolist() and e2[0, 3].tolist() == e[0, 2].tolist()
    s1 = PARTITIONS2[17].astype(bool)
    assert np.array_equal(i2[0], 7 - idx[0])  # every index of both subsets inverted
    assert i2[0, 0] < 4 and i2[0, 2] < 4 and s1[2] and not s1[0]
    assert np.array_equal(decode_to_u16(blocks), mode10.decode_params(e, idx, part).view(np.uint16))
    # only the flipped subset changes
    idx2 = np.zeros((1, 16), int)
    idx2[0, 2] = 4
    e3, i3, _ = mode10.unpack(mode10.pack(e, idx2, part))
    assert e3[0, 0].tolist() == e[0, 0].tolist() and e3[0, 2].tolist() == e[0, 3].tolist()
    assert np.array_equal(i3[0, ~s1], idx2[0, ~s1]) and np.array_equal(i3[0, s1], 7 - idx2[0, s1])


def test_pack_unpack_validation():
    e, idx, part = _random_params(np.random.default_rng(0), 4)
    e[0, 0, 0], idx[0, 0], part[0] = 63, 7, 31
    with pytest.raises(ValueError):
        mode10.pack(e + 1, idx, part)  # 64 out of range
    with pytest.raises(ValueError):
        mode10.pack(e - 64, idx, part, signed=False)
    with pytest.raises(ValueError):
        mode10.pack(e, idx, part, signed=True)  # 63 is not a signed 6-bit value
    with pytest.raises(ValueError):
        mode10.pack(e, idx + 1, part)
    with pytest.raises(ValueError):
        mode10.pack(e, idx, part + 1)
    with pytest.raises(ValueError):
        mode10.pack(e, idx[:3], part)
    with pytest.raises(ValueError):
        mode10.pack(e + 0.5, idx, part)
    blocks = mode10.pack(e, idx, part)
    blocks[2, 0] = (blocks[2, 0] & 0xE0) | 0b00011  # mode 11 (one region)
    with pytest.raises(ValueError, match="11110"):
        mode10.unpack(blocks)
    assert mode10.is_mode10(blocks).tolist() == [True, True, False, True]


# ---------------------------------------------------------------------------
# encoder
# ---------------------------------------------------------------------------


def _psnr(a, b):
    return 10 * np.log10(1.0 / np.mean((np.asarray(a, np.float64) - b) ** 2))


def _exact_blocks(rng, n, signed):
    """Decoded mode-10 blocks with known parameters, every subset using indices 0 and 7."""
    lo, hi = (-12, 12) if signed else (22, 38)  # a texture-like dynamic range
    e = rng.integers(lo, hi + 1, (n, 4, 3))
    part = rng.integers(0, 32, n)
    idx = rng.integers(0, 8, (n, 16))
    for b in range(n):
        for s in (0, 1):
            tex = np.flatnonzero(PARTITIONS2[part[b]] == s)
            idx[b, rng.choice(tex, 2, replace=False)] = [0, 7]
    return e, idx, part, mode10.decode_params(e, idx, part, signed=signed).astype(np.float32)


@pytest.mark.parametrize("signed", [False, True])
def test_encoder_recovers_exact_two_region_blocks(signed):
    rng = np.random.default_rng(42 + signed)
    n = 256
    e, idx, part, dec = _exact_blocks(rng, n, signed)
    img = enc.image_from_blocks(dec, 64, 64)
    ep, ix, pt = enc.encode_params(img, signed=signed)
    got = mode10.decode_params(ep, ix, pt, signed=signed).astype(np.float32)
    err = ((got - dec) ** 2).sum(axis=(1, 2))
    # the chosen shape does at least as well as the true one, which is exact (up to
    # a negligible 1e-6 relative, from ties of the least-squares surrogate)
    assert np.all(err <= 1e-6 * (dec.astype(np.float64) ** 2).sum(axis=(1, 2)))
    assert np.mean(err == 0) > 0.98
    assert np.mean(pt == part) > 0.95


def test_encoder_shape_choice_close_to_exhaustive_and_beats_partition0():
    y, x = np.mgrid[0:32, 0:32] / 31.0
    edge = (x + 0.5 * y > 0.7).astype(np.float32)  # a diagonal edge through many blocks
    img = np.stack([0.1 + 0.8 * edge, 0.6 - 0.4 * edge * y, 0.3 + 0.5 * x], -1).astype(np.float32)
    best = enc.encode(img)
    d_best = decode(best, 32, 32).astype(np.float32)
    # per block, no forced single shape does better than the chosen one
    blocks_img = enc.blocks_from_image(img)
    e_best = ((enc.blocks_from_image(d_best) - blocks_img) ** 2).sum(axis=(1, 2))
    e_all = []
    for p in range(32):
        d = decode(enc.encode(img, partitions=p), 32, 32).astype(np.float32)
        e_all.append(((enc.blocks_from_image(d) - blocks_img) ** 2).sum(axis=(1, 2)))
    e_all = np.stack(e_all, 1)
    print("chosen / best forced shape, total error:", e_best.sum() / e_all.min(1).sum())
    assert np.mean(e_best <= e_all.min(1) * 1.05 + 1e-7) > 0.7
    assert e_best.sum() <= 1.15 * e_all.min(1).sum()
    assert e_best.sum() < 0.9 * e_all[:, 0].sum()
    assert _psnr(d_best, img) > _psnr(decode(enc.encode(img, partitions=0), 32, 32).astype(np.float32), img)


def test_error_bounds():
    y, x = np.mgrid[0:64, 0:64] / 63.0
    smooth = np.stack([0.2 + 0.7 * x, 0.1 + 0.8 * y, 0.5 + 0.3 * np.sin(3 * x + 2 * y)], -1).astype(np.float32)
    d = decode(enc.encode(smooth), 64, 64).astype(np.float32)
    assert _psnr(d, smooth) > 37.0 and np.abs(d - smooth).max() < 0.08
    noise = np.random.default_rng(0).random((64, 64, 3)).astype(np.float32)
    d = decode(enc.encode(noise), 64, 64).astype(np.float32)
    assert _psnr(d, noise) > 14.5
    # HDR-ish smooth data, relative error
    hdr = smooth * 300.0
    d = decode(enc.encode(hdr), 64, 64).astype(np.float32)
    assert np.sqrt(np.mean((d - hdr) ** 2)) / np.sqrt(np.mean(hdr**2)) < 0.03
    # signed
    sg = (smooth - 0.5) * 2
    d = decode(enc.encode(sg, signed=True), 64, 64, signed=True).astype(np.float32)
    assert _psnr(d / 2, sg / 2) > 33.0


def test_constant_blocks_use_interpolation():
    for v in (0.1, 0.5, 0.76, 1.0, 3.0):
        img = np.full((4, 4, 3), v, np.float32) * np.array([1.0, 0.8, 0.5], np.float32)
        d = decode(enc.encode(img), 4, 4).astype(np.float32)
        assert np.abs(d - img).max() <= 0.02 * v


def test_clamping_and_validation():
    img = np.full((4, 8, 3), 1e6, np.float32)
    img[:, :4] = -5.0
    d = decode(enc.encode(img), 8, 4).astype(np.float32)
    assert np.all(d[:, :4] == 0.0) and np.all(d[:, 4:] == 65504.0)
    d = decode(enc.encode(img, signed=True), 8, 4, signed=True).astype(np.float32)
    assert np.all(d[:, 4:] == 65504.0) and np.allclose(d[:, :4], -5.0, rtol=0.01)
    with pytest.raises(ValueError):
        enc.encode(np.zeros((6, 8, 3), np.float32))
    with pytest.raises(ValueError):
        enc.encode(np.zeros((8, 6, 3), np.float32))
    with pytest.raises(ValueError):
        enc.encode(np.zeros((8, 8), np.float32))
    with pytest.raises(ValueError):
        enc.encode(np.zeros((8, 8, 4), np.float32))
    for bad in (np.nan, np.inf, -np.inf):
        x = np.zeros((8, 8, 3), np.float32)
        x[3, 5, 1] = bad
        with pytest.raises(ValueError):
            enc.encode(x)
    with pytest.raises(ValueError):
        enc.encode(np.zeros((8, 8, 3)), partitions=32)


def test_params_blocks_and_forced_partitions_agree():
    rng = np.random.default_rng(3)
    img = rng.random((16, 24, 3)).astype(np.float32) * 0.3 + 0.2
    ep, ix, pt = enc.encode_params(img)
    assert ep.shape == (24, 4, 3) and ix.shape == (24, 16) and pt.shape == (24,)
    assert ep.min() >= 0 and ep.max() <= 63 and ix.min() >= 0 and ix.max() <= 7
    blocks = enc.encode(img)
    assert np.array_equal(blocks, mode10.pack(ep, ix, pt))
    assert np.array_equal(decode(blocks, 24, 16).view(np.uint16),
                          enc.image_from_blocks(mode10.decode_params(ep, ix, pt), 24, 16).view(np.uint16))
    forced = np.arange(24) % 32
    _, _, pf = enc.encode_params(img, partitions=forced)
    assert np.array_equal(pf, forced)
    _, _, p7 = enc.encode_params(img, partitions=7)
    assert np.all(p7 == 7)
    # deterministic and independent of chunking / threading
    ep2, ix2, pt2 = enc.encode_params(img, chunk=5, workers=2)
    assert np.array_equal(ep, ep2) and np.array_equal(ix, ix2) and np.array_equal(pt, pt2)


@pytest.mark.skipif(not __import__("torch").cuda.is_available(), reason="needs CUDA")
def test_encode_on_cuda_matches_cpu_quality():
    y, x = np.mgrid[0:64, 0:64] / 63.0
    img = np.stack([0.2 + 0.7 * x, 0.1 + 0.8 * y, 0.5 + 0.3 * np.sin(3 * x + 2 * y)], -1).astype(np.float32)
    d_cpu = decode(enc.encode(img), 64, 64).astype(np.float32)
    d_gpu = decode(enc.encode(img, device="cuda"), 64, 64).astype(np.float32)
    assert abs(_psnr(d_gpu, img) - _psnr(d_cpu, img)) < 0.2
