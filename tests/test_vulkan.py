"""`bcfpipe verify --runtime vulkan` (issue 60): the decoder's SPIR-V (`bcfpipe shaders`' source)
run on a real Vulkan device (Mesa's lavapipe on a CPU machine) against decoder.onnx at verify's
points, beside OpenGL. Trained materials with a T_0 of 2 layers (5 BC7 layers) and 4 BC6H layers
(tests/test_format_spec.py's, 64², tiny / smoke); the sample scene's neural build in
tests/test_render.py. Skips where no Vulkan device with BC textures can be had."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pathlib import Path

from cli_run import run_cli

REPO = Path(__file__).resolve().parents[1]
from test_format_spec import materials  # noqa: F401 - the trained materials, a module fixture


@pytest.fixture(scope="module")
def vk():
    pytest.importorskip("vulkan", reason="needs the vulkan package (pip install vulkan)")
    from bcfpipe.verify.vulkan import VulkanRuntime, VulkanUnavailable

    try:
        rt = VulkanRuntime()
    except VulkanUnavailable as e:
        pytest.skip(f"no Vulkan here: {e} (apt-get install libvulkan1 mesa-vulkan-drivers)")
    yield rt
    rt.release()


@pytest.mark.vulkan
@pytest.mark.parametrize("name", ["bc7-5", "bc6h-4"])
def test_verify_runtime_vulkan_passes_with_its_figure_beside_opengls(vk, materials, name):  # noqa: F811
    r = run_cli("verify", materials[name], "--runtime", "vulkan", "--json")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    rep = json.loads(r.stdout)
    assert rep["vulkan"]["version"].startswith("Vulkan 1.")
    checks = {c["name"]: c for c in rep["materials"][0]["checks"]}
    assert checks["vulkan"]["passed"] and checks["glsl"]["passed"]
    figure = float(checks["vulkan"]["detail"].split("max |Vulkan - ONNX| ")[1].split()[0])
    assert figure < 1e-3  # fp32 arithmetic and the texture unit's filter: the runtimes agree closely
    text = run_cli("verify", materials[name], "--runtime", "vulkan")
    assert "Vulkan: " in text.stdout and "max |Vulkan - ONNX|" in text.stdout and "max |GLSL - ONNX|" in text.stdout


@pytest.mark.vulkan
def test_vulkan_decode_equals_opengls_and_rejects_a_bad_record(vk, materials, rt):  # noqa: F811
    """At points far outside [0, 1] on the clamp / mirror material: Vulkan's decode is OpenGL's,
    to fp32 rounding; a record of another shape decodes to NaN, which verify fails."""
    from bcfpipe.verify import glsl as G

    m = G.read_material(materials["bc7-5"])
    rng = np.random.default_rng(3)
    uv = rng.uniform(-3, 4, (3000, 2)).astype(np.float32)
    s = rng.uniform(-2, 9, 3000).astype(np.float32)
    vm, gm = vk.load(m), rt.load(m)
    try:
        np.testing.assert_allclose(vk.decode(vm, uv, s), rt.decode(gm, uv, s), rtol=0, atol=2e-5)
        dx, dy = (rng.normal(0, 1, (2, 3000, 2)) * 0.01).astype(np.float32)
        np.testing.assert_allclose(vk.decode_grad(vm, uv, dx, dy), rt.decode_grad(gm, uv, dx, dy), rtol=0, atol=2e-5)
    finally:
        vk.unload(vm)
        rt.unload(gm)
    bad = bytearray(m.weights_file.read_bytes())
    bad[8:12] = (99).to_bytes(4, "little")  # n_in of no layer count
    vm = vk.load(m, weights=bytes(bad))
    try:
        assert np.isnan(vk.decode(vm, uv[:100], s[:100])).all()
    finally:
        vk.unload(vm)


def _include_kernel(layers: int) -> bytes:
    from bcfpipe.verify import spirv as S

    kernel = (REPO / "examples" / "hlsl" / "bcf_include_kernel.hlsl").read_text()
    return S.hlsl_spirv(kernel, {"BCF_N_LAYERS": layers}, (S.shipped_dir(),))


def _glsl_kernel(layers: int) -> bytes:
    from bcfpipe.verify import spirv as S

    return S.shaders(layers).spirv


@pytest.mark.vulkan
@pytest.mark.parametrize("kernel", ["hlsl-include", "glsl-spirv"])
def test_other_kernels_decode_as_the_shipped_one_and_pass_verify(vk, materials, kernel):  # noqa: F811
    """Two more kernels run on Vulkan: examples/hlsl/bcf_include_kernel.hlsl (its own main, the
    shipped bcf_decode.hlsli included) through glslang's HLSL front end, and glslang's SPIR-V of
    the GLSL, the one the shipped HLSL and Metal are SPIRV-Cross's translations of (combined image
    samplers). On materials of 4, 5 and 6 BC7 layers and 4 BC6H ones each decodes as the shipped
    kernel does, and verify's check holds it to decoder.onnx within its tolerance."""
    from bcfpipe.verify import checks, glsl as G
    from bcfpipe.verify.vulkan import VulkanRuntime

    other = VulkanRuntime(*((_include_kernel, False) if kernel == "hlsl-include" else (_glsl_kernel, True)))
    rng = np.random.default_rng(5)
    uv = rng.uniform(-2.5, 3.5, (2000, 2)).astype(np.float32)
    s = rng.uniform(-2, 8, 2000).astype(np.float32)
    dx, dy = (rng.normal(0, 1, (2, 2000, 2)) * 0.02).astype(np.float32)
    try:
        for name in ("bc7-4", "bc7-5", "bc7-6", "bc6h-4"):
            m = G.read_material(materials[name])
            a, b = other.load(m), vk.load(m)
            try:
                np.testing.assert_allclose(other.decode(a, uv, s), vk.decode(b, uv, s), rtol=0, atol=2e-6,
                                           err_msg=name)
                np.testing.assert_allclose(other.decode_grad(a, uv, dx, dy), vk.decode_grad(b, uv, dx, dy),
                                           rtol=0, atol=2e-6, err_msg=name)
                np.testing.assert_allclose(other.decode_grid(a, 24, 16, 1.5), vk.decode_grid(b, 24, 16, 1.5),
                                           rtol=0, atol=2e-6, err_msg=name)
            finally:
                other.unload(a)
                vk.unload(b)
            rep = checks.verify_target(checks.find_targets(materials[name])[0], None, vulkan=other)
            assert {c.name: c.passed for c in rep.checks}["vulkan"], [c.detail for c in rep.checks]
    finally:
        other.release()


@pytest.mark.vulkan
def test_the_engine_example_writes_what_bcfpipe_decode_writes(vk, materials, tmp_path):  # noqa: F811
    """examples/vulkan_decode.py, which reads the folder as docs/format.md says and runs the shipped
    SPIR-V with no bcfpipe code, in tiles of queries: its 8-bit PNGs are `bcfpipe decode
    --backend onnx`'s within 1 step (4 for a normal map, whose z comes from x and y), on the
    clamp / mirror material of 5 layers at a lod between mips."""
    import subprocess
    import sys

    import OpenImageIO as oiio

    folder = materials["bc7-5"]
    ex, ours = tmp_path / "example", tmp_path / "decode"
    r = subprocess.run([sys.executable, str(REPO / "examples" / "vulkan_decode.py"), str(folder), "-o", str(ex),
                        "--lod", "1.37", "--size", "96", "--tile", "40"], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert run_cli("decode", folder, "--backend", "onnx", "-o", ours, "--lod", "1.37", "--size", "96x96").returncode == 0
    compared = []
    for png in sorted(ours.glob("*.png")):
        a = np.asarray(oiio.ImageBuf(str(ex / png.name)).get_pixels(oiio.UINT8)).astype(int)
        b = np.asarray(oiio.ImageBuf(str(png)).get_pixels(oiio.UINT8)).astype(int)
        assert a.shape == b.shape, png.name
        assert np.abs(a - b).max() <= (4 if png.stem == "normal" else 1), png.name
        compared.append(png.stem)
    assert compared == ["albedo", "normal", "roughness"]


def test_no_vulkan_is_one_line_and_exit_2(materials, monkeypatch):  # noqa: F811
    pytest.importorskip("vulkan", reason="needs the vulkan package (pip install vulkan)")
    monkeypatch.setenv("VK_ICD_FILENAMES", "/nonexistent/icd.json")
    monkeypatch.setenv("VK_DRIVER_FILES", "/nonexistent/icd.json")
    r = run_cli("verify", materials["bc7-4"], "--runtime", "vulkan")
    assert r.returncode == 2, r.stdout + r.stderr
    assert "no Vulkan" in r.stdout + r.stderr and "Traceback" not in r.stdout + r.stderr


@pytest.mark.vulkan
@pytest.mark.parametrize("name", ["bc7-6", "bc6h-4"])
def test_decode_backend_vulkan_gives_onnxs_grid(vk, materials, name):  # noqa: F811
    """`bcfpipe decode --backend vulkan`'s grid (the shader's grid mode) against --backend onnx's,
    every output, at a lod between mips: within the texture unit's filtering, as verify holds it."""
    from bcfpipe.cli.decode import decode_material, select_target

    target = select_target(str(materials[name]), None)
    ours, used = decode_material(target, (40, 24), 1.3, "vulkan")
    theirs, _ = decode_material(target, (40, 24), 1.3, "onnx")
    assert used == "vulkan" and ours.shape == theirs.shape == (24, 40, target.desc.c_out)
    assert np.abs(ours - theirs).max() < 2e-3


@pytest.mark.vulkan
@pytest.mark.parametrize("backend", ["vulkan", "onnx"])
def test_decode_refuses_a_bad_record_in_one_line(vk, materials, tmp_path, backend):  # noqa: F811
    """A weight record the runtimes would decode to NaN (Vulkan, OpenGL) or ONNX's reader raise on:
    `bcfpipe decode` says so in one line and exits 2, writing nothing."""
    import shutil

    folder = tmp_path / "bad"
    shutil.copytree(materials["bc7-4"], folder)
    record = bytearray((folder / "weights.bin").read_bytes())
    record[8:12] = (99).to_bytes(4, "little")  # n_in of no layer count
    (folder / "weights.bin").write_bytes(bytes(record))
    r = run_cli("decode", folder, "--backend", backend, "-o", tmp_path / "img")
    assert r.returncode == 2 and "weights.bin" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "img").exists()
