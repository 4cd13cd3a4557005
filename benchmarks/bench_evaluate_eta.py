"""The evaluation's ETA constant (`export.material.METRICS_PER_DECODE`): the metrics' seconds in
units of the decode's, for exported folders of a named set.

Per folder, twice: `writer.decode_mips` of the folder, then `metrics_and_errors` with PSNR and the
per-channel errors alone, and with SSIM and FLIP at mip 0. Prints the seconds and both ratios.

  python benchmarks/bench_evaluate_eta.py --set bottle FOLDER [FOLDER ...]

(FOLDER: a `bcfpipe train` output of that set, e.g. one with `--layout neural` and one with the
default layout.)
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, machine, specs  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(ap, set="bottle", reps=2)
    ap.add_argument("folders", nargs="+", type=Path)
    args = ap.parse_args()
    from bcfpipe.export import writer
    from bcfpipe.texset.chain import Reference
    from bcfpipe.texset.metrics import metrics_and_errors
    from bcfpipe.texset.texture_set import load_texture_set

    ts = load_texture_set(specs(args.set))
    ref = Reference.of(ts, None, "repeat")
    print(f"machine: {machine()}; {args.set} {ts.width}x{ts.height} x {len(ts.channels)} channels", flush=True)
    for folder in args.folders:
        for _ in range(args.reps):
            t = time.perf_counter()
            dec = writer.decode_mips(writer.load(folder), ref.shapes)
            decode = time.perf_counter() - t
            t = time.perf_counter()
            metrics_and_errors(ref.mips, dec, ts.channels, ssim=False, flip=False)
            psnr = time.perf_counter() - t
            t = time.perf_counter()
            metrics_and_errors(ref.mips, dec, ts.channels)
            image = time.perf_counter() - t
            print(f"{folder}: decode {decode:.2f} s; PSNR alone {psnr:.2f} s ({psnr / decode:.2f}); "
                  f"with SSIM and FLIP {image:.2f} s ({image / decode:.2f})", flush=True)


if __name__ == "__main__":
    main()
