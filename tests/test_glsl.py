"""The GLSL runtime decoder (glsl/): offline compilation with glslangValidator (GL 4.50 and ES 3.2),
and behaviour through the OpenGL driver (moderngl on EGL; skipped without a context)."""
from __future__ import annotations

import dataclasses
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bcfpipe.verify import glsl as G

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_verify import make_material  # noqa: E402

GLSLANG = shutil.which("glslangValidator")
ES_HEADER = "320 es\nprecision highp float;\nprecision highp int;\nprecision highp sampler2D;"
# ES 3.2 fragment shaders may have no storage blocks (GL_MAX_FRAGMENT_SHADER_STORAGE_BLOCKS can be 0):
# the README's UBO accessor, substituted for the SSBO one
UBO_ACCESSOR = ("layout(std140, binding = 0) uniform BcfWeights { uvec4 bcfWeights[1024]; };\n"
                "uint bcfWeightWord(uint i) { return bcfWeights[i >> 2u][i & 3u]; }")


def validate_texels(source: str, stage: str, tmp_path: Path) -> None:
    if GLSLANG is None:
        pytest.skip("glslangValidator is not installed (Debian: glslang-tools)")
    path = tmp_path / f"shader.{stage}"
    path.write_text(source)
    r = subprocess.run([GLSLANG, str(path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, f"{stage}:\n{r.stdout}\n{r.stderr}"


@pytest.mark.parametrize("stage", ["vert", "frag", "comp"])
def test_shaders_compile_glsl450(stage, tmp_path):
    validate_texels(G.assemble(stage), stage, tmp_path)


@pytest.mark.parametrize("stage", ["frag", "comp"])
def test_shaders_compile_for_one_network_shape(stage, tmp_path):
    validate_texels(G.assemble(stage, {"BCF_N_HIDDEN": 16, "BCF_N_OUT": 6, "BCF_MAX_OUT": 7}), stage, tmp_path)


@pytest.mark.parametrize("stage", ["vert", "frag", "comp"])
def test_shaders_compile_es32(stage, tmp_path):
    validate_texels(G.assemble(stage, version=ES_HEADER), stage, tmp_path)


def test_es32_fragment_with_uniform_block_weights(tmp_path):
    src = G.assemble("frag", version=ES_HEADER)
    ssbo = re.search(r"layout\(std430, binding = 0\) readonly buffer BcfWeights .*\n.*\n", src)
    assert ssbo, "the example fragment shader's weight accessor changed; update the README and this test"
    validate_texels(src.replace(ssbo.group(0), UBO_ACCESSOR + "\n"), "frag", tmp_path)


def test_library_is_binding_and_extension_free():
    lib = G.read_source(G.LIBRARY)
    code = "\n".join(line.split("//")[0] for line in lib.splitlines())
    assert "#version" not in code and "#include" not in code and "#extension" not in code
    assert "binding" not in code and "uniform" not in code and "buffer" not in code
    for name in G.STAGES.values():
        assert "#extension" not in G.read_source(name)
        assert G.read_source(name).startswith("#version 450 core\n")


def test_readme_documents_bindings_and_uniforms():
    readme = (G.glsl_dir() / "README.md").read_text()
    for word in ("uWeightOffset", "uLodBias", "uRefSize", "uNormalIndex", "uCount", "uOutStride", "uGrid",
                 "uGridLod", "uLodMode", "uLod", "uView", "uUvTransform", "bcfWeightWord", "BCFW", "ES 3.2",
                 "unpackHalf2x16", "GL_TEXTURE_MAX_LEVEL"):
        assert word in readme, word


# ---------------------------------------------------------------------------------------- through GL

@pytest.fixture(scope="module")
def mat(tmp_path_factory):
    d = tmp_path_factory.mktemp("glmat")
    return make_material(d, normal=True, seed=7)


@pytest.fixture()
def loaded(rt, mat):
    gm = rt.load(G.read_material(mat))
    yield gm
    rt.unload(gm)



@pytest.mark.gl
def test_lod_clamping_matches_the_sampler_rules(rt, loaded):
    """s_i < 0 samples level 0 (magnification), s_i past the last mip samples the last mip."""
    m = loaded.desc
    rng = np.random.default_rng(0)
    uv = rng.uniform(-1, 2, (500, 2)).astype(np.float32)
    all_level0 = -max(m.lod_biases)  # every s_i <= 0
    all_last = max(n - 1 - b for n, b in zip(m.mip_counts, m.lod_biases))
    np.testing.assert_array_equal(rt.decode(loaded, uv, -100.0), rt.decode(loaded, uv, all_level0))
    np.testing.assert_array_equal(rt.decode(loaded, uv, 1e4), rt.decode(loaded, uv, all_last))
    assert np.abs(rt.decode(loaded, uv, all_last - 0.5) - rt.decode(loaded, uv, all_last)).max() > 0


@pytest.mark.gl
def test_fragment_shader_matches_compute(rt, loaded):
    ref_w, ref_h = loaded.desc.ref_size
    c = loaded.desc.c_out
    for w, lod, view in ((ref_w, None, 0), (ref_w // 2, None, 3), (ref_w // 4, 0.75, 4), (ref_w * 2, None, c - 3)):
        img = rt.render_fullscreen(loaded, w, w, lod, view)
        s = float(np.log2(ref_w / w)) if lod is None else lod  # derivative path: s = log2(footprint)
        grid = rt.decode_grid(loaded, w, w, s)
        expect = np.stack([grid[..., min(view + k, c - 1)] for k in range(3)], -1)
        assert np.abs(img[..., :3] - expect).max() < 1e-5, (w, lod, view)
        assert (img[..., 3] == 1).all()


@pytest.mark.gl
def test_weight_offset_in_a_shared_buffer(rt, mat):
    m = G.read_material(mat)
    rng = np.random.default_rng(1)
    uv = rng.uniform(0, 1, (300, 2)).astype(np.float32)
    s = rng.uniform(-2, 6, 300).astype(np.float32)
    gm = rt.load(m)
    base = rt.decode(gm, uv, s)
    rt.unload(gm)
    record = m.weights_file.read_bytes()
    m = dataclasses.replace(m, weight_offset=1008)  # any 4-byte aligned offset works
    gm = rt.load(m, weights=b"\x55" * 1008 + record + b"\x77" * 64)
    try:
        np.testing.assert_array_equal(rt.decode(gm, uv, s), base)
    finally:
        rt.unload(gm)


@pytest.mark.gl
def test_fixed_shape_build_and_invalid_records(rt, loaded):
    rng = np.random.default_rng(2)
    uv = rng.uniform(0, 1, (200, 2)).astype(np.float32)
    base = rt.decode(loaded, uv, 1.5)
    n_out = loaded.desc.n_out
    # the shape bcfpipe bench's decode cost compiles (`decode_cost._net`): one program for both tests
    fixed = rt.decode(loaded, uv, 1.5, defines={"BCF_N_HIDDEN": 16, "BCF_N_OUT": n_out,
                                                "BCF_MAX_OUT": loaded.desc.c_out})
    assert np.abs(fixed - base).max() < 1e-6
    # record has 16: rejected (a narrower shape than the record's, as a wider one: llvmpipe compiles
    # a fixed width of 8 in 3.5 s, one of 32 in 41 s)
    wrong = rt.decode(loaded, uv, 1.5, defines={"BCF_N_HIDDEN": 8})
    assert np.isnan(wrong).all()
    bad = bytearray(loaded.desc.weights_file.read_bytes())
    bad[0:4] = b"XXXX"
    gm = rt.load(loaded.desc, weights=bytes(bad))
    try:
        assert np.isnan(rt.decode(gm, uv, 0.0)).all()
        img = rt.render_fullscreen(gm, 8, 8, 0.0)
        assert (img[..., :3] == [1, 0, 1]).all()  # magenta
    finally:
        rt.unload(gm)


@pytest.mark.gl
def test_normal_z_is_reconstructed(rt, loaded):
    n = loaded.desc.normal_index
    rng = np.random.default_rng(3)
    y = rt.decode(loaded, rng.uniform(0, 1, (400, 2)).astype(np.float32), 0.0)
    x, yy, z = y[:, n], y[:, n + 1], y[:, n + 2]
    np.testing.assert_allclose(z, np.sqrt(np.maximum(0, 1 - x * x - yy * yy)), atol=1e-6)
    assert (np.abs(x) <= 1).all() and (np.abs(yy) <= 1).all()
    others = np.delete(y, [n, n + 1, n + 2], axis=1)
    assert (others >= 0).all() and (others <= 1).all()


@pytest.mark.gl
def test_decode_cost_times_both_stages(rt, mat):
    """The decode-cost protocol in the fragment and the compute stage: one row per material, the
    classic pass built from the material's own semantics, grids past one dispatch refused."""
    from bcfpipe.bench import decode_cost as D

    desc = G.read_material(mat)
    classic = D.random_classic(desc)
    names, fmts = D.upload_classic(rt, classic, desc.wrap)
    assert "BC5" in fmts  # the material's normal map
    try:
        for run, stage in ((D.measure, "fragment"), (D.measure_compute, "compute")):
            (c,) = run(rt, [desc], names, (48, 32), frames=2, warmup=1)
            assert (c.stage, c.width, c.height, c.frames) == (stage, 48, 32, 2)
            assert c.neural_ms > 0 and c.classic_ms > 0 and c.to_json()["stage"] == stage
        with pytest.raises(ValueError, match="exceeds one dispatch"):
            D.measure_compute(rt, [desc], names, (1 << 14, 1 << 14), frames=1, warmup=0)
    finally:
        rt.delete_textures(names)
