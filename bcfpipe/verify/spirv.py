"""glsl/bcf_decode.comp (with the library, `verify.glsl.assemble`) compiled by glslang to Vulkan
SPIR-V, and that SPIR-V translated by SPIRV-Cross: HLSL (shader model 6.0, D3D12) and MSL
(Metal 2.0). One source, so every engine runs the function the GLSL decoder runs. The HLSL is
compiled again through glslang's HLSL front end (`hlsl_spirv`), and that SPIR-V is the one shipped
and the one `bcfpipe verify --runtime vulkan` runs: the HLSL itself is what is verified. MSL cannot
run on this machine; it is SPIRV-Cross's output of the same SPIR-V. The library's functions alone,
translated the same way from glsl/bcf_include.comp, are the HLSL include (`include`).

`decoder_files` is the whole set, which the package ships in bcfpipe/decoders/ (`bcfpipe shaders`
writes it anew; tests/test_shader_targets.py checks the shipped bytes against it).

The resource layout (set 0; glsl/bcf_decode.comp's header): binding 0 the weight words, 1 the
queries, 2 the output, 3 the parameters, 4 the N feature textures as combined image samplers.
In HLSL binding k is register tk / uk / sk (the textures t4.., their samplers s4..); in Metal,
buffer(k), texture(4..) and sampler(4..). The HLSL's SPIR-V (`hlsl_spirv`) has separate images at
binding 4.. and samplers at `HLSL_SAMPLER_BINDING`.. (glslang's --shift-sampler-binding).
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from bcfpipe import resources
from bcfpipe.errors import Unavailable
from bcfpipe.formats.vocabulary import StrEnum
from bcfpipe.verify.glsl import assemble

LAYER_COUNTS = (4, 5, 6)  # BCF_N_LAYERS: a T_0 of one to three layers
TARGET_ENV = "vulkan1.1"
HLSL_SHADER_MODEL = "60"
HLSL_SAMPLER_BINDING = 12  # the HLSL's samplers s4.. in its SPIR-V: 8 past the images' bindings
MSL_VERSION = "20000"  # Metal 2.0: arrays of textures as kernel arguments
TOOLS = {"glslangValidator": "glslang-tools", "spirv-cross": "spirv-cross"}
INCLUDE_SOURCE = "bcf_include.comp"
INCLUDE_NAME = "bcf_decode.hlsli"
VERSIONS_NAME = "versions.json"
# what SPIRV-Cross emits for bcf_include.comp besides the library's functions
_ENTRY_ITEMS = re.compile(r"(static const uint3 gl_WorkGroupSize|.*: register\(|uint bcfWeightWord\(|"
                          r"void comp_main\(|\[numthreads|void main\()")


class Target(StrEnum):
    """What `bcfpipe shaders` writes, by file suffix."""

    SPIRV = "spv"
    HLSL = "hlsl"
    MSL = "metal"


@dataclass(frozen=True)
class Shaders:
    """The batch decoder for materials of ``layers`` feature layers, in each target."""

    layers: int
    spirv: bytes  # glslang's, from the GLSL: what SPIRV-Cross translates
    hlsl: str
    msl: str
    hlsl_spirv: bytes  # the HLSL compiled back by glslang's HLSL front end: what ships and runs

    def text(self, target: Target) -> bytes:
        return {Target.SPIRV: self.hlsl_spirv, Target.HLSL: self.hlsl.encode(), Target.MSL: self.msl.encode()}[target]


def tool(name: str) -> str:
    """The path of ``name``, or `Unavailable` naming the Debian package that has it."""
    path = shutil.which(name)
    if path is None:
        raise Unavailable(f"{name} not found: install it (apt-get install {TOOLS[name]})")
    return path


def _run(args: list[str], what: str) -> str:
    p = subprocess.run(args, capture_output=True, text=True)
    if p.returncode != 0:
        detail = (p.stdout + p.stderr).strip().splitlines()
        raise RuntimeError(f"{what} failed: " + " | ".join(detail[-6:]))
    return p.stdout + p.stderr


def versions() -> dict[str, str]:
    """The compilers' own version lines, and their Debian package versions where dpkg knows them:
    the shipped files are these tools' output."""
    out = {"glslangValidator": _run([tool("glslangValidator"), "--version"], "glslang").splitlines()[0].strip(),
           "spirv-cross": _run([tool("spirv-cross"), "--revision"], "SPIRV-Cross").strip()}
    if shutil.which("dpkg-query"):
        for name, package in TOOLS.items():
            p = subprocess.run(["dpkg-query", "-W", "-f", "${Version}", package], capture_output=True, text=True)
            if p.returncode == 0 and p.stdout.strip():
                out[name] += f" (Debian {package} {p.stdout.strip()})"
    return out


def spirv(defines: dict[str, object] | None = None, stage: str = "comp") -> bytes:
    """bcf_decode.comp (or the glsl/ file ``stage``) with ``defines`` (BCF_N_LAYERS, a fixed
    BCF_N_HIDDEN / BCF_N_OUT, ...) as Vulkan SPIR-V (glslang defines VULKAN, which selects the
    set 0 layout)."""
    with tempfile.TemporaryDirectory(prefix="bcfpipe-spirv-") as d:
        src, out = Path(d) / "bcf_decode.comp", Path(d) / "bcf_decode.spv"
        src.write_text(assemble(stage, defines))
        _run([tool("glslangValidator"), "-V", "--target-env", TARGET_ENV, "-S", "comp", "-o", str(out), str(src)],
             "glslang (GLSL to SPIR-V)")
        return out.read_bytes()


def _cross(code: bytes, *flags: str) -> str:
    with tempfile.TemporaryDirectory(prefix="bcfpipe-cross-") as d:
        src, out = Path(d) / "in.spv", Path(d) / "out.txt"
        src.write_bytes(code)
        _run([tool("spirv-cross"), str(src), *flags, "--output", str(out)], "SPIRV-Cross")
        return out.read_text()


def hlsl(code: bytes) -> str:
    """``code`` (SPIR-V) as HLSL, shader model 6.0; entry point ``main``."""
    return _cross(code, "--hlsl", "--shader-model", HLSL_SHADER_MODEL)


def msl(code: bytes) -> str:
    """``code`` (SPIR-V) as Metal Shading Language 2.0; kernel ``main0``."""
    return _cross(code, "--msl", "--msl-version", MSL_VERSION, "--msl-decoration-binding")


def hlsl_spirv(text: str, defines: dict[str, object] | None = None, include_dirs: tuple[Path, ...] = (),
               stage: str = "comp") -> bytes:
    """``text`` compiled by glslang's HLSL front end (entry ``main`` of ``stage``; samplers shifted
    to `HLSL_SAMPLER_BINDING`; ``#include`` found in ``include_dirs``): its Vulkan SPIR-V, or
    RuntimeError with the compiler's messages."""
    with tempfile.TemporaryDirectory(prefix="bcfpipe-hlsl-") as d:
        src, out = Path(d) / "bcf_decode.comp.hlsl", Path(d) / "out.spv"
        src.write_text(text)
        shift = str(HLSL_SAMPLER_BINDING - 4)
        flags = [f"-D{k}={v}" for k, v in (defines or {}).items()] + [f"-I{p}" for p in include_dirs]
        _run([tool("glslangValidator"), "-D", "-e", "main", "-S", stage, "-V", "--target-env", TARGET_ENV,
              "--shift-sampler-binding", shift, *flags, "-o", str(out), str(src)], "glslang's HLSL front end")
        return out.read_bytes()


def _layer_defines(layers: int) -> dict[str, object]:
    if layers not in LAYER_COUNTS:
        raise ValueError(f"layers must be one of {LAYER_COUNTS}, got {layers}")
    return {"BCF_N_LAYERS": layers} if layers != 4 else {}


def shaders(layers: int, defines: dict[str, object] | None = None) -> Shaders:
    """The decoder for ``layers`` feature layers in every target."""
    code = spirv({**_layer_defines(layers), **(defines or {})})
    text = hlsl(code)
    return Shaders(layers, code, text, msl(code), hlsl_spirv(text))


def _top_level_items(text: str) -> list[str]:
    """``text`` (SPIRV-Cross's HLSL) cut into its top-level declarations and definitions."""
    items, current, depth = [], [], 0
    for line in text.splitlines():
        if not current and not line.strip():
            continue
        current.append(line)
        depth += line.count("{") - line.count("}")
        if depth == 0 and not line.lstrip().startswith("[") and line.rstrip().endswith(("}", ";")):
            items.append("\n".join(current))
            current = []
    if current:
        items.append("\n".join(current))
    return items


def include_functions(layers: int) -> str:
    """bcf_decode.glsl's functions for ``layers`` layers as HLSL: SPIRV-Cross's translation of
    glsl/bcf_include.comp without its entry point, resources and ``bcfWeightWord``."""
    _layer_defines(layers)  # a layer count it knows
    text = hlsl(spirv({"BCF_N_LAYERS": layers}, INCLUDE_SOURCE))
    kept = [item for item in _top_level_items(text) if not _ENTRY_ITEMS.match(item)]
    if not any(item.startswith("int bcfDecodeGrad(") for item in kept):
        raise RuntimeError("SPIRV-Cross's HLSL of bcf_include.comp has no bcfDecodeGrad")
    return "\n\n".join(kept)


INCLUDE_HEADER = """\
// bcf_decode.hlsli - bcfpipe's runtime decoder as HLSL functions (shader model 6), for a material
// function or any shader stage. Generated by `bcfpipe shaders` from glsl/bcf_decode.glsl through
// glslang and SPIRV-Cross (glsl/bcf_include.comp): do not edit. docs/format.md describes the decode.
//
// Before including it:
//   #define BCF_N_LAYERS 4, 5 or 6   (material.json's len(layers); default 4)
//   uint bcfWeightWord(uint wordIndex) { ... }   // 32-bit word wordIndex of the weight buffer
// Then, with the N feature textures (BC7 as UNORM, BC6H as UF16/SF16) and their samplers (trilinear,
// the material's addressing per axis) in arrays, and a BcfMaterial filled from material.json:
//   float ch[16];
//   int n = bcfDecodeLod(T, S, m, uv, s, ch);            // lod s in reference mip units
//   int n = bcfDecodeGrad(T, S, m, uv, ddx(uv), ddy(uv), ch);
// n is the channel count (material.json's outputs in order, a normal's z after its y), 0 for a
// record this decoder refuses. bcfDecodeFeatures(m, t, ch) runs the MLP on features an engine has
// sampled itself: t[i] = T_i.SampleLevel(S_i, bcfReduceUv(uv, m.wrap), clamp(s + m.lodBias[i], 0, 32)).
"""


DECODERS_README = """\
# bcfpipe's runtime decoder for D3D, Vulkan and Metal engines

Generated by `bcfpipe shaders -o DIR` (`make decoders` in the repository) from the one GLSL source,
`bcfpipe/glsl/bcf_decode.glsl`, through glslang and SPIRV-Cross (`versions.json`): do not edit.
docs/format.md is the format and the decode; its "Other APIs" section is this folder's manual.

| file | what |
|---|---|
| `bcf_decode.hlsli` | the decoder's functions as an HLSL include (shader model 6), for a material function or any stage; `#define BCF_N_LAYERS` and define `uint bcfWeightWord(uint)` first |
| `bcf_decode_N.hlsl` | the batch decoder for materials of N = 4, 5, 6 feature layers, an HLSL compute shader (entry `main`) |
| `bcf_decode_N.spv` | that HLSL compiled by glslang's HLSL front end: Vulkan 1.1 SPIR-V (images at binding 4..., samplers at 12...) |
| `bcf_decode_N.metal` | the batch decoder as Metal 2.0 (kernel `main0`) |

Verified: `bcfpipe verify --runtime vulkan` runs `bcf_decode_N.spv` on Vulkan and holds it to the
material's decoder.onnx; the tests run the include inside an engine-style kernel and glslang's
SPIR-V of the GLSL the same way. The Metal source is not run anywhere by bcfpipe (no Metal on
Linux): it is SPIRV-Cross's output of that same GLSL SPIR-V, from which the HLSL comes too.
"""


def include(layer_counts: tuple[int, ...] = LAYER_COUNTS) -> str:
    """bcf_decode.hlsli: `include_functions` for each layer count, chosen by BCF_N_LAYERS."""
    parts = [INCLUDE_HEADER, "#ifndef BCF_DECODE_HLSLI\n#define BCF_DECODE_HLSLI\n",
             "#ifndef BCF_N_LAYERS\n#define BCF_N_LAYERS 4\n#endif\n"]
    for i, n in enumerate(layer_counts):
        parts.append(f"{'#if' if i == 0 else '#elif'} BCF_N_LAYERS == {n}\n\n{include_functions(n)}\n")
    parts.append(f'#else\n#error "BCF_N_LAYERS must be one of {", ".join(map(str, layer_counts))}"\n'
                 "#endif\n\n#endif  // BCF_DECODE_HLSLI\n")
    return "\n".join(parts)


def decoder_files(layer_counts: tuple[int, ...] = LAYER_COUNTS) -> dict[str, bytes]:
    """Every file of the shipped decoder set, by name: bcf_decode_N.spv / .hlsl / .metal per
    layer count, bcf_decode.hlsli, README.md and versions.json (the tools that made them)."""
    files: dict[str, bytes] = {}
    for n in layer_counts:
        sh = shaders(n)
        for target in Target:
            files[f"bcf_decode_{n}.{target.value}"] = sh.text(target)
    files[INCLUDE_NAME] = include(layer_counts).encode()
    files["README.md"] = DECODERS_README.encode()
    files[VERSIONS_NAME] = (json.dumps(versions(), indent=2, sort_keys=True) + "\n").encode()
    return files


def shipped_dir() -> Path:
    """The package's decoders/ folder (``BCFPIPE_DECODERS`` overrides it)."""
    return resources.data_dir(resources.DECODER_DIR, "BCFPIPE_DECODERS", INCLUDE_NAME)


def shipped_kernel(layers: int) -> bytes:
    """The shipped SPIR-V of the batch decoder for ``layers`` layers: the HLSL's, as it runs."""
    _layer_defines(layers)
    return (shipped_dir() / f"bcf_decode_{layers}.{Target.SPIRV.value}").read_bytes()
