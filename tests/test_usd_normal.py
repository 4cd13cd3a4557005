"""Normals a renderer can use (issue 57, item 3): a layout's classic normal is BC5 of its slopes
(x / z, y / z) / m, the USD layer reads it as (s_x, s_y, 1) / M (r, g: scale 2m / M, bias -m / M; b:
scale 0, bias 1 / M, M = max(m, 1)) so that every component stays in [-1, 1], and what a
UsdPreviewSurface shades with, the DDS as OpenImageIO decodes it with that scale and bias,
normalised, is within a small angle of the source's normal; layout.json and the manifest report it."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from pxr import Sdf, Usd, UsdShade

from bcfpipe.cli import main
from bcfpipe.formats import manifest as mfst
from bcfpipe.formats import material as mf
from bcfpipe.texset.normals import angular_stats, rebuild_z, unit, usd_normal

N = 128
BOUND = (0.45, 1.1)  # mean, p99 degrees (measured 0.39, 0.93); BC7 x, y, z, shipped before the slopes, is worse
LOOKS = "/World/Looks/Smooth"


def bumps(n: int = N) -> np.ndarray:
    """A tangent-space normal map of smooth bumps, tilted up to about 50 degrees: (n, n, 3) unit."""
    y, x = np.mgrid[0:n, 0:n] / n
    xy = np.stack([0.6 * np.sin(2 * np.pi * 2 * x) * np.cos(2 * np.pi * y),
                   0.5 * np.cos(2 * np.pi * 3 * y) * np.sin(2 * np.pi * x)], -1)
    return rebuild_z(xy)


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, np.ndarray]:
    """The smooth quad with a normal map (scale 2, bias -1, as authors wire one), built with
    ``--classic normal`` at R = 128 (``--profile auto``); (OUT, the source normals as stored 8-bit, back to unit vectors)."""
    from test_render import smooth_stage, write_png

    root = tmp_path_factory.mktemp("usd_normal")
    quad = smooth_stage(root)
    write_png(root / "tex" / "normal.png", (bumps() + 1.0) * 0.5)
    stage = Usd.Stage.Open(str(quad))
    tex = UsdShade.Shader.Define(stage, f"{LOOKS}/normalTex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./tex/normal.png")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
    tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set((2.0, 2.0, 2.0, 1.0))
    tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set((-1.0, -1.0, -1.0, 0.0))
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        UsdShade.Shader(stage.GetPrimAtPath(f"{LOOKS}/St")).ConnectableAPI(), "result")
    tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    UsdShade.Shader(stage.GetPrimAtPath(f"{LOOKS}/Surface")).CreateInput(
        "normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    stage.GetRootLayer().Save()
    out = root / "out"
    r = CliRunner().invoke(main, ["build", str(quad), "-o", str(out), "--quality", "smoke", "--profile", "auto",
                                  "--layout", "neural", "--classic", "normal", "--jobs", "1", "--threads", "1",
                                  "--no-cache"])
    assert r.exit_code == 0, r.output
    import OpenImageIO as oiio

    src = np.asarray(oiio.ImageBuf(str(root / "tex" / "normal.png")).get_pixels(oiio.FLOAT), np.float32)[..., :3]
    return out, unit(src * 2.0 - 1.0)


def test_the_normal_usd_reads_stores_z_with_scale_2_bias_minus_1(built) -> None:
    out, _ = built
    man = mfst.read(out)
    stage = Usd.Stage.Open(str(out / man.root_layer))
    surface = UsdShade.Shader(stage.GetPrimAtPath(f"{LOOKS}/Surface"))
    src, output, _ = surface.GetInput("normal").GetConnectedSource()
    node = UsdShade.Shader(src.GetPrim())
    assert output == "rgb"
    path = Path(node.GetInput("file").Get().resolvedPath)
    assert path.suffix == ".dds" and path.resolve().is_relative_to(out.resolve())
    desc = mf.read(path.parent)
    tex = next(c for c in desc.classic if c.file == path.name)
    assert tex.format == "BC5_UNORM" and tex.channels == 2  # BC@R's normal bytes
    x, y, z = (next(o for o in desc.outputs if o.name == f"normal.{c}") for c in "xyz")
    m = x.texel_scale / 2.0
    assert x.encoding == y.encoding == z.encoding == "slope" and z.texel_channel is None
    assert (x.texel_bias, y.texel_scale, y.texel_bias) == (-m, 2 * m, -m) and m >= 1 / 64
    big = max(m, 1.0)
    scale, bias = tuple(node.GetInput("scale").Get())[:3], tuple(node.GetInput("bias").Get())[:3]
    assert np.allclose(scale, (2 * m / big, 2 * m / big, 0.0)) and np.allclose(bias, (-m / big, -m / big, 1 / big))
    lo, hi = np.minimum(bias, np.add(scale, bias)), np.maximum(bias, np.add(scale, bias))
    assert lo.min() >= -1.0 - 1e-6 and hi.max() <= 1.0 + 1e-6  # UsdPreviewSurface's normal range, every texel


def test_what_usd_shades_with_is_within_a_small_angle_of_the_source(built) -> None:
    import OpenImageIO as oiio

    out, truth = built
    man = mfst.read(out)
    stage = Usd.Stage.Open(str(out / man.root_layer))
    src, _, _ = UsdShade.Shader(stage.GetPrimAtPath(f"{LOOKS}/Surface")).GetInput("normal").GetConnectedSource()
    node = UsdShade.Shader(src.GetPrim())
    texels = np.asarray(oiio.ImageBuf(node.GetInput("file").Get().resolvedPath).get_pixels(oiio.FLOAT), np.float32)
    assert texels.shape[:2] == truth.shape[:2]  # --profile auto: R is the source's side
    seen = usd_normal(texels, tuple(node.GetInput("scale").Get())[:3], tuple(node.GetInput("bias").Get())[:3])
    mean, p99 = angular_stats(truth, seen)
    flat_mean, flat_p99 = angular_stats(truth, unit(np.concatenate([seen[..., :2], np.ones_like(seen[..., :1])], -1)))
    assert mean < BOUND[0] and p99 < BOUND[1], (mean, p99)
    assert flat_p99 > 4 * p99, (flat_p99, p99)  # z = 1, as before, is far off on these 50-degree bumps
    m = next(m for m in man.built() if m.path == LOOKS)
    assert m.layout is not None and m.layout.normal_angle_deg is not None
    reported = json.loads((out / m.outputs.folder / "layout.json").read_text())["normal_angular_error"]
    assert reported["read_as"].startswith("USD: BC5 slopes") and reported["p99_deg"] < BOUND[1], reported


def test_the_slopes_beat_bc7_xyz_in_the_same_bytes(built) -> None:
    """BC7 of x, y and the rebuilt z (the layout's normal before the slopes), read with scale 2 and
    bias -1, is further from the source than what ships, in the same 16 bytes a block."""
    from bcfpipe.texset.baselines import bc7_mips
    from bcfpipe.texset.normals import stored_xyz

    out, truth = built
    man = mfst.read(out)
    stage = Usd.Stage.Open(str(out / man.root_layer))
    src, _, _ = UsdShade.Shader(stage.GetPrimAtPath(f"{LOOKS}/Surface")).GetInput("normal").GetConnectedSource()
    node = UsdShade.Shader(src.GetPrim())
    import OpenImageIO as oiio

    texels = np.asarray(oiio.ImageBuf(node.GetInput("file").Get().resolvedPath).get_pixels(oiio.FLOAT), np.float32)
    shipped = angular_stats(truth, usd_normal(texels, tuple(node.GetInput("scale").Get())[:3],
                                              tuple(node.GetInput("bias").Get())[:3]))
    xy = truth[..., :2] / np.maximum(np.linalg.norm(truth, axis=-1, keepdims=True), 1e-6)
    (bc7,), size = bc7_mips([np.concatenate([stored_xyz(xy), np.ones_like(xy[..., :1])], -1)])
    assert size == N * N  # 16 bytes per 4x4 block, as BC5's
    xyz = angular_stats(truth, usd_normal(bc7))
    assert shipped[0] < xyz[0] and shipped[1] < xyz[1], (shipped, xyz)
