"""The decoder for every engine (issue 60): glsl/bcf_decode.comp, the one source, as Vulkan SPIR-V
(glslang; valid by spirv-val), HLSL (SPIRV-Cross, compiled again by glslang's HLSL front end) and
MSL (SPIRV-Cross, from the same SPIR-V), for 4, 5 and 6 feature layers and for one fixed network
shape; the HLSL include of the library's functions; `bcfpipe shaders`, which writes them; the
copies the package ships in bcfpipe/decoders/, which must be the tools' output of today's source;
and the Sdr node that names them. Real tools, no mocks; skips without them."""
from __future__ import annotations

import json
import re
import shutil
import subprocess

from pathlib import Path

import pytest

from cli_run import run_cli

REPO = Path(__file__).resolve().parents[1]
EXAMPLE_KERNEL = REPO / "examples" / "hlsl" / "bcf_include_kernel.hlsl"

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
    assert sh.hlsl_spirv == S.hlsl_spirv(sh.hlsl)  # what ships is the HLSL compiled, every time alike
    spirv_val(sh.hlsl_spirv, tmp_path)  # the HLSL compiles, and to valid SPIR-V
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
        [f"bcf_decode_{n}.{s}" for n in (4, 6) for s in ("spv", "hlsl", "metal")]
        + ["bcf_decode.hlsli", "README.md", "versions.json"])
    include = (tmp_path / "out" / "bcf_decode.hlsli").read_text()
    assert "#if BCF_N_LAYERS == 4" in include and "#elif BCF_N_LAYERS == 6" in include
    assert "BCF_N_LAYERS == 5" not in include
    assert (tmp_path / "out" / "bcf_decode_6.metal").read_text().count("texture2d<float>, 6>") >= 1
    bad = run_cli("shaders", "-o", tmp_path / "out", "--layers", "3")
    assert bad.returncode == 2 and "no layer count" in bad.stderr and "Traceback" not in bad.stderr


def test_the_shipped_decoders_are_the_tools_output_of_todays_source(tmp_path):
    """bcfpipe/decoders/ is what `bcfpipe shaders` makes now, byte for byte: a change to glsl/
    without `make decoders` fails here. Other tool versions emit other bytes; then it says so."""
    from bcfpipe.verify import spirv as S

    shipped = S.shipped_dir()
    recorded = json.loads((shipped / S.VERSIONS_NAME).read_text())
    if recorded != S.versions():
        pytest.skip(f"the shipped decoders come from {recorded}, this machine has {S.versions()}")
    files = S.decoder_files()
    assert sorted(files) == sorted(p.name for p in shipped.iterdir())
    stale = [name for name, data in files.items() if (shipped / name).read_bytes() != data]
    assert not stale, f"{stale} differ from `bcfpipe shaders`' output: run make decoders"


@pytest.mark.parametrize("layers", [4, 5, 6])
def test_the_include_compiles_in_an_engines_kernel(layers, tmp_path):
    """examples/hlsl/bcf_include_kernel.hlsl, a kernel of its own that includes the shipped
    bcf_decode.hlsli, compiles with glslang's HLSL front end to valid SPIR-V for each layer count;
    the include holds the library's functions only (no entry point, no resources)."""
    from bcfpipe.verify import spirv as S

    include = (S.shipped_dir() / S.INCLUDE_NAME).read_text()
    code_lines = "\n".join(x for x in include.splitlines() if not x.startswith("//"))
    assert "register(" not in code_lines and "numthreads" not in code_lines
    assert "bcfWeightWord(uint" not in code_lines  # the engine defines it
    assert include.count("int bcfDecodeLod(Texture2D<float4> T[") == 3
    code = S.hlsl_spirv(EXAMPLE_KERNEL.read_text(), {"BCF_N_LAYERS": layers}, (S.shipped_dir(),))
    spirv_val(code, tmp_path)


def test_the_docs_hlsl_snippet_compiles_in_a_pixel_shader(tmp_path):
    """docs/format.md's include snippet, as printed: its declarations at file scope, its call in a
    pixel shader's main (ddx / ddy), compiled by glslang's HLSL front end to valid SPIR-V."""
    from bcfpipe.verify import spirv as S

    blocks = re.findall(r"```hlsl\n(.*?)```", (REPO / "docs" / "format.md").read_text(encoding="utf-8"), re.S)
    assert len(blocks) == 1
    declarations, call = blocks[0].split("\n\n")
    shader = (f"{declarations}\nTexture2D<float4> T[BCF_N_LAYERS] : register(t4);\n"
              "SamplerState S[BCF_N_LAYERS] : register(s4);\n"
              "float4 main(float2 uv : TEXCOORD0) : SV_Target {\n    BcfMaterial m = (BcfMaterial)0;\n"
              f"{call}\n    return float4(ch[0], ch[1], ch[2], n);\n}}\n")
    spirv_val(S.hlsl_spirv(shader, include_dirs=(S.shipped_dir(),), stage="frag"), tmp_path)


def test_the_sdr_node_names_the_shipped_decoders():
    """BcfNeuralMaterial's HLSL implementation is the shipped include, and sdrMetadata bcfKernels
    names the shipped kernels, each of which exists."""
    import subprocess
    import sys

    script = (
        "import json\n"
        "from pxr import Sdr\n"
        "from bcfpipe.formats.usd_schema import register_shader_defs\n"
        "register_shader_defs()\n"
        "r = Sdr.Registry()\n"
        "n = r.GetShaderNodeByIdentifierAndType('BcfNeuralMaterial', 'hlsl')\n"
        "print(json.dumps({'valid': bool(n and n.IsValid()), 'impl': n.GetResolvedImplementationURI(),\n"
        "                  'kernels': n.GetMetadata()['bcfKernels'], 'def': n.GetResolvedDefinitionURI()}))\n")
    out = json.loads(subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True,
                                    cwd="/").stdout)
    from bcfpipe.verify import spirv as S

    assert out["valid"] and Path(out["impl"]) == S.shipped_dir() / S.INCLUDE_NAME
    kernels = out["kernels"].split()
    assert sorted(Path(k).name for k in kernels) == sorted(
        f"bcf_decode_{n}.{t.value}" for n in S.LAYER_COUNTS for t in S.Target)
    base = Path(out["def"]).parent
    assert all((base / k).resolve().is_file() for k in kernels)
