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
from bench_fidelity import specs  # noqa: E402
from common import machine  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", default="teapot")
    ap.add_argument("--profile", default="0.5k")
    ap.add_argument("--scales", default="1,3,10,30")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--base", default=None, metavar="WARM:CONSTRAINED",
                    help="k = 1's warm-up and constrained steps (default: the standard preset's); "
                         "800:4000 is the standard issue 30 was filed against")
    ap.add_argument("--lod-power", type=float, default=None,
                    help="draw each step's lods as s = s_max u^p with this p instead of the preset's (2); "
                         "p = 8 gives mip 0 about 75%% of the samples, RTXNTC's share (texel-count proportional)")
    args = ap.parse_args()

    from bcfpipe.texset.baselines import encode_texture_set_baseline
    from bcfpipe.config import PRESETS, PROFILES, TrainingOptions, _cpu_preset
    from bcfpipe.export.material import train_material, make_config
    from bcfpipe.formats.vocabulary import Kernel
    from bcfpipe.texset.metrics import mse_per_mip, psnr_from_mse
    from bcfpipe.texset.texture_set import build_mip_chain, load_texture_set

    ts = load_texture_set(specs(args.set))
    std = PRESETS["standard"]
    if args.base:
        warm, constrained = (int(v) for v in args.base.split(":"))
        std = _cpu_preset(warm, constrained, std.finetune.steps, std.batch)
    t0_side = PROFILES[args.profile][0]
    ref = build_mip_chain(ts.data)
    bc, _ = encode_texture_set_baseline(ts, "bc", t0_side, ref_mips=ref)
    bc_mips = [psnr_from_mse(m) for m in mse_per_mip(ref, bc, ts.channels)]
    n = len(bc_mips)
    print(f"machine: {machine()}; {args.set} {ts.width}x{ts.height}, profile {args.profile}, the standard "
          f"schedule ({std.warmup.steps} + {std.constrained.steps} steps of {std.batch}) scaled k times, "
          f"--kernel fused, 1 thread, seed {args.seed}, lod power {args.lod_power or std.lod_power:g}", flush=True)
    print("\n| k | samples | " + " | ".join(f"mip {i}" for i in range(n)) + " | all mips | train |")
    print("|---:|---:|" + "---:|" * (n + 2))
    print(f"| BC@{t0_side} | | " + " | ".join(f"{v:.1f}" for v in bc_mips) + " | | |", flush=True)
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
            print(f"| {k} | {samples:.2e} | " + " | ".join(f"{v:.1f}" for v in m.psnr_per_mip)
                  + f" | **{m.psnr:.2f}** | {res.train_seconds:.0f} s ({wall:.0f} s with export) |", flush=True)
    print("\n(PSNR in dB from the exported files; all mips: MSE averaged over the mips, as everywhere in bcfpipe)")


if __name__ == "__main__":
    main()
