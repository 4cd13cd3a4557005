#!/usr/bin/env python3
"""Decoding cost of a neural material vs classic block-compressed textures (paper Table 4 setup).

Renders a full-screen pass at 1080p, 1440p and 2160p into an RGBA8 framebuffer and times each draw
with GL timer queries (GL_TIME_ELAPSED); reports the median over N frames after warm-up, the
frames of the two passes interleaved (bcfpipe.bench.decode_cost, which `bcfpipe bench` uses too).

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
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bcfpipe.bench import decode_cost as D  # noqa: E402
from bcfpipe.verify import glsl as G  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="material folder or build folder")
    ap.add_argument("--material", default=None, help="prim / material name in a build")
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--warmup", type=int, default=20)
    ap.add_argument("--sizes", default="1080p,1440p,2160p", help="comma list of 1080p/1440p/2160p or WxH")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)

    if args.material is None:  # no CLI import: runs where USD is not installed (a lent GPU machine)
        from bcfpipe.verify.checks import find_targets

        targets = find_targets(args.out)
        if len(targets) != 1:
            print(f"{args.out} holds {len(targets)} materials; pick one with --material", file=sys.stderr)
            return 2
        m = targets[0].desc
    else:
        from bcfpipe.cli.decode import select_target

        m = select_target(args.out, args.material).desc
    try:
        rt = G.GLRuntime()
    except G.GLUnavailable as e:
        print(f"no OpenGL: {e}", file=sys.stderr)
        return 2
    software = rt.is_software
    sizes = []
    for s in args.sizes.split(","):
        s = s.strip()
        sizes.append((s, D.SIZES[s]) if s in D.SIZES else (s, tuple(int(x) for x in s.lower().split("x"))))
    frames, warmup = args.frames, args.warmup
    if software:
        sizes, frames, warmup = [("256x144", (256, 144))], min(frames, 5), min(warmup, 1)
    ctex, cfmts = D.upload_classic(rt, D.random_classic(m), m.wrap)
    rows = []
    try:
        for label, size in sizes:
            (c,) = D.measure(rt, [m], ctex, size, frames, warmup)
            rows.append({"size": label, "width": c.width, "height": c.height, "neural_ms": c.neural_ms,
                         "classic_ms": c.classic_ms, "overhead_ms": c.neural_ms - c.classic_ms, "ratio": c.ratio})
    finally:
        rt.delete_textures(ctex)
    hidden = m.file.mlp.n_hidden
    report = {"material": m.name, "renderer": rt.info, "software": software, "frames": frames,
              "classic_formats": cfmts, "network": f"{m.file.mlp.n_in}-{hidden}-{m.n_out}",
              "layers": [x.resolution for x in m.file.layers], "rows": rows}
    rt.release()
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"{m.name}: neural {report['network']}, layers {report['layers']}; classic {', '.join(cfmts)}")
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
