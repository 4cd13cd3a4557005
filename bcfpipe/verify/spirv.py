"""glsl/bcf_decode.comp (with the library, `verify.glsl.assemble`) compiled by glslang to Vulkan
SPIR-V, and that SPIR-V translated by SPIRV-Cross: HLSL (shader model 6.0, D3D12) and MSL
(Metal 2.0). One source, so every engine runs the function the GLSL decoder runs. The HLSL is
compiled again through glslang's HLSL front end (`hlsl_spirv`), and that SPIR-V is what
`bcfpipe verify --runtime vulkan` runs: the HLSL itself is what is verified. MSL cannot run on this
machine; it is SPIRV-Cross's output of the same SPIR-V.

The resource layout (set 0; glsl/bcf_decode.comp's header): binding 0 the weight words, 1 the
queries, 2 the output, 3 the parameters, 4 the N feature textures as combined image samplers.
In HLSL binding k is register tk / uk / sk (the textures t4.., their samplers s4..); in Metal,
buffer(k), texture(4..) and sampler(4..). The HLSL's SPIR-V (`hlsl_spirv`) has separate images at
binding 4.. and samplers at `HLSL_SAMPLER_BINDING`.. (glslang's --shift-sampler-binding).
"""
from __future__ import annotations

import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from bcfpipe.errors import Unavailable
from bcfpipe.formats.vocabulary import StrEnum
from bcfpipe.verify.glsl import assemble

LAYER_COUNTS = (4, 5, 6)  # BCF_N_LAYERS: a T_0 of one to three layers
TARGET_ENV = "vulkan1.1"
HLSL_SHADER_MODEL = "60"
HLSL_SAMPLER_BINDING = 12  # the HLSL's samplers s4.. in its SPIR-V: 8 past the images' bindings
MSL_VERSION = "20000"  # Metal 2.0: arrays of textures as kernel arguments
TOOLS = {"glslangValidator": "glslang-tools", "spirv-cross": "spirv-cross"}


class Target(StrEnum):
    """What `bcfpipe shaders` writes, by file suffix."""

    SPIRV = "spv"
    HLSL = "hlsl"
    MSL = "metal"


@dataclass(frozen=True)
class Shaders:
    """The batch decoder for materials of ``layers`` feature layers, in each target."""

    layers: int
    spirv: bytes
    hlsl: str
    msl: str

    def text(self, target: Target) -> bytes:
        return {Target.SPIRV: self.spirv, Target.HLSL: self.hlsl.encode(), Target.MSL: self.msl.encode()}[target]


def tool(name: str) -> str:
    """The path of ``name``, or `Unavailable` naming the Debian package that has it."""
    path = shutil.which(name)
    if path is None:
        raise Unavailable(f"{name} not found: install it (apt-get install {TOOLS[name]})")
    return path


def _run(args: list[str], what: str) -> None:
    p = subprocess.run(args, capture_output=True, text=True)
    if p.returncode != 0:
        detail = (p.stdout + p.stderr).strip().splitlines()
        raise RuntimeError(f"{what} failed: " + " | ".join(detail[-6:]))


def spirv(defines: dict[str, object] | None = None) -> bytes:
    """bcf_decode.comp with ``defines`` (BCF_N_LAYERS, a fixed BCF_N_HIDDEN / BCF_N_OUT, ...) as
    Vulkan SPIR-V (glslang defines VULKAN, which selects the set 0 layout)."""
    with tempfile.TemporaryDirectory(prefix="bcfpipe-spirv-") as d:
        src, out = Path(d) / "bcf_decode.comp", Path(d) / "bcf_decode.spv"
        src.write_text(assemble("comp", defines))
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


def hlsl_spirv(text: str) -> bytes:
    """``text`` compiled by glslang's HLSL front end (entry ``main``, compute; samplers shifted to
    `HLSL_SAMPLER_BINDING`): its Vulkan SPIR-V, or RuntimeError with the compiler's messages."""
    with tempfile.TemporaryDirectory(prefix="bcfpipe-hlsl-") as d:
        src, out = Path(d) / "bcf_decode.comp.hlsl", Path(d) / "out.spv"
        src.write_text(text)
        shift = str(HLSL_SAMPLER_BINDING - 4)
        _run([tool("glslangValidator"), "-D", "-e", "main", "-S", "comp", "-V", "--target-env", TARGET_ENV,
              "--shift-sampler-binding", shift, "-o", str(out), str(src)], "glslang's HLSL front end")
        return out.read_bytes()


def shaders(layers: int, defines: dict[str, object] | None = None) -> Shaders:
    """The decoder for ``layers`` feature layers in every target."""
    if layers not in LAYER_COUNTS:
        raise ValueError(f"layers must be one of {LAYER_COUNTS}, got {layers}")
    code = spirv({**({"BCF_N_LAYERS": layers} if layers != 4 else {}), **(defines or {})})
    return Shaders(layers, code, hlsl(code), msl(code))
