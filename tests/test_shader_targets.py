"""The decoder for every engine (issue 60): glsl/bcf_decode.comp, the one source, as Vulkan SPIR-V
(glslang; valid by spirv-val), HLSL (SPIRV-Cross, compiled again by glslang's HLSL front end) and
MSL (SPIRV-Cross, from the same SPIR-V), for 4, 5 and 6 feature layers and for one fixed network
shape; and `bcfpipe shaders`, which writes them. Real tools, no mocks; skips without them."""
from __future__ import annotations

import json
import re
import shutil
import subprocess

import pytest

from cli_run import run_cli

pytestmark = pytest.mark.skipif(not (shutil.which("glslangValidator") and shutil.which("spirv-cross")),
                                reason="needs glslang and SPIRV-Cross (apt-get install glslang-tools spirv-cross)")


def spirv_val(code: bytes, tmp_path) -> None:
    if shutil.which("spirv-val") is None:
        return
    p = tmp_path / "x.spv"
    p.write_bytes(code)
    r = subprocess.run(["spirv-val", "--target-env", "vulkan1.1", str(p)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


@pytest.mark.parametrize("layers", [4, 5, 6])
def test_one_source_gives_spirv_hlsl_and_msl(layers, tmp_path):
    from bcfpipe.verify import spirv as S

    sh = S.shaders(layers)
    assert sh.spirv[:4] == bytes.fromhex("03022307")  # SPIR-V magic, little-endian
    spirv_val(sh.spirv, tmp_path)
    spirv_val(S.hlsl_spirv(sh.hlsl), tmp_path)  # the HLSL compiles, and to valid SPIR-V
    # binding k keeps its number: buffers t0, t1, u2, t3, then the textures from t4 (no overlap)
    registers = dict(re.findall(r"(\w+(?:\[\d+\])?) : register\((\w+)(?:, space0)?\)", sh.hlsl))
    assert registers[f"bcfT[{layers}]"] == "t4" and registers[f"_bcfT_sampler[{layers}]"] == "s4", registers
    assert sorted(v for k, v in registers.items() if "bcfT" not in k) == ["t0", "t1", "t3", "u2"], registers
    assert "void main(" in sh.hlsl and "kernel void main0(" in sh.msl
    assert f"array<texture2d<float>, {layers}> bcfT [[texture(4)]]" in sh.msl
    assert all(f"[[buffer({k})]]" in sh.msl for k in range(4))
    # the parameters block keeps its std430 offsets: uLodBias right after the 48 fixed bytes
    assert re.search(r"float uLodBias\[" + str(layers) + r"\];", sh.msl)


def test_a_fixed_network_shape_compiles_for_every_target(tmp_path):
    from bcfpipe.verify import spirv as S

    sh = S.shaders(4, {"BCF_N_HIDDEN": 16, "BCF_N_OUT": 6, "BCF_MAX_OUT": 7})
    spirv_val(sh.spirv, tmp_path)
    spirv_val(S.hlsl_spirv(sh.hlsl), tmp_path)


def test_a_broken_hlsl_is_reported_with_the_compilers_words():
    from bcfpipe.verify import spirv as S

    with pytest.raises(RuntimeError, match="HLSL front end failed"):
        S.hlsl_spirv("[numthreads(64, 1, 1)] void main() { undefined_thing(); }")


def test_shaders_command_writes_every_target(tmp_path):
    r = run_cli("shaders", "-o", tmp_path / "out", "--layers", "4,6", "--json")
    assert r.returncode == 0, r.stderr
    files = json.loads(r.stdout)["files"]
    assert sorted(p.rsplit("/", 1)[1] for p in files) == sorted(
        f"bcf_decode_{n}.{s}" for n in (4, 6) for s in ("spv", "hlsl", "metal"))
    assert (tmp_path / "out" / "bcf_decode_6.metal").read_text().count("texture2d<float>, 6>") >= 1
    bad = run_cli("shaders", "-o", tmp_path / "out", "--layers", "3")
    assert bad.returncode == 2 and "no layer count" in bad.stderr and "Traceback" not in bad.stderr
