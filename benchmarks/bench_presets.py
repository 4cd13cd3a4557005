"""Issue 30: what each quality preset buys, per mip, from the exported files.

Trains one texture set at one profile with each preset named (one of config.PRESETS, or a custom
``name:warmup:constrained:finetune:batch`` schedule in the CPU presets' rates), one after another on
one thread with the default kernel, and prints one row per preset as it finishes: PSNR at every
reference mip and over all mips (the DDS features and fp16 decoder through onnxruntime,
``train_material``), the training time and the wall time with export and measurement.

  python benchmarks/bench_presets.py --set teapot --profile 1k [--features bc6h] [--kernel auto]
                                     [--presets draft,fast,standard] [--device cpu] [--keep DIR]

``--device cuda`` trains on a GPU (the presets' CUDA step counts; ``--kernel auto`` is torch there);
``--keep DIR`` keeps each preset's exported material in DIR/<preset> (for bench_decode_formats.py).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import PSNR_NOTE, add_options, machine, mip_columns, psnr_cells, specs  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(ap, set="teapot", profile="1k", features="bc6h", kernel="auto", presets="draft,fast,standard", seed=0)
    ap.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N")
    ap.add_argument("--keep", type=Path, default=None, help="keep each exported material in KEEP/<preset>")
    args = ap.parse_args()

    from bcfpipe.config import PRESETS, TrainingOptions, _cpu_preset
    from bcfpipe.export.material import train_material, make_config
    from bcfpipe.texset.texture_set import load_texture_set

    ts = load_texture_set(specs(args.set))
    print(f"machine: {machine()}; {args.set} {ts.width}x{ts.height}, profile {args.profile}, {args.features}, "
          f"--kernel {args.kernel}, --device {args.device}, 1 thread, seed {args.seed}", flush=True)
    header = False
    for spec in args.presets.split(","):
        if ":" in spec:
            name, w, b, m, batch = spec.split(":")
            preset = _cpu_preset(int(w), int(b), int(m), int(batch))
        else:
            name, preset = spec, PRESETS[spec]
        _, cfg = make_config(ts, TrainingOptions(profile=args.profile, features=args.features, kernel=args.kernel,
                                                 device=args.device, seed=args.seed))
        cfg = cfg.with_(preset=preset, preset_name=name, threads=1)
        with tempfile.TemporaryDirectory(prefix="bcfpipe-presets-") as tmp:
            t = time.perf_counter()
            out = args.keep / name if args.keep else Path(tmp) / "m"
            res, _ = train_material(ts, out, cfg, args.profile)
            wall = time.perf_counter() - t
        m = res.metrics
        if not header:
            n = len(m.psnr_per_mip)
            print("\n| preset | steps (warm-up + constrained + MLP) x batch | " + mip_columns(n) + " | all mips | train | wall |")
            print("|---|---|" + "---:|" * (n + 3))
            header = True
        steps = f"{preset.warmup.steps} + {preset.constrained.steps} + {preset.finetune.steps} x {preset.batch}"
        print(f"| {name} | {steps} | {psnr_cells(m.psnr_per_mip, m.psnr)} | {res.train_seconds:.0f} s | {wall:.0f} s |",
              flush=True)
    print(PSNR_NOTE)


if __name__ == "__main__":
    main()
