"""Issue 50, "HDR stays HDR": a float colour beyond 1 ships as BC6H_UF16 of its linear values (what
a UsdUVTexture reads as it is), never as BC1 or inside a BC7 repack; a float scalar beyond 1 stays
BC4 with an affine map; and a layout's figures for HDR channels are measured where compute_metrics
measures them (the log domain), so the layout block and the headline PSNR are one figure."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from bcfpipe.bc6h.decode import block_modes
from bcfpipe.formats import dds
from bcfpipe.formats.bcn import BLOCK_BYTES, DXGI, FORMAT_OF, ClassicFormat, decode_levels
from bcfpipe.layout import choose as C
from bcfpipe.layout.classic import channel_errors, encode, groups, repacks
from bcfpipe.texset.metrics import compute_metrics, mse_per_channel
from bcfpipe.texset.texture_set import build_mip_chain, load_texture_set

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_hdr import hdr_ramp, write_exr  # noqa: E402

N = 64


@pytest.fixture(scope="module")
def hdr_set(tmp_path_factory):
    """An HDR emissive ramp (0..3,000, half EXR), an 8-bit albedo, a float displacement in [0, 5]
    alone in its file: BC6H + BC1 + BC4 in BC@R."""
    import OpenImageIO as oiio

    root = tmp_path_factory.mktemp("hdr")
    emissive = write_exr(root / "emissive.exr", hdr_ramp(N))
    y, x = (np.mgrid[0:N, 0:N] + 0.5) / N
    alb = np.stack([0.5 + 0.4 * np.sin(6.28 * x), 0.5 + 0.3 * np.cos(6.28 * y), 0.3 + 0.2 * x], -1)
    buf = oiio.ImageBuf(oiio.ImageSpec(N, N, 3, "uint8"))
    buf.set_pixels(oiio.ROI(), np.ascontiguousarray(alb, np.float32))
    assert buf.write(str(root / "albedo.png"))
    disp = write_exr(root / "disp.exr", np.repeat((5 * x * y)[..., None], 3, -1))
    ts = load_texture_set([f"emissiveColor={emissive}:rgb", f"albedo={root / 'albedo.png'}:rgb",
                           f"displacement={disp}:r"])
    return ts, np.asarray(oiio.ImageBuf(str(emissive)).get_pixels(oiio.FLOAT)).reshape(N, N, 3)


def test_bc6h_is_a_classic_format_with_its_dxgi_code_and_block_size():
    assert DXGI[ClassicFormat.BC6H] == dds.DXGI_FORMAT_BC6H_UF16 == 95
    assert FORMAT_OF[95] == ClassicFormat.BC6H and BLOCK_BYTES[ClassicFormat.BC6H] == dds.block_bytes(95) == 16
    assert dds.DXGI_NAMES[95] == "BC6H_UF16"


def test_an_hdr_colour_group_is_bc6h_a_float_scalar_stays_bc4(hdr_set):
    ts, _ = hdr_set
    by_name = {g.name: g for g in groups(ts)}
    assert {n: g.format for n, g in by_name.items()} == {
        "emissiveColor": ClassicFormat.BC6H, "albedo": ClassicFormat.BC1, "displacement": ClassicFormat.BC4}
    em, disp = by_name["emissiveColor"], by_name["displacement"]
    # BC6H stores the source value itself: texel * scale + bias = set value, scale = 1 / value_scale
    for (scale, bias), c in zip(em.texel_map(ts), em.channels):
        assert ts.channels[c].log_gain > 11 and scale * ts.channels[c].value_scale == pytest.approx(1.0)
        assert bias == 0.0 and str(bias) == "0.0"
    # a scalar beyond 1 is linear (no log curve): BC4 of its normalised value, undone by the affine
    # value_scale / value_bias that the USD layer folds into the UsdUVTexture's scale and bias
    (c,) = disp.channels
    assert ts.channels[c].log_gain == 0.0 and ts.channels[c].value_scale == pytest.approx(5 * (1 - 0.5 / N) ** 2, rel=1e-3)
    assert disp.texel_map(ts) == ((1.0, 0.0),)


def test_bc6h_blocks_hold_the_linear_values_and_three_decoders_agree(hdr_set, tmp_path):
    import OpenImageIO as oiio
    import texture2ddecoder as t2d

    ts, source = hdr_set
    ref = build_mip_chain(ts.data)
    (enc,) = [e for e in encode(ts, N, ref, "clamp") if e.group.format == ClassicFormat.BC6H]
    assert [(w, h) for _, w, h in enc.levels] == [(N >> k, N >> k) for k in range(N.bit_length())]  # every mip
    texels = decode_levels(ClassicFormat.BC6H, enc.levels)
    scale, bias = np.array(enc.group.texel_map(ts)).T
    for k, t in enumerate(texels):  # what the layout measured is what the blocks decode to
        np.testing.assert_allclose(t * scale + bias, enc.decoded[k], rtol=1e-6, atol=1e-9)
    # level 0 is the source's linear values, to BC6H's relative precision: within the robustness
    # floor (0.05, 5 %) on this ramp, steep enough that one 4×4 block spans a factor 1.65
    band = (source >= 1) & (source <= 10)
    assert np.median(np.abs(texels[0][band] - source[band]) / source[band]) < 0.05
    assert np.abs(np.log1p(texels[0]) - np.log1p(source)).mean() < 0.05
    path = tmp_path / "C0.dds"
    dds.write(path, enc.levels, dxgi_format=DXGI[ClassicFormat.BC6H])
    assert path.stat().st_size == dds.HEADER_BYTES + sum(16 * dds.block_count(w, h) for _, w, h in enc.levels)
    back = dds.read(path)
    assert back.dxgi_format == 95 and back.format_name == "BC6H_UF16" and back.mip_count == len(enc.levels)
    inp = oiio.ImageInput.open(str(path))
    misread = 0
    try:
        for k, ((blocks, w, h), t) in enumerate(zip(back.levels, texels)):
            assert inp.seek_subimage(0, k)  # OpenImageIO (bcdec): the same fp16 bits
            half = np.asarray(inp.read_image(format="half")).reshape(h, w, -1)[..., :3]
            np.testing.assert_array_equal(half.view(np.uint16), t.astype(np.float16).view(np.uint16))
            # texture2ddecoder: 8 bits clamped to [0, 1], the same values in every block but those of
            # mode 2, whose endpoints it misreads (bcfpipe, OpenImageIO and Mesa agree there)
            pw, ph = (w + 3) // 4 * 4, (h + 3) // 4 * 4
            bgra = np.frombuffer(t2d.decode_bc6(blocks.tobytes(), pw, ph), np.uint8).reshape(ph, pw, 4)
            ours = np.pad(np.rint(np.clip(t, 0, 1) * 255), ((0, ph - h), (0, pw - w), (0, 0)), mode="edge")
            differ = (bgra[..., [2, 1, 0]] != ours)[:h, :w].any(-1)
            per_block = np.pad(differ, ((0, ph - h), (0, pw - w))).reshape(ph // 4, 4, pw // 4, 4).any((1, 3))
            modes = np.asarray(block_modes(blocks)).reshape(ph // 4, pw // 4)
            assert set(modes[per_block].tolist()) <= {2}, (k, set(modes[per_block].tolist()))
            misread += int(per_block.sum())
    finally:
        inp.close()
    assert misread < len(enc.levels[0][0]) // 10


def test_repacks_never_take_an_hdr_group(hdr_set):
    ts, _ = hdr_set
    gs = groups(ts)
    hdr = {c for g in gs if g.format == ClassicFormat.BC6H for c in g.channels}
    found = repacks(gs)
    assert found  # albedo + displacement still repack
    for rp in found:
        assert "emissiveColor" not in rp.replaces
        assert not hdr & {c for g in rp.groups for c in g.channels}, rp.label


def test_a_layouts_hdr_figures_are_the_headline_psnrs(hdr_set):
    """BC@R's per-channel errors (channel_errors) and the exported measure (mse_per_channel,
    compute_metrics) agree, HDR channels in their log domain: one PSNR for one material."""
    ts, _ = hdr_set
    ref = build_mip_chain(ts.data)
    enc = encode(ts, N // 2, ref, "repeat")
    e_bc = channel_errors(ts, enc, ref)
    dec = [np.zeros_like(m) for m in ref]
    for e in enc:
        for k, m in enumerate(e.decoded):
            dec[k][..., list(e.group.channels)] = m
    np.testing.assert_allclose(e_bc, mse_per_channel(ref, dec, ts.channels), rtol=1e-9)
    use = tuple(k for k, m in enumerate(ref) if min(m.shape[:2]) >= 4)
    bc = C.Candidate(tuple(e.group.name for e in enc), None, 0, C.combine(None, e_bc, range(ts.num_channels)),
                     "measured", use)
    assert bc.psnr == pytest.approx(compute_metrics(ref, dec, ts.channels, ssim=False, flip=False).psnr, abs=1e-9)


@pytest.mark.gl
def test_bc6h_classic_blocks_decode_as_the_gpu_does(hdr_set):
    """Mesa (or the GPU driver) decodes the shipped BC6H chain to the same fp16 bits as bcfpipe."""
    from gl_oracle import gl_decode_bc6h_mips

    ts, _ = hdr_set
    (enc,) = [e for e in encode(ts, N, build_mip_chain(ts.data), "clamp") if e.group.format == ClassicFormat.BC6H]
    for gl, t in zip(gl_decode_bc6h_mips(enc.levels, False), decode_levels(ClassicFormat.BC6H, enc.levels)):
        np.testing.assert_array_equal(np.asarray(gl, np.float16).view(np.uint16), t.astype(np.float16).view(np.uint16))
