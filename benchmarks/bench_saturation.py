"""Issue 30: where the method saturates on a CPU, PSNR against samples trained.

Trains one set with the `standard` preset's schedule scaled k times (warm-up and constrained steps ×
k, same batch, the same per-phase decay to the same final rates; the MLP fine-tune unchanged), with
the fused kernel on one thread, for each k, and reports from the exported files (the DDS features
and fp16 decoder through onnxruntime, `train_material`): PSNR at every reference mip and over all
mips, against BC at the profile's T_0 resolution at every mip. Rows print as they finish, so a cut
run keeps its rows. Run one process per set to use two cores.

  python benchmarks/bench_saturation.py --set teapot [--profile 0.5k] [--scales 1,3,10,30] [--base 800:4000]

`--base` sets k = 1's warm-up and constrained steps; 800:4000 is the `standard` that issue 30 was
filed against ("today's"), the default is the current `standard`.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import PSNR_NOTE, add_options, bc_per_mip, machine, mip_columns, psnr_cells, specs  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(ap, set="teapot", profile="0.5k", scales="1,3,10,30", seed=0)
    ap.add_argument("--base", default=None, metavar="WARM:CONSTRAINED",
                    help="k = 1's warm-up and constrained steps (default: the standard preset's); "
                         "800:4000 is the standard issue 30 was filed against")
    ap.add_argument("--lod-power", type=float, default=None,
                    help="draw each step's lods as s = s_max u^p with this p instead of the preset's (2); "
                         "p = 8 gives mip 0 about 75%% of the samples, RTXNTC's share (texel-count proportional)")
    args = ap.parse_args()

    from bcfpipe.config import PRESETS, PROFILES, TrainingOptions, _cpu_preset
    from bcfpipe.export.material import train_material, make_config
    from bcfpipe.formats.vocabulary import Kernel
    from bcfpipe.texset.texture_set import load_texture_set

    ts = load_texture_set(specs(args.set))
    std = PRESETS["standard"]
    if args.base:
        warm, constrained = (int(v) for v in args.base.split(":"))
        std = _cpu_preset(warm, constrained, std.finetune.steps, std.batch)
    t0_side = PROFILES[args.profile][0]
    bc_mips = bc_per_mip(ts, t0_side)
    n = len(bc_mips)
    print(f"machine: {machine()}; {args.set} {ts.width}x{ts.height}, profile {args.profile}, the standard "
          f"schedule ({std.warmup.steps} + {std.constrained.steps} steps of {std.batch}) scaled k times, "
          f"--kernel fused, 1 thread, seed {args.seed}, lod power {args.lod_power or std.lod_power:g}", flush=True)
    print("\n| k | samples | " + mip_columns(n) + " | all mips | train |")
    print("|---:|---:|" + "---:|" * (n + 2))
    print(f"| BC@{t0_side} | | {psnr_cells(bc_mips)} | | |", flush=True)
    with tempfile.TemporaryDirectory(prefix="bcfpipe-saturation-") as tmp:
        for k in (int(s) for s in args.scales.split(",")):
            preset = _cpu_preset(std.warmup.steps * k, std.constrained.steps * k, std.finetune.steps, std.batch)
            if args.lod_power is not None:
                preset = replace(preset, lod_power=args.lod_power)
            _, cfg = make_config(ts, TrainingOptions(profile=args.profile, device="cpu", seed=args.seed))
            cfg = cfg.with_(preset=preset, preset_name=f"standard x{k}", kernel=Kernel.FUSED, threads=1)
            t = time.perf_counter()
            res, _ = train_material(ts, Path(tmp) / f"k{k}", cfg, args.profile)
            wall = time.perf_counter() - t
            samples = (preset.warmup.steps + preset.constrained.steps) * preset.batch
            m = res.metrics
            print(f"| {k} | {samples:.2e} | {psnr_cells(m.psnr_per_mip, m.psnr)} "
                  f"| {res.train_seconds:.0f} s ({wall:.0f} s with export) |", flush=True)
    print(PSNR_NOTE)


if __name__ == "__main__":
    main()
