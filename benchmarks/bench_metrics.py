"""What measuring a trained material costs: `compute_metrics` (PSNR per mip and group, SSIM, FLIP)
on a real set, with the groups' SSIMs one at a time and two at a time, repetitions interleaved.

The decoded mips are the reference plus noise of about 35 dB: the metrics' cost does not depend
on the error. Prints each configuration's median seconds and checks that both give the same record.

  python benchmarks/bench_metrics.py [--set teapot] [--reps 3]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, machine, specs  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(ap, set="teapot", reps=3)
    args = ap.parse_args()
    import bcfpipe.texset.metrics as M
    from bcfpipe.texset.texture_set import build_mip_chain, load_texture_set

    ts = load_texture_set(specs(args.set))
    ref = build_mip_chain(ts.data)
    rng = np.random.default_rng(0)
    dec = [r + rng.normal(0, 0.018, r.shape).astype(np.float32) for r in ref]
    print(f"machine: {machine()}; {args.set} {ts.width}x{ts.height} x {len(ts.channels)} channels, "
          f"{args.reps} interleaved repetitions", flush=True)
    configs = {"one at a time": 0, "two at a time": M.SSIM_PARALLEL_VALUES}
    times: dict[str, list[float]] = {k: [] for k in configs}
    records = {}
    saved = M.SSIM_PARALLEL_VALUES
    try:
        for _ in range(args.reps):
            for name, limit in configs.items():
                M.SSIM_PARALLEL_VALUES = limit
                t = time.perf_counter()
                records[name] = M.compute_metrics(ref, dec, ts.channels)
                times[name].append(time.perf_counter() - t)
    finally:
        M.SSIM_PARALLEL_VALUES = saved
    print("\n| SSIM groups | compute_metrics (median) | runs |\n|---|---:|---|")
    for name, ts_ in times.items():
        print(f"| {name} | {statistics.median(ts_):.2f} s | {', '.join(f'{x:.2f}' for x in ts_)} |")
    a, b = records.values()
    print(f"\nsame record: {a == b} (SSIM {a.ssim:.4f}, FLIP {a.flip:.4f}, PSNR {a.psnr:.2f} dB)")


if __name__ == "__main__":
    main()
