"""Issue 29: the decode cost of BC6H against BC7 feature textures, in one GL run.

Times a full-screen decode of exported materials of the same texture set (say one trained with
`--features bc6h`, one with `bc7`) against one pass sampling the classic BC textures an engine
would ship for it (BC1/BC4/BC5, random blocks at the reference size: sampling cost does not depend
on block contents), frames interleaved in one GL context (bcfpipe.bench.decode_cost.measure).
``--stages compute`` times the same decodes as compute dispatches over the grid
(decode_cost.measure_compute), which on a GPU with a weak fragment stage shows the decoder's own
cost. On llvmpipe only the ratios are meaningful.

  python benchmarks/bench_decode_formats.py FOLDER [FOLDER ...] [--size 640x360[,WxH]] [--frames 5]
                                            [--stages fragment[,compute]]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", type=Path, nargs="+", help="exported material folders of one texture set")
    ap.add_argument("--size", default="640x360", help="comma list of WxH")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--stages", default="fragment", help="comma list of fragment, compute")
    args = ap.parse_args()
    from bcfpipe.bench import decode_cost as D
    from bcfpipe.verify import glsl as G
    from bcfpipe.verify.targets import find_targets

    descs = [find_targets(f)[0].desc for f in args.folders]
    labels = [("bc7" if d.bc7 else "bc6h") + f" ({f.name})" for d, f in zip(descs, args.folders)]
    rt = G.GLRuntime()
    try:
        names, fmts = D.upload_classic(rt, D.random_classic(descs[0]), descs[0].wrap)
        print(f"machine: {machine()}; {rt.info['renderer']}; {args.frames} frames, interleaved; "
              f"classic: {'+'.join(fmts)}")
        print("\n| stage | size | features | neural ms | classic ms | neural / classic |")
        print("|---|---|---|---:|---:|---:|")
        for stage in args.stages.split(","):
            run = {"fragment": D.measure, "compute": D.measure_compute}[stage]
            for size in args.size.split(","):
                w, h = (int(v) for v in size.split("x"))
                for label, c in zip(labels, run(rt, descs, names, (w, h), args.frames, 1)):
                    print(f"| {stage} | {w}x{h} | {label} | {c.neural_ms:.2f} | {c.classic_ms:.3f} | "
                          f"{c.ratio:.1f} |", flush=True)
    finally:
        rt.release()


if __name__ == "__main__":
    main()
