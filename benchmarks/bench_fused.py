"""Issue 30: training throughput of the fused kernel against the torch path, per phase.

Trains the teapot (profile 1k, the `standard` preset's batch and rates) for a short schedule with
each kernel, repetitions interleaved (torch, fused, torch, fused, ...) so that load hits both alike,
at 1 and 2 threads, and reports samples per second of the warm-up and of the constrained phase (the
real steps: targets, features, MLP, loss, backward, Adam), from the trainer's own phase timings.
The kernels are compiled (or loaded from the cache) before anything is timed.

  python benchmarks/bench_fused.py [--set teapot] [--profile 1k] [--steps 120] [--reps 2] [--threads 1,2]
                                  [--backends native,numba]
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, machine, specs  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(ap, set="teapot", profile="1k", features="bc6h")
    ap.add_argument("--steps", type=int, default=120, help="steps of each timed phase")
    add_options(ap, reps=2, threads="1,2")
    ap.add_argument("--backends", default="native,numba", help="fused implementations to time beside torch")
    args = ap.parse_args()

    import torch

    from bcfpipe.config import PRESETS, TrainingOptions
    from bcfpipe.export.material import make_config
    from bcfpipe.formats.vocabulary import Kernel
    from bcfpipe.texset.texture_set import load_texture_set
    from bcfpipe.train.fused import step as fused_step
    from bcfpipe.train.trainer import train

    ts = load_texture_set(specs(args.set))
    _, cfg = make_config(ts, TrainingOptions(profile=args.profile, features=args.features, device="cpu"))
    std = PRESETS["standard"]
    preset = replace(std, warmup=replace(std.warmup, steps=args.steps),
                     constrained=replace(std.constrained, steps=args.steps), finetune=replace(std.finetune, steps=1))
    cfg = cfg.with_(preset=preset, preset_name="bench")
    print(f"machine: {machine()}; {args.set} {ts.width}x{ts.height}, profile {args.profile}, {args.features}, batch "
          f"{preset.batch}, {args.steps} steps per phase (the constrained phase's second half quantization-aware), "
          f"{args.reps} interleaved repetitions")
    warm = replace(preset, warmup=replace(std.warmup, steps=2), constrained=replace(std.constrained, steps=2))
    backends = args.backends.split(",")
    for b in backends:  # compile / load
        fused_step._BACKEND = b
        train(ts, cfg.with_(preset=warm, kernel=Kernel.FUSED, threads=1), measure_float=False)

    rows = []
    for threads in (int(t) for t in args.threads.split(",")):
        rate: dict[tuple[str, str], list[float]] = {}
        for _ in range(args.reps):
            for name in ["torch", *backends]:
                fused_step._BACKEND = None if name == "torch" else name
                kernel = Kernel.TORCH if name == "torch" else Kernel.FUSED
                torch.manual_seed(0)
                tm = train(ts, cfg.with_(kernel=kernel, threads=threads), measure_float=False)
                for phase in ("warmup", "constrained"):
                    rate.setdefault((name, phase), []).append(tm.phase_samples[phase] / tm.phase_seconds[phase])
        for phase in ("warmup", "constrained"):
            rows.append((threads, phase, [max(rate[(name, phase)]) for name in ["torch", *backends]]))
    print("\n| threads | phase | torch samples/s | " + " | ".join(f"{b} samples/s | {b} / torch" for b in backends) + " |")
    print("|---:|---|---:|" + "---:|---:|" * len(backends))
    for threads, phase, r in rows:
        print(f"| {threads} | {phase} | {r[0]:,.0f} | " + " | ".join(f"{f:,.0f} | {f / r[0]:.2f}x" for f in r[1:]) + " |")
    print("\n(best of the repetitions for each cell)")


if __name__ == "__main__":
    main()
