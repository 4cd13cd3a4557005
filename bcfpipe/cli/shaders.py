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
@click.option("--json", "as_json", is_flag=True, help="Print the files written as JSON.")
def shaders(out_dir: str, layer_counts: str, as_json: bool) -> None:
    """Write the runtime decoder for D3D, Vulkan and Metal engines from its one GLSL source: the set
    the package ships in bcfpipe/decoders/ (docs/format.md, "Other APIs").

    \b
    bcf_decode_N.hlsl   the batch decoder (glsl/bcf_decode.comp) as HLSL, shader model 6.0
    bcf_decode_N.spv    that HLSL compiled by glslang's HLSL front end: Vulkan SPIR-V
    bcf_decode_N.metal  the GLSL's SPIR-V, which the HLSL comes from, as Metal 2.0 (kernel main0)
    bcf_decode.hlsli    the decoder's functions as an HLSL include, for a material function
    README.md           what each file is
    versions.json       the glslang and SPIRV-Cross that made them

    glslang compiles the GLSL to SPIR-V; SPIRV-Cross translates that SPIR-V to HLSL and MSL.
    Resources: set 0, binding 0 the weight words, 1 the queries, 2 the output, 3 the parameters,
    4 the N feature textures; HLSL registers t0, t1, u2, t3, t4.. and s4.. (samplers at binding
    12.. in the .spv). The same tools give the same bytes. Exit codes: 0 ok, 2 glslang or
    SPIRV-Cross missing (apt-get install glslang-tools spirv-cross), 1 a compile failed.
    """
    try:
        counts = tuple(int(x) for x in layer_counts.split(","))
    except ValueError:
        raise InputError(f"--layers {layer_counts!r}: give layer counts such as 4,5,6") from None
    if bad := [n for n in counts if n not in S.LAYER_COUNTS]:
        raise InputError(f"--layers: {bad[0]} is no layer count (one of {', '.join(map(str, S.LAYER_COUNTS))})")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, data in S.decoder_files(counts).items():
        atomic_write(out / name, data)
        written.append(str(out / name))
    if as_json:
        click.echo(json.dumps({"files": written, "versions": S.versions()}, indent=2))
    else:
        for p in written:
            click.echo(p)
