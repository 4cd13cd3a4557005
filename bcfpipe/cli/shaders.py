"""`bcfpipe shaders`: the runtime decoder for engines that do not take GLSL (issue 60)."""
from __future__ import annotations

import json
from pathlib import Path

import click

from bcfpipe.cli.errors import Command
from bcfpipe.errors import InputError
from bcfpipe.formats.atomic import atomic_write
from bcfpipe.verify import spirv as S


@click.command("shaders", cls=Command)
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Folder for the shaders (made if missing).")
@click.option("--layers", "layer_counts", default="4,5,6", show_default=True, metavar="N[,N...]",
              help="Feature layer counts to compile for (material.json's len(layers): 4, 5 or 6).")
@click.option("--check/--no-check", default=True, show_default=True,
              help="Compile the HLSL again through glslang's HLSL front end.")
@click.option("--json", "as_json", is_flag=True, help="Print the files written as JSON.")
def shaders(out_dir: str, layer_counts: str, check: bool, as_json: bool) -> None:
    """Write the batch decoder (glsl/bcf_decode.comp, the one source) as Vulkan SPIR-V, HLSL and
    Metal for materials of each layer count: bcf_decode_N.spv, .hlsl and .metal.

    glslang compiles the GLSL to SPIR-V; SPIRV-Cross translates that SPIR-V to HLSL (shader model
    6.0, entry main) and MSL (Metal 2.0, kernel main0). Resources: set 0, binding 0 the weight
    words, 1 the queries, 2 the output, 3 the parameters, 4 the N feature textures (combined image
    samplers); HLSL registers and Metal indices keep those numbers (glsl/bcf_decode.comp's header). Exit codes: 0 ok, 2 glslang or
    SPIRV-Cross missing (apt-get install glslang-tools spirv-cross), 1 a compile failed.
    """
    try:
        counts = [int(x) for x in layer_counts.split(",")]
    except ValueError:
        raise InputError(f"--layers {layer_counts!r}: give layer counts such as 4,5,6") from None
    if bad := [n for n in counts if n not in S.LAYER_COUNTS]:
        raise InputError(f"--layers: {bad[0]} is no layer count (one of {', '.join(map(str, S.LAYER_COUNTS))})")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for n in counts:
        sh = S.shaders(n)
        if check:
            S.hlsl_spirv(sh.hlsl)
        for target in S.Target:
            path = out / f"bcf_decode_{n}.{target.value}"
            atomic_write(path, sh.text(target))
            written.append(str(path))
    if as_json:
        click.echo(json.dumps({"files": written, "hlsl_checked": check}, indent=2))
    else:
        for p in written:
            click.echo(p)
