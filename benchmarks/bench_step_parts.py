"""Issue 30: where a training's time goes as T_0 grows: the phases, and each part of a fused step.

Trains one set at each profile named with a short schedule (200 + 600 + 10 steps of 128² by
default) on one thread with the default kernel, with timers around every call of each part of a
step, and prints the phases' seconds and each part's milliseconds per call: the features' Adam
(`FusedStep.adam`: Adam, clamp and gradient zeroing), the step's targets (`_batch_at`; of them the
texel-centre batches and the bicubic lookups, per call), the kernel (`FusedStep.__call__`) and the
MLP's Adam (torch's). The kernel's own work per sample does not depend on the profile; Adam's and
the first encode's grow with the blocks.

  python benchmarks/bench_step_parts.py --set teapot --profiles 1k,2k [--steps 200:600:10]
"""
from __future__ import annotations

import argparse
import collections
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, machine, specs  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(ap, set="teapot", profiles="1k,2k")
    ap.add_argument("--steps", default="200:600:10", help="warm-up:constrained:finetune steps")
    args = ap.parse_args()

    import torch

    import bcfpipe.train.fused.step as S
    import bcfpipe.train.fused.targets as TG
    import bcfpipe.train.trainer as T
    from bcfpipe.config import TrainingOptions, _cpu_preset
    from bcfpipe.export.material import make_config
    from bcfpipe.texset.texture_set import load_texture_set

    seconds: dict[str, float] = collections.defaultdict(float)
    calls: collections.Counter = collections.Counter()

    def timed(owner, name: str, part: str) -> None:
        fn = getattr(owner, name)

        def wrapper(*a, **k):
            t = time.perf_counter()
            out = fn(*a, **k)
            seconds[part] += time.perf_counter() - t
            calls[part] += 1
            return out

        setattr(owner, name, wrapper)

    timed(S.FusedStep, "adam", "features' Adam")
    timed(S.FusedStep, "__call__", "kernel")
    timed(T, "_batch_at", "targets")
    timed(TG, "centre_batch", "centre batch")
    timed(TG, "sample_reference", "bicubic lookup")
    timed(torch.optim.Adam, "step", "MLP's Adam")
    parts = ["targets", "centre batch", "bicubic lookup", "kernel", "features' Adam", "MLP's Adam"]

    ts = load_texture_set(specs(args.set))
    w, b, m = (int(v) for v in args.steps.split(":"))
    print(f"machine: {machine()}; {args.set}, {w} + {b} + {m} steps of 128², one thread, the default kernel\n")
    rows = []
    for prof in args.profiles.split(","):
        seconds.clear()
        calls.clear()
        _, cfg = make_config(ts, TrainingOptions(profile=prof, device="cpu", seed=0, threads=1))
        tm = T.train(ts, cfg.with_(preset=_cpu_preset(w, b, m, 128 * 128), preset_name="timed", threads=1),
                     measure_float=False)
        p = tm.phase_seconds
        print(f"| {prof} | targets {p['targets']:.1f} s | warm-up {p['warmup']:.1f} s | encode {p['encode']:.1f} s "
              f"| constrained {p['constrained']:.1f} s ({1000 * p['constrained'] / b:.2f} ms per step) |", flush=True)
        rows.append((prof, {k: 1000 * seconds[k] / max(calls[k], 1) for k in parts}))
    print("\nms per call (every step of the three phases):\n")
    print("| profile | " + " | ".join(parts) + " |\n|---|" + "---:|" * len(parts))
    for prof, ms in rows:
        print(f"| {prof} | " + " | ".join(f"{ms[k]:.2f}" for k in parts) + " |")


if __name__ == "__main__":
    main()
