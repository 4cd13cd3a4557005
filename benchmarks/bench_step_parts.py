"""Issue 30: where a training's time goes as T_0 grows: the phases, and the features' Adam per step.

Trains one set at each profile named with a short schedule (200 + 600 + 10 steps of 128² by
default) on one thread with the default kernel, timing `FusedStep.adam` (the feature levels' Adam,
clamp and gradient zeroing) around every call, and prints the phases' seconds and Adam's
milliseconds per step. The kernel's own work per sample does not depend on the profile; Adam's and
the first encode's grow with the blocks.

  python benchmarks/bench_step_parts.py --set teapot --profiles 1k,2k [--steps 200:600:10]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fidelity import specs  # noqa: E402
from common import machine  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", default="teapot")
    ap.add_argument("--profiles", default="1k,2k")
    ap.add_argument("--steps", default="200:600:10", help="warm-up:constrained:finetune steps")
    args = ap.parse_args()

    import bcfpipe.train.fused.step as S
    from bcfpipe.config import TrainingOptions, _cpu_preset
    from bcfpipe.export.fit import make_config
    from bcfpipe.texset.texture_set import load_texture_set
    from bcfpipe.train.trainer import train

    acc = {"s": 0.0, "n": 0}
    adam = S.FusedStep.adam

    def timed(self, *a, **k):
        t = time.perf_counter()
        adam(self, *a, **k)
        acc["s"] += time.perf_counter() - t
        acc["n"] += 1

    S.FusedStep.adam = timed
    ts = load_texture_set(specs(args.set))
    w, b, m = (int(v) for v in args.steps.split(":"))
    print(f"machine: {machine()}; {args.set}, {w} + {b} + {m} steps of 128², one thread, the default kernel\n")
    print("| profile | targets | warm-up | encode | constrained | Adam per step |\n|---|---:|---:|---:|---:|---:|")
    for prof in args.profiles.split(","):
        acc.update(s=0.0, n=0)
        _, cfg = make_config(ts, TrainingOptions(profile=prof, device="cpu", seed=0, threads=1))
        tm = train(ts, cfg.with_(preset=_cpu_preset(w, b, m, 128 * 128), preset_name="timed", threads=1))
        p = tm.phase_seconds
        print(f"| {prof} | {p['targets']:.1f} s | {p['warmup']:.1f} s | {p['encode']:.1f} s | {p['constrained']:.1f} s "
              f"| {1000 * acc['s'] / max(acc['n'], 1):.1f} ms |", flush=True)


if __name__ == "__main__":
    main()
