"""Texture-set loading: spec parsing, channel selection, value conventions, resampling, mips."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from bcfpipe.texset import texture_set as texset
from bcfpipe.texset.texture_set import (
    SEMANTICS, TextureError, TextureSet, TextureSpec, build_mip_chain, common_resolution,
    load_texture_set, semantic_info,
)

SCENES = Path(__file__).resolve().parents[1].parent / "shared" / "scenes"
needs_shared = pytest.mark.skipif(not SCENES.is_dir(), reason=f"real texture files not available ({SCENES} is absent)")
FORMATS = SCENES / "usdwg_texture_file_formats"
MISC = SCENES / "materialx_texture_sets" / "misc"


def write_image(path: Path, pixels: np.ndarray, fmt=oiio.UINT8, names: tuple[str, ...] | None = None) -> Path:
    """Write an (H, W, n) float image in [0, 1] to `path` with OpenImageIO."""
    h, w, n = pixels.shape
    spec = oiio.ImageSpec(w, h, n, fmt)
    if names:
        spec.channelnames = names
    if n == 4 or (names and "A" in names):
        spec.alpha_channel = n - 1
        spec.attribute("oiio:UnassociatedAlpha", 1)
    buf = oiio.ImageBuf(spec)
    buf.set_pixels(oiio.ROI(0, w, 0, h, 0, 1, 0, n), np.ascontiguousarray(pixels, dtype=np.float32))
    assert buf.write(str(path)), buf.geterror()
    return path


def q8(x: np.ndarray) -> np.ndarray:
    return np.rint(x * 255) / 255


@pytest.fixture
def rng():
    return np.random.default_rng(7)


# ---------------------------------------------------------------------------------- specs


def test_registry_semantics_and_aliases():
    assert semantic_info("diffuseColor").name == "albedo"
    assert SEMANTICS["albedo"].usd_input == "diffuseColor" and SEMANTICS["albedo"].kind == "color"
    assert SEMANTICS["normal"].channels == 2 and SEMANTICS["normal"].kind == "normal"
    for name in ("occlusion", "roughness", "metallic", "displacement", "opacity"):
        assert SEMANTICS[name].channels == 1 and SEMANTICS[name].kind == "scalar"
    assert SEMANTICS["emissiveColor"].channels == 3 and SEMANTICS["generic"].channels is None
    with pytest.raises(ValueError, match="unknown texture semantic"):
        semantic_info("sheen")


def test_spec_parse_defaults_and_selection(tmp_path):
    assert TextureSpec.parse("albedo=diff.jpg") == TextureSpec("albedo", "diff.jpg", "rgb")
    assert TextureSpec.parse("diffuseColor=diff.jpg").semantic == "albedo"
    assert TextureSpec.parse("roughness=arm.jpg:g").channels == "g"
    assert TextureSpec.parse("roughness=arm.jpg").channels == "r"
    assert TextureSpec.parse("normal=nrm.png").channels == "xy"
    assert TextureSpec.parse("normal=nrm.png:xy").channels == "xy"
    assert TextureSpec.parse("generic=mask.png:rga").channels == "rga"
    # a colon that is not a channel selection stays part of the path
    assert TextureSpec.parse("albedo=C:/tex/d.png").path == "C:/tex/d.png"
    assert TextureSpec.parse("albedo=d.png", base_dir=tmp_path).path == str(tmp_path / "d.png")
    assert str(TextureSpec.parse("metallic=arm.jpg:b")) == "metallic=arm.jpg:b"


@pytest.mark.parametrize("text, message", [
    ("albedo=diff.jpg:rg", "albedo needs 3 channel"),
    ("normal=n.png:xyz", "normal needs 2 channel"),
    ("roughness=arm.jpg:rg", "roughness needs 1 channel"),
    ("albedo", "expected semantic=path"),
    ("=diff.jpg", "expected semantic=path"),
    ("shininess=s.png", "unknown texture semantic"),
    ("albedo=arm.jpg:rgbq", "bad channel selection 'rgbq'"),  # not 'texture file not found: arm.jpg:rgbq'
])
def test_spec_parse_errors(text, message):
    with pytest.raises(ValueError, match=message):
        TextureSpec.parse(text)


def test_spec_rejects_bad_letters():
    with pytest.raises(ValueError, match="bad channel selection"):
        TextureSpec("roughness", "a.png", "q")


# ------------------------------------------------------------------------------ generated files


def test_load_rgb_scalar_and_normal_values(tmp_path, rng):
    rgb = rng.random((16, 8, 3))
    arm = rng.random((16, 8, 3))
    f_rgb = write_image(tmp_path / "diff.png", rgb)
    f_arm = write_image(tmp_path / "arm.png", arm)
    f_nrm = write_image(tmp_path / "nrm.png", rgb[..., ::-1])
    ts = load_texture_set([f"albedo={f_rgb}", f"roughness={f_arm}:g", f"metallic={f_arm}:b",
                           f"normal={f_nrm}:xy"])
    assert (ts.width, ts.height) == (8, 16) and ts.data.shape == (16, 8, 7) and ts.data.dtype == np.float32
    assert ts.groups() == {"albedo": [0, 1, 2], "roughness": [3], "metallic": [4], "normal": [5, 6]}
    np.testing.assert_allclose(ts.data[..., :3], q8(rgb), atol=1e-6)  # stored values, no linearisation
    np.testing.assert_allclose(ts.data[..., 3], q8(arm[..., 1]), atol=1e-6)
    np.testing.assert_allclose(ts.data[..., 4], q8(arm[..., 2]), atol=1e-6)


def test_load_channels_groups_and_normal_mapping(tmp_path, rng):
    rgb = rng.random((8, 8, 3))
    f = write_image(tmp_path / "n.png", rgb)
    ts = load_texture_set([f"albedo={f}", f"roughness={f}:g", f"normal={f}:xy"])
    assert [c.name for c in ts.channels] == ["albedo.r", "albedo.g", "albedo.b", "roughness.g", "normal.x", "normal.y"]
    assert ts.groups() == {"albedo": [0, 1, 2], "roughness": [3], "normal": [4, 5]}
    assert [c.kind for c in ts.channels] == ["color"] * 3 + ["scalar"] + ["normal"] * 2
    assert [c.source_channel for c in ts.channels] == [0, 1, 2, 1, 0, 1]
    np.testing.assert_allclose(ts.data[..., 4:], q8(rgb[..., :2]) * 2 - 1, atol=1e-6)
    assert ts.channels[4].peak == 2.0 and ts.channels[0].peak == 1.0


def test_grey_replicates_and_grey_alpha(tmp_path, rng):
    y = rng.random((8, 8, 1))
    ya = np.concatenate([y, rng.random((8, 8, 1))], axis=-1)
    f_y = write_image(tmp_path / "g.png", y)
    f_ya = write_image(tmp_path / "ga.png", ya, names=("Y", "A"))
    ts = load_texture_set([f"albedo={f_y}", f"opacity={f_ya}:a", f"roughness={f_ya}:g"])
    for c in range(3):
        np.testing.assert_allclose(ts.data[..., c], q8(y[..., 0]), atol=1e-6)
    np.testing.assert_allclose(ts.data[..., 3], q8(ya[..., 1]), atol=1e-6)
    # straight alpha: the grey value is not premultiplied by alpha
    np.testing.assert_allclose(ts.data[..., 4], q8(ya[..., 0]), atol=1e-6)


def test_rgba_unassociated_alpha_kept(tmp_path):
    px = np.zeros((4, 4, 4))
    px[..., :3] = 0.8
    px[..., 3] = 0.0  # transparent but coloured: a premultiplying reader would return 0
    f = write_image(tmp_path / "rgba.png", px)
    ts = load_texture_set([f"albedo={f}", f"opacity={f}:a"])
    np.testing.assert_allclose(ts.data[..., :3], q8(0.8), atol=1e-6)
    assert np.all(ts.data[..., 3] == 0)


def test_16bit_and_float_files(tmp_path, rng):
    v = rng.random((8, 8, 3))
    f16 = write_image(tmp_path / "v16.png", v, fmt=oiio.UINT16)
    fexr = write_image(tmp_path / "v.exr", v * 3.0, fmt=oiio.HALF)
    ts16 = load_texture_set([f"albedo={f16}"])
    np.testing.assert_allclose(ts16.data, np.rint(v * 65535) / 65535, atol=1e-6)
    tsx = load_texture_set([f"generic={fexr}:rgb"])
    # float data passes through unclamped: stored normalised to its range, value = t * scale + bias
    scale = np.array([c.value_scale for c in tsx.channels])
    bias = np.array([c.value_bias for c in tsx.channels])
    np.testing.assert_allclose(tsx.data * scale + bias, v * 3.0, rtol=2e-3, atol=1e-6)
    assert tsx.data.max() == pytest.approx(1.0) and (scale > 1.0).all() and (bias == 0).all()


def test_missing_channel_and_file_errors(tmp_path, rng):
    f = write_image(tmp_path / "rgb.png", rng.random((4, 4, 3)))
    with pytest.raises(TextureError, match=r"rgb\.png: has 3 channel\(s\) \(R,G,B\); cannot read channel 'a'"):
        load_texture_set([f"opacity={f}:a"])
    with pytest.raises(TextureError, match="not found"):
        load_texture_set([f"albedo={tmp_path / 'nope.png'}"])
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image")
    with pytest.raises(TextureError, match="cannot read image"):
        load_texture_set([f"albedo={bad}"])
    with pytest.raises(ValueError, match="given twice"):
        load_texture_set([f"albedo={f}", f"albedo={f}"])
    with pytest.raises(ValueError, match="powers of two"):
        load_texture_set([f"albedo={f}"], resolution=12)
    assert issubclass(TextureError, ValueError)


def test_each_file_read_once(tmp_path, rng, monkeypatch):
    f = write_image(tmp_path / "arm.png", rng.random((8, 8, 3)))
    g = write_image(tmp_path / "d.png", rng.random((4, 4, 3)))
    opened, resized = [], []
    real_open, real_resize = texset._open, oiio.ImageBufAlgo.resize
    monkeypatch.setattr(texset, "_open", lambda p, shown: opened.append(p) or real_open(p, shown))
    monkeypatch.setattr(oiio.ImageBufAlgo, "resize", lambda *a, **k: resized.append(1) or real_resize(*a, **k))
    ts = load_texture_set([f"occlusion={f}:r", f"roughness={f}:g", f"metallic={f}:b", f"albedo={g}"])
    assert sorted(opened) == sorted([str(f), str(g)])
    assert len(resized) == 1 and (ts.width, ts.height) == (8, 8)  # only the 4x4 file is resampled


def test_common_resolution_rule():
    assert common_resolution([(1280, 1024)]) == (1024, 1024)
    assert common_resolution([(2048, 2048), (512, 512)]) == (2048, 2048)
    assert common_resolution([(4256, 2832)]) == (4096, 2048)
    assert common_resolution([(221, 510), (100, 100)]) == (256, 512)
    assert common_resolution([(1536, 1)]) == (2048, 1)


def test_resample_npot_non_square_without_overshoot(tmp_path, rng):
    step = np.zeros((20, 48, 1))
    step[:, 24:] = 1.0
    const = np.full((20, 48, 3), 0.4)
    f_step = write_image(tmp_path / "step.png", step)
    f_const = write_image(tmp_path / "c.png", const)
    ts = load_texture_set([f"roughness={f_step}", f"albedo={f_const}"])
    assert (ts.width, ts.height) == (64, 16)  # 48 -> 64, 20 -> 16: per-axis nearest power of two
    assert ts.data[..., 0].min() >= 0.0 and ts.data[..., 0].max() <= 1.0  # positive filter: no ringing
    np.testing.assert_allclose(ts.data[..., 1:], q8(0.4), atol=1e-5)
    ts2 = load_texture_set([f"albedo={f_const}"], resolution=(8, 32))
    assert ts2.data.shape == (32, 8, 3)


def test_texture_set_validation():
    ch = (texset.Channel("roughness", "r", "scalar", "x.png", 0),)
    with pytest.raises(ValueError, match="float32"):
        TextureSet(np.zeros((2, 2, 1)), ch, 2, 2)
    with pytest.raises(ValueError, match="expected"):
        TextureSet(np.zeros((2, 2, 1), np.float32), ch, 4, 2)


# ---------------------------------------------------------------------------------- mips


def test_mip_chain_box_average_non_square(rng):
    a = rng.random((8, 2, 3)).astype(np.float32)
    mips = build_mip_chain(a)
    assert [m.shape[:2] for m in mips] == [(8, 2), (4, 1), (2, 1), (1, 1)]
    assert mips[0] is a or np.array_equal(mips[0], a)
    np.testing.assert_allclose(mips[1][0, 0], a[:2, :2].mean(axis=(0, 1)), rtol=1e-6)
    np.testing.assert_allclose(mips[2][1, 0], a[4:, :].mean(axis=(0, 1)), rtol=1e-6)
    for m in mips:
        np.testing.assert_allclose(m.mean(axis=(0, 1)), a.mean(axis=(0, 1)), rtol=1e-5)
    assert all(m.dtype == np.float32 for m in mips)
    assert [m.shape for m in build_mip_chain(np.zeros((4, 4)))] == [(4, 4), (2, 2), (1, 1)]
    with pytest.raises(ValueError, match="power-of-two"):
        build_mip_chain(np.zeros((6, 4, 1)))


# ------------------------------------------------------------------------------ real files


@pytest.mark.shared
@needs_shared
def test_real_grey_jpeg_and_grey_alpha_png():
    ts = load_texture_set([f"albedo={FORMATS / 'jpeg_grayscale_8-bit.jpg'}"])
    assert (ts.width, ts.height) == (256, 256)
    assert np.array_equal(ts.data[..., 0], ts.data[..., 1]) and np.array_equal(ts.data[..., 0], ts.data[..., 2])
    f8, f16 = FORMATS / "png_grayscale_8-bit.png", FORMATS / "png_grayscale_16-bit.png"
    ts = load_texture_set([f"roughness={f8}", f"opacity={f8}:a", f"displacement={f16}:r"])
    assert ts.channels[1].source_channel == 1
    assert 0.0 <= ts.data.min() and ts.data.max() <= 1.0
    # 16-bit precision survives: values are not on the 8-bit grid
    assert np.mean(np.abs(ts.data[..., 2] * 255 - np.rint(ts.data[..., 2] * 255)) > 1e-3) > 0.5
    # grey+alpha holds transparent texels; their grey is kept, not premultiplied to 0
    a = ts.data[..., 1]
    assert (a < 0.1).sum() > 0 and ts.data[..., 0][a < 0.1].mean() > 0.05


@pytest.mark.shared
@needs_shared
def test_real_rgba_png_alpha_and_missing_alpha():
    f = FORMATS / "png_rgb_8-bit.png"
    ts = load_texture_set([f"albedo={f}", f"opacity={f}:a"])
    a = ts.data[..., 3]
    assert (a < 0.1).sum() > 0 and ts.data[..., :3][a < 0.1].mean() > 0.05  # straight alpha
    with pytest.raises(TextureError, match=r"jpeg_rgb_8-bit\.jpg: has 3 channel"):
        load_texture_set([f"opacity={FORMATS / 'jpeg_rgb_8-bit.jpg'}:a"])


@pytest.mark.shared
@needs_shared
def test_real_cmyk_jpeg_converted_to_plausible_rgb():
    cmyk = load_texture_set([f"albedo={FORMATS / 'jpeg_cmyk_8-bit.jpg'}"]).data
    rgb = load_texture_set([f"albedo={FORMATS / 'jpeg_rgb_8-bit.jpg'}"]).data
    assert cmyk.shape == rgb.shape == (256, 256, 3)
    # OIIO converts CMYK naively (no ICC): not identical, but the same picture, not inverted
    assert np.abs(cmyk - rgb).mean() < 0.15
    for c in range(3):
        assert np.corrcoef(cmyk[..., c].ravel(), rgb[..., c].ravel())[0, 1] > 0.8  # text differs too


@pytest.mark.shared
@needs_shared
def test_real_exr_half_and_palette_formats():
    ts = load_texture_set([f"albedo={MISC / 'gamma_chart.exr'}"], resolution=1024)
    assert ts.data.shape == (1024, 1024, 3) and np.isfinite(ts.data).all()
    assert 0.0 <= ts.data.min() and ts.data.max() <= 1.0 + 1e-3
    bmp = load_texture_set([f"albedo={MISC / 'cloth.bmp'}"], resolution=128).data
    tga = load_texture_set([f"albedo={MISC / 'cloth.tga'}"], resolution=128).data
    gif = load_texture_set([f"albedo={MISC / 'cloth.gif'}"], resolution=128).data
    assert np.abs(bmp - tga).mean() < 0.01  # same picture, lossless formats
    assert np.abs(bmp - gif).mean() < 0.08  # palette-quantised


@pytest.mark.shared
@needs_shared
def test_real_npot_non_square_file():
    f = next(SCENES.glob("usdwg_vehicles/**/wheelRedAsset_ZPos.png"), None)
    if f is None:
        pytest.skip("wheelRedAsset_ZPos.png (221x510) not found under shared/scenes")
    ts = load_texture_set([f"albedo={f}", f"opacity={f}:a"])
    assert (ts.width, ts.height) == (256, 512)
    assert 0.0 <= ts.data.min() and ts.data.max() <= 1.0


@pytest.mark.shared
@needs_shared
def test_real_packed_arm_read_once(monkeypatch):
    tex = SCENES / "usdwg_teapot" / "textures"
    arm = tex / "tea_set_01_arm_2k.jpg"
    opened = []
    real_open = texset._open
    monkeypatch.setattr(texset, "_open", lambda p, shown: opened.append(p) or real_open(p, shown))
    ts = load_texture_set([f"albedo={tex / 'tea_set_01_diff_2k.jpg'}", f"occlusion={arm}:r",
                           f"roughness={arm}:g", f"metallic={arm}:b"], resolution=256)
    assert len(opened) == 2 and ts.data.shape == (256, 256, 6)
    assert [c.source_channel for c in ts.channels[3:]] == [0, 1, 2]
    assert len(build_mip_chain(ts.data)) == 9
