"""Issue 29: the decode cost of BC6H against BC7 feature textures, in one GL run.

Times a full-screen decode of two exported materials of the same texture set (one trained with
`--features bc6h`, one with `bc7`) against one pass sampling the classic BC textures an engine
would ship for it (BC1/BC4/BC5, random blocks at the reference size: sampling cost does not depend
on block contents), frames interleaved in one GL context (bcfpipe.bench.decode_cost.measure).
On llvmpipe only the ratios are meaningful.

  python benchmarks/bench_decode_formats.py BC6H_FOLDER BC7_FOLDER [--size 640x360] [--frames 5]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bc6h", type=Path)
    ap.add_argument("bc7", type=Path)
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--frames", type=int, default=5)
    args = ap.parse_args()
    from bcfpipe.bench import decode_cost as D
    from bcfpipe.verify import glsl as G
    from bcfpipe.verify.targets import find_targets

    w, h = (int(v) for v in args.size.split("x"))
    descs = [find_targets(f)[0].desc for f in (args.bc6h, args.bc7)]
    rt = G.GLRuntime()
    try:
        names, fmts = D.upload_classic(rt, D.random_classic(descs[0]), descs[0].wrap)
        costs = D.measure(rt, descs, names, (w, h), args.frames, 1)
        print(f"machine: {machine()}; {rt.info['renderer']}; {w}x{h}, {args.frames} frames, interleaved")
        print("| features | neural ms | classic ms (" + "+".join(fmts) + ") | neural / classic |")
        print("|---|---:|---:|---:|")
        for name, c in zip(("bc6h", "bc7"), costs):
            j = c.to_json()
            print(f"| {name} | {j['neural_ms']:.1f} | {j['classic_ms']:.2f} | {j['ratio']:.0f} |")
    finally:
        rt.release()


if __name__ == "__main__":
    main()
