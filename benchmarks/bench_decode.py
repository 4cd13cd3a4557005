#!/usr/bin/env python3
"""Decoding cost of a neural material vs classic block-compressed textures (paper Table 4 setup).

Renders a full-screen pass at 1080p, 1440p and 2160p into an RGBA8 framebuffer and times each draw
with GL timer queries (GL_TIME_ELAPSED, moderngl ``ctx.query(time=True)``); reports the median over
N frames after warm-up.

* neural: glsl/bcf_fullscreen.vert + .frag decoding the material per pixel (lod from the uv
  derivatives, paper §5.2), compiled for the material's network shape (BCF_N_HIDDEN / BCF_N_OUT);
  four BC6H layers + the weight SSBO.
* classic: the same pass sampling the material's texture set as ordinary BC textures at the
  reference resolution with full mip chains, trilinear: one texture per semantic (colour -> BC1,
  normal x/y -> BC5, scalar -> BC4), as a renderer would ship them. BC1 is
  GL_EXT_texture_compression_s3tc (not core, but in every desktop driver and in Mesa); without it
  the colour textures fall back to BC7 (GL_ARB_texture_compression_bptc, core 4.2), which the
  report states. BC4/BC5 are RGTC, core since GL 3.0. Block contents are random: sampling cost
  does not depend on them.

The uv transform tiles the material so one reference texel covers about one pixel (s ~ 0).

On a software renderer (Mesa llvmpipe) absolute times mean nothing: the script uses a small size
and few frames, times draw + glFinish on the CPU clock (llvmpipe's timer queries miss its
rasterizer threads) and prints only the neural / classic ratio.

    python benchmarks/bench_decode.py OUT [--material PRIM] [--frames 200] [--json]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bcfpipe.verify import glsl as G  # noqa: E402

GL_COMPRESSED_RGB_S3TC_DXT1_EXT = 0x83F0
GL_COMPRESSED_RED_RGTC1 = 0x8DBB
GL_COMPRESSED_RG_RGTC2 = 0x8DBD
GL_COMPRESSED_RGBA_BPTC_UNORM = 0x8E8C
SIZES = {"1080p": (1920, 1080), "1440p": (2560, 1440), "2160p": (3840, 2160)}

def classic_frag(n: int) -> str:
    """Classic material pass: sample each of the n BC textures (trilinear, implicit derivatives) and
    write three of the channels, like bcf_fullscreen.frag does for the neural material."""
    decl = "\n".join(f"layout(binding = {k}) uniform sampler2D tex{k};" for k in range(n))
    fetch = "\n".join(f"    t = texture(tex{k}, vUv); ch[{4 * k}] = t.r; ch[{4 * k + 1}] = t.g; "
                       f"ch[{4 * k + 2}] = t.b; ch[{4 * k + 3}] = t.a;" for k in range(n))
    return f"""#version 450 core
layout(location = 0) in vec2 vUv;
layout(location = 0) out vec4 fragColor;
{decl}
uniform int uView;
void main() {{
    float ch[{4 * n}];
    vec4 t;
{fetch}
    int last = {4 * n - 1};
    fragColor = vec4(ch[clamp(uView, 0, last)], ch[clamp(uView + 1, 0, last)], ch[clamp(uView + 2, 0, last)], 1.0);
}}
"""


def classic_textures(rt: G.GLRuntime, m: G.MaterialDesc, rng) -> tuple[list[int], list[str]]:
    """One BC texture per semantic at the reference size with a full mip chain -> (names, formats)."""
    has_s3tc = "GL_EXT_texture_compression_s3tc" in rt.ctx.extensions
    groups: dict[str, list] = {}
    for o in m.outputs:
        if not o.reconstructed:
            groups.setdefault(o.semantic, []).append(o)
    w0, h0 = m.ref_size
    texs, fmts = [], []
    for sem, outs in groups.items():
        kind = outs[0].kind
        if kind == "normal":
            fmt, block, name = GL_COMPRESSED_RG_RGTC2, 16, "BC5"
        elif len(outs) == 1:
            fmt, block, name = GL_COMPRESSED_RED_RGTC1, 8, "BC4"
        elif has_s3tc:
            fmt, block, name = GL_COMPRESSED_RGB_S3TC_DXT1_EXT, 8, "BC1"
        else:
            fmt, block, name = GL_COMPRESSED_RGBA_BPTC_UNORM, 16, "BC7"
        levels = []
        for k in range(max(w0, h0).bit_length()):
            w, h = max(1, w0 >> k), max(1, h0 >> k)
            n = ((w + 3) // 4) * ((h + 3) // 4)
            levels.append((rng.integers(0, 256, (n, block), dtype=np.uint8), w, h))
        texs.append(rt.upload_compressed(levels, fmt, m.wrap))
        fmts.append(f"{sem}:{name}")
    return texs, fmts


def time_pass(rt: G.GLRuntime, prog, vao, fbo, textures, frames: int, warmup: int, wall: bool = False) -> float:
    """Median GPU time of one full-screen draw in milliseconds (GL_TIME_ELAPSED per draw), or with
    ``wall`` the median wall time of draw + glFinish (llvmpipe's time queries do not cover its
    asynchronous rasterizer threads, so they under-report cheap passes)."""
    import time

    fbo.use()
    rt.bind_textures(textures)
    query = rt.ctx.query(time=True)
    for _ in range(warmup):
        vao.render(rt.moderngl.TRIANGLES, vertices=3)
    rt.ctx.finish()
    times = []
    for _ in range(frames):
        if wall:
            t0 = time.perf_counter()
            vao.render(rt.moderngl.TRIANGLES, vertices=3)
            rt.ctx.finish()
            times.append((time.perf_counter() - t0) * 1e3)
        else:
            with query:
                vao.render(rt.moderngl.TRIANGLES, vertices=3)
            times.append(query.elapsed / 1e6)
    return statistics.median(times)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="material folder or build folder")
    ap.add_argument("--material", default=None, help="prim / material name in a build")
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--warmup", type=int, default=20)
    ap.add_argument("--sizes", default="1080p,1440p,2160p", help="comma list of 1080p/1440p/2160p or WxH")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)

    from bcfpipe.cli.decode import select_target

    target = select_target(args.out, args.material)
    m = target.desc
    try:
        rt = G.GLRuntime()
    except G.GLUnavailable as e:
        print(f"no OpenGL: {e}", file=sys.stderr)
        return 2
    software = rt.is_software
    sizes = []
    for s in args.sizes.split(","):
        s = s.strip()
        sizes.append((s, SIZES[s]) if s in SIZES else (s, tuple(int(x) for x in s.lower().split("x"))))
    frames, warmup = args.frames, args.warmup
    if software:
        sizes, frames, warmup = [("256x144", (256, 144))], min(frames, 5), min(warmup, 1)

    gm = rt.load(m)
    hidden = m.file.mlp.n_hidden
    neural = rt.render_program({"BCF_N_HIDDEN": hidden, "BCF_N_OUT": m.n_out, "BCF_MAX_OUT": m.c_out})
    ctex, cfmts = classic_textures(rt, m, np.random.default_rng(0))
    classic = rt.ctx.program(vertex_shader=G.assemble("vert"), fragment_shader=classic_frag(len(ctex)))
    rows = []
    try:
        for label, (w, h) in sizes:
            fbo = rt.ctx.simple_framebuffer((w, h), components=4)  # RGBA8
            uvt = (w / m.ref_size[0], h / m.ref_size[1], 0.0, 0.0)  # ~1 reference texel per pixel
            G.set_uniforms(neural, dict(gm.uniforms(), uLodMode=0, uLod=0.0, uView=0, uUvTransform=uvt))
            G.set_uniforms(classic, {"uView": 0, "uUvTransform": uvt})
            gm.weights.bind_to_storage_buffer(0)
            nvao, cvao = rt.ctx.vertex_array(neural, []), rt.ctx.vertex_array(classic, [])
            t_neural = time_pass(rt, neural, nvao, fbo, gm.textures, frames, warmup, software)
            t_classic = time_pass(rt, classic, cvao, fbo, ctex, frames, warmup, software)
            rows.append({"size": label, "width": w, "height": h, "neural_ms": t_neural, "classic_ms": t_classic,
                         "overhead_ms": t_neural - t_classic, "ratio": t_neural / t_classic})
            nvao.release()
            cvao.release()
    finally:
        rt.delete_textures(ctex)
        rt.unload(gm)
    report = {"material": m.name, "renderer": rt.info, "software": software, "frames": frames,
              "classic_formats": cfmts, "network": f"12-{hidden}-{m.n_out}",
              "layers": [x.resolution for x in m.file.layers], "rows": rows}
    rt.release()
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"{m.name}: neural 12-{hidden}-{m.n_out}, layers {report['layers']}; classic {', '.join(cfmts)}")
    print(f"renderer: {report['renderer']['renderer']} | {report['renderer']['version']}")
    if software:
        r = rows[0]
        print(f"software renderer: {r['size']}, median of {frames} frames; neural / classic time ratio "
              f"{r['ratio']:.2f} (absolute times are not meaningful here)")
        return 0
    print(f"median of {frames} frames (GL_TIME_ELAPSED)")
    print(f"{'size':>8} {'classic ms':>11} {'neural ms':>10} {'overhead ms':>12} {'ratio':>6}")
    for r in rows:
        print(f"{r['size']:>8} {r['classic_ms']:>11.3f} {r['neural_ms']:>10.3f} {r['overhead_ms']:>12.3f} "
              f"{r['ratio']:>6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
