"""Issue 30 on a CUDA GPU: the torch training path's samples/s, a whole `standard` training, and
where the method saturates once samples are cheap.

Sections, in this order; each is skipped when the time left (``--budget``) cannot hold it, as
predicted from the step times measured first, so a lent machine's minutes are never overrun:

  throughput  warm-up and constrained samples/s at the CPU presets' batch (128²) and the paper's
              (512²), the teapot at 1k; and what the `paper` preset's 206k steps would take
  standard    the teapot at 1k, `standard`, exported and measured from the files
  saturation  teapot and brick at 0.5k, the `standard` schedule's samples ×k: k = 1 as on the CPU
              (128² batch), k = 10 and 30 as batch 512² (16×) with steps ×k/16 (same decays)
  bc7         the teapot at 1k at 10× the standard samples, bc6h and bc7 (issue 29: is mip 1's gap
              to BC a training budget?)
  runs        any list of ``set:profile:features:k[:batch]`` (``--runs``): the standard schedule's
              samples ×k at that batch (default 128², so ×k the steps)

Every quality figure is from the exported files (DDS features, fp16 decoder through onnxruntime).
Rows print as they finish and go to ``--jsonl``.

  python benchmarks/bench_cuda.py [--budget 480] [--jsonl results.jsonl] [--device cuda]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import traceback
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, psnr_cells, specs  # noqa: E402

STD_WARM, STD_CONSTRAINED, STD_FINETUNE, STD_BATCH = 800, 4000, 300, 128 * 128
BIG = 512 * 512


class Budget:
    def __init__(self, seconds: float):
        self.end = time.perf_counter() + seconds

    def left(self) -> float:
        return self.end - time.perf_counter()


def schedule(k: float, batch: int):
    """The standard schedule's samples ×k at ``batch`` (steps scaled so samples match; decays follow)."""
    from bcfpipe.config import _cpu_preset

    f = k * STD_BATCH / batch
    return _cpu_preset(round(STD_WARM * f), round(STD_CONSTRAINED * f), STD_FINETUNE, batch)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=float, default=480.0, help="seconds this script may run")
    ap.add_argument("--jsonl", default=None)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--sections", default="throughput,standard,saturation,bc7")
    ap.add_argument("--saturation", default="1:teapot,1:brick,30:teapot,30:brick,10:teapot,10:brick",
                    help="k:set[:batch] of the saturation section, in order (batch: 128² at k = 1, else 512²)")
    ap.add_argument("--runs", default="teapot:1k:bc7:1,teapot:1k:bc7:3",
                    help="set:profile:features:k[:batch] of the runs section, in order")
    ap.add_argument("--bc7-formats", default="bc7,bc6h", help="feature formats of the bc7 section, in order")
    ap.add_argument("--keep", default=None, help="keep the `standard` section's exported material here (for bench_decode)")
    ap.add_argument("--scale", type=float, default=1.0, help="scale every step count (a quick CPU check: 0.02)")
    args = ap.parse_args()

    import torch

    from bcfpipe.config import PRESETS, TrainingOptions, _cpu_preset
    from bcfpipe.export.material import train_material, make_config
    from bcfpipe.texset.texture_set import load_texture_set
    from bcfpipe.train.trainer import train

    budget = Budget(args.budget)
    sections = set(args.sections.split(","))
    out = open(args.jsonl, "a") if args.jsonl else None

    def emit(row: dict) -> None:
        if out:
            out.write(json.dumps(row) + "\n")
            out.flush()

    def scaled(p):
        if args.scale == 1.0:
            return p
        s = lambda ph: replace(ph, steps=max(2, round(ph.steps * args.scale)))  # noqa: E731
        return replace(p, warmup=s(p.warmup), constrained=s(p.constrained), finetune=s(p.finetune))

    print(f"machine: {machine()}; device {args.device}", flush=True)
    sets = {}

    def texture_set(name):
        if name not in sets:
            sets[name] = load_texture_set(specs(name))
        return sets[name]

    def config(name, profile, preset, label, features="bc6h"):
        _, cfg = make_config(texture_set(name), TrainingOptions(profile=profile, device=args.device, seed=0,
                                                                features=features))
        return cfg.with_(preset=scaled(preset), preset_name=label)

    # Step times: {batch: (warm-up s/step, constrained s/step, fine-tune s/step)}; the first run
    # also pays CUDA's start-up, so it is repeated.
    step = {}
    overhead = 30.0  # encode + quantize + export + evaluate, until measured

    def measure(batch, steps):
        p = _cpu_preset(steps, steps, steps, batch)
        tm = train(texture_set("teapot"), config("teapot", "1k", p, f"probe {batch}"), measure_float=False)
        ps, n = tm.phase_seconds, tm.phase_samples
        step[batch] = tuple(ps[ph] / max(1, p.warmup.steps if ph == "warmup" else p.constrained.steps
                                          if ph == "constrained" else p.finetune.steps)
                            for ph in ("warmup", "constrained", "finetune"))
        return ps, n

    def predict(p) -> float:
        tw, tc, tf = step.get(p.batch) or step[max(step)]
        return p.warmup.steps * tw + p.constrained.steps * tc + p.finetune.steps * tf + overhead

    t = time.perf_counter()
    measure(64 * 64, max(2, round(20 * args.scale)))  # start-up: kernels, allocator, onnx
    print(f"start-up run: {time.perf_counter() - t:.1f} s", flush=True)

    if "throughput" in sections:
        print("\n| batch | warm-up samples/s | constrained samples/s | fine-tune steps/s |\n|---:|---:|---:|---:|")
        for batch, steps in ((STD_BATCH, 200), (BIG, 100)):
            ps, n = measure(batch, max(2, round(steps * args.scale)))
            rate = {ph: n.get(ph, 0) / ps[ph] for ph in ("warmup", "constrained")}
            print(f"| {batch} | {rate['warmup']:,.0f} | {rate['constrained']:,.0f} | {1 / step[batch][2]:.0f} |",
                  flush=True)
            emit({"section": "throughput", "batch": batch, "samples_per_s": rate, "step_seconds": step[batch]})
        paper = PRESETS["paper"]
        est = predict(paper) - overhead
        print(f"the paper preset ({paper.warmup.steps} + {paper.constrained.steps} + {paper.finetune.steps} steps "
              f"of 512²) at these rates: {est / 60:.1f} min of training", flush=True)
        emit({"section": "paper_estimate", "train_seconds": est})
    else:
        measure(STD_BATCH, max(2, round(50 * args.scale)))
        measure(BIG, max(2, round(30 * args.scale)))

    def fit(name, profile, preset, label, features="bc6h", keep=None):
        need = predict(scaled(preset))
        if need > budget.left():
            print(f"skipped {name} {profile} {label} {features}: predicted {need:.0f} s, {budget.left():.0f} s left",
                  flush=True)
            return None
        nonlocal overhead
        cfg = config(name, profile, preset, label, features)
        with tempfile.TemporaryDirectory(prefix="bcfpipe-cuda-") as tmp:
            t = time.perf_counter()
            try:
                res, _ = train_material(texture_set(name), Path(keep or Path(tmp) / "m"), cfg, profile)
            except Exception:  # a broken device path must not cost the rest of the lease
                traceback.print_exc()
                return None
            wall = time.perf_counter() - t
        phases = res.phase_seconds
        overhead = max(30.0, wall - sum(phases.get(ph, 0.0) for ph in ("warmup", "constrained", "finetune")))
        m = res.metrics
        p = scaled(preset)
        samples = (p.warmup.steps + p.constrained.steps) * p.batch
        row = {"set": name, "profile": profile, "label": label, "features": features, "samples": samples,
               "psnr_per_mip": m.psnr_per_mip, "psnr": m.psnr, "ssim": m.ssim, "size_bytes": res.size_bytes,
               "train_seconds": res.train_seconds, "wall_seconds": wall, "phase_seconds": phases}
        emit(row)
        print(f"| {name} | {profile} | {label} | {features} | {samples:.2e} | {psnr_cells(m.psnr_per_mip, m.psnr)} "
              f"| {res.train_seconds:.0f} s ({wall:.0f} s with export) |", flush=True)
        return row

    head = "\n| set | profile | schedule | features | samples | per-mip PSNR | | | | | | | | | | | all mips | train |"
    for section in args.sections.split(","):  # in the order given
        if section == "standard":
            print(head, flush=True)
            fit("teapot", "1k", PRESETS["standard"], "standard", keep=args.keep)
        elif section == "saturation":
            print(head, flush=True)
            for pair in args.saturation.split(","):
                k, name, *batch = pair.split(":")
                b = int(batch[0]) if batch else STD_BATCH if int(k) == 1 else BIG
                fit(name, "0.5k", schedule(int(k), b), f"standard x{k} @{b}")
        elif section == "runs":
            print(head, flush=True)
            for run in args.runs.split(","):
                name, profile, features, k, *batch = run.split(":")
                b = int(batch[0]) if batch else STD_BATCH
                fit(name, profile, schedule(float(k), b), f"standard x{k} @{b}", features)
        elif section == "bc7":
            print(head, flush=True)
            for features in args.bc7_formats.split(","):
                fit("teapot", "1k", schedule(10, BIG), "standard x10", features,
                    keep=f"{args.keep}_{features}" if args.keep else None)
    print(f"\n{budget.left():.0f} s of the budget left; torch {torch.__version__}", flush=True)


if __name__ == "__main__":
    main()
