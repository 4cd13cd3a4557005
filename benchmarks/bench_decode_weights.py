"""Where the decoder's per-pixel cost goes: the same decode with its weights read three ways.

glsl/bcf_decode.glsl reads the MLP's fp16 weights through ``bcfWeightWord``, which the including
shader defines. The shipped shaders read a shader storage buffer (``ssbo``). This benchmark swaps
only that accessor: a uniform buffer (``ubo``, std140, the constant cache on most GPUs), or the
record's words compiled into the shader as a constant array (``const``; with BCF_N_HIDDEN /
BCF_N_OUT the loops unroll and every weight can become an immediate). Each variant is timed
against the classic BC pass, frames interleaved, in the fragment stage (full-screen draw) and the
compute stage (grid dispatch), as bcfpipe.bench.decode_cost does; the compute outputs of every
variant are checked bit for bit against the ssbo one first, and the ssbo one against the library's
own decode (`GLRuntime.decode`, which verify checks against ONNX). The programs compile with the
material's own #defines (`MaterialDesc.defines`: BCF_N_LAYERS for a T_0 of several layers, issue 52),
as bcfpipe.bench.decode_cost and verify compile theirs.

  python benchmarks/bench_decode_weights.py MATERIAL_FOLDER [--size 1920x1080] [--frames 100]
"""
from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402

SSBO = ("layout(std430, binding = 0) readonly buffer BcfWeights { uint bcfWeights[]; };\n"
        "uint bcfWeightWord(uint wordIndex) { return bcfWeights[wordIndex]; }")


def accessor(variant: str, words: np.ndarray) -> str:
    if variant == "ssbo":
        return SSBO
    if variant == "ubo":
        n = -(-len(words) // 4)
        return (f"layout(std140, binding = 0) uniform BcfWeightBlock {{ uvec4 bcfW4[{n}]; }};\n"
                "uint bcfWeightWord(uint wordIndex) { return bcfW4[wordIndex >> 2u][wordIndex & 3u]; }")
    body = ", ".join(f"{int(w)}u" for w in words)
    return (f"const uint bcfWords[{len(words)}] = uint[]({body});\n"
            "uint bcfWeightWord(uint wordIndex) { return bcfWords[wordIndex]; }")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--size", default="640x360", help="comma list of WxH")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--variants", default="ssbo,ubo,const")
    args = ap.parse_args()
    from bcfpipe.bench import decode_cost as D
    from bcfpipe.verify import glsl as G
    from bcfpipe.verify.targets import find_targets

    m = find_targets(args.folder)[0].desc
    raw = m.weights_file.read_bytes()
    raw += b"\0" * (-len(raw) % 16)
    words = np.frombuffer(raw, "<u4")
    variants = args.variants.split(",")
    defines = {**m.defines, "BCF_N_HIDDEN": m.file.mlp.n_hidden, "BCF_N_OUT": m.n_out, "BCF_MAX_OUT": m.c_out}
    rt = G.GLRuntime()
    try:
        gm = rt.load(m)
        ubo = rt.ctx.buffer(raw)
        names, fmts = D.upload_classic(rt, D.random_classic(m), m.wrap)
        comp = {v: rt.ctx.compute_shader(G.assemble("comp", defines).replace(SSBO, accessor(v, words)))
                for v in variants}
        frag = {v: rt.ctx.program(vertex_shader=G.assemble("vert"),
                                  fragment_shader=G.assemble("frag", defines).replace(SSBO, accessor(v, words)))
                for v in variants}

        def bind(v):
            rt.bind_textures(gm.textures)
            (ubo.bind_to_uniform_block(0) if v == "ubo" else gm.weights.bind_to_storage_buffer(0))

        # the same values from every accessor: a 256 x 256 grid at lod 0 and lod 3
        check = {}
        for v in variants:
            bind(v)
            outs = []
            for lod in (0.0, 3.0):
                out = rt.ctx.buffer(reserve=256 * 256 * m.c_out * 4)
                out.bind_to_storage_buffer(2)
                G.set_uniforms(comp[v], dict(gm.uniforms(), uCount=256 * 256, uOutStride=m.c_out, uGrid=(256, 256),
                                             uGridLod=lod, uGradQueries=False))
                comp[v].run(group_x=256 * 256 // G.LOCAL_SIZE)
                rt.ctx.finish()
                outs.append(np.frombuffer(out.read(), np.float32).copy())
                out.release()
            check[v] = np.concatenate(outs)
        g = (np.stack(np.meshgrid(np.arange(256), np.arange(256)), -1).reshape(-1, 2) + 0.5) / 256
        lib = np.concatenate([rt.decode(gm, g, lod).reshape(-1) for lod in (0.0, 3.0)])
        print(f"ssbo: max |diff| against the library's decode {np.abs(check['ssbo'] - lib).max():.3g}")
        for v in variants:
            same = np.array_equal(check[v].view(np.uint32), check["ssbo"].view(np.uint32))
            print(f"{v}: compute output {'bit-identical to' if same else 'DIFFERS from'} ssbo "
                  f"(max |diff| {np.abs(check[v] - check['ssbo']).max():.3g})")

        print(f"machine: {machine()}; {rt.info['renderer']}; {args.frames} frames, interleaved; "
              f"classic: {'+'.join(fmts)}; {len(m.file.layers)} feature layers; "
              f"MLP {m.file.mlp.n_in}-{m.file.mlp.n_hidden}-{m.n_out}")
        print("\n| stage | size | classic ms | " + " | ".join(f"{v} ms" for v in variants) + " | "
              + " | ".join(f"{v} / classic" for v in variants) + " |")
        print("|---|---|---:|" + "---:|" * (2 * len(variants)))
        query = rt.ctx.query(time=True)
        software = rt.is_software
        plain_c = rt.ctx.compute_shader(D.classic_comp(len(names)))
        plain_f = rt.ctx.program(vertex_shader=G.assemble("vert"), fragment_shader=D.classic_frag(len(names)))
        for stage in ("fragment", "compute"):
            for size in args.size.split(","):
                w, h = (int(x) for x in size.split("x"))
                count, groups = w * h, -(-w * h // G.LOCAL_SIZE)
                out = rt.ctx.buffer(reserve=count * 3 * 4)
                out.bind_to_storage_buffer(2)
                fbo = rt.ctx.simple_framebuffer((w, h), components=4)
                fbo.use()
                uvt = (w / m.ref_size[0], h / m.ref_size[1], 0.0, 0.0)
                vaos = {}
                times = {k: [] for k in ["classic"] + variants}
                for i in range(5 + args.frames):
                    for k in ["classic"] + variants:
                        if stage == "compute":
                            prog = plain_c if k == "classic" else comp[k]
                            u = dict(uCount=count, uGrid=(w, h), uGridLod=0.0)
                            u.update(uView=0) if k == "classic" else u.update(gm.uniforms(), uOutStride=3,
                                                                             uGradQueries=False)
                            G.set_uniforms(prog, u)
                            rt.bind_textures(names) if k == "classic" else bind(k)
                            t = D._time_dispatch(rt, prog, groups, query, software)
                        else:
                            prog = plain_f if k == "classic" else frag[k]
                            vao = vaos.setdefault(k, rt.ctx.vertex_array(prog, []))
                            u = dict(uView=0, uUvTransform=uvt)
                            if k != "classic":
                                u.update(gm.uniforms(), uLodMode=0, uLod=0.0)
                            G.set_uniforms(prog, u)
                            rt.bind_textures(names) if k == "classic" else bind(k)
                            t = D._time_draw(rt, vao, query, software)
                        if i >= 5:
                            times[k].append(t)
                med = {k: statistics.median(v) for k, v in times.items()}
                print(f"| {stage} | {w}x{h} | {med['classic']:.3f} | " + " | ".join(f"{med[v]:.3f}" for v in variants)
                      + " | " + " | ".join(f"{med[v] / med['classic']:.1f}" for v in variants) + " |", flush=True)
                out.release()
    finally:
        rt.release()


if __name__ == "__main__":
    main()
