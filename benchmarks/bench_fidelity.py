"""Issue #9: per-mip fidelity of BCf against BC@1024 on the teapot and brick sets, before/after.

Every BCf row is trained, exported and measured from the exported files (BC6H DDS decoded by
bcfpipe.bc6h.decode, fp16 decoder through onnxruntime), against the same 2048² reference chain as
the BC row. BC@1024: BC1 for colour and packed maps, BC4 for a lone scalar, BC5 for normals, every
mip encoded, level 0 magnified for reference mip 0 (bcfpipe.baselines).

Variants run side by side (``--parallel``, one torch thread each) so load hits them alike:
  before    session 2's `standard`: random start, s uniform, 800 + 4000 + 300 steps of 128²
  <preset>  a preset of bcfpipe.config as it is now (draft, fast, standard, paper)

  python benchmarks/bench_fidelity.py [--sets teapot,brick] [--variants before,standard]
                                      [--profile 1k] [--parallel 2] [--json out.json]
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, machine, psnr_cells, specs, write_json  # noqa: E402


def variant_config(ts, variant: str, profile: str, seed: int):
    from bcfpipe.config import PRESETS, TrainingOptions, _cpu_preset
    from bcfpipe.export.material import make_config

    if variant == "before":
        name, cfg = make_config(ts, TrainingOptions(profile=profile, preset="standard", device="cpu", seed=seed))
        legacy = replace(_cpu_preset(800, 4000, 300, 128 * 128), lod_power=1.0, centre_targets=False)
        return name, cfg.with_(preset=legacy, preset_name="before", feature_init="random")
    if variant not in PRESETS:
        raise SystemExit(f"unknown variant {variant!r}: before or one of {', '.join(PRESETS)}")
    return make_config(ts, TrainingOptions(profile=profile, preset=variant, device="cpu", seed=seed))


def run_variant(set_name: str, variant: str, profile: str, seed: int, out: str) -> dict:
    from bcfpipe.export.material import train_material
    from bcfpipe.texset.texture_set import load_texture_set

    ts = load_texture_set(specs(set_name))
    name, cfg = variant_config(ts, variant, profile, seed)
    t0 = time.perf_counter()
    res, tm = train_material(ts, Path(out) / f"{set_name}_{variant}", cfg, name)
    m = res.metrics
    per_phase = {p: res.phase_samples.get(p, 0) / res.phase_seconds[p]
                 for p in ("warmup", "constrained", "finetune") if res.phase_seconds.get(p)}
    return dict(set=set_name, method=f"BCf {name} {variant}", psnr=m.psnr, ssim=m.ssim, flip=m.flip,
                per_mip=m.psnr_per_mip, size_bytes=res.size_bytes, train_seconds=res.train_seconds,
                wall_seconds=time.perf_counter() - t0, float_psnr=res.float_metrics.psnr,
                samples_per_second=per_phase, phase_seconds=res.phase_seconds)


def baseline(set_name: str) -> dict:
    from bcfpipe.texset.baselines import encode_texture_set_baseline
    from bcfpipe.texset.metrics import compute_metrics
    from bcfpipe.texset.texture_set import build_mip_chain, load_texture_set

    ts = load_texture_set(specs(set_name))
    ref = build_mip_chain(ts.data)
    dec, size = encode_texture_set_baseline(ts, "bc", 1024, ref_mips=ref)
    m = compute_metrics(ref, dec, ts.channels)
    return dict(set=set_name, method="BC@1024", psnr=m.psnr, ssim=m.ssim, flip=m.flip, per_mip=m.psnr_per_mip,
                size_bytes=size)


def table(rows: list[dict], bc: dict) -> str:
    n = len(bc["per_mip"])
    lines = ["| method | " + " | ".join(str(k) for k in range(n)) + " | all mips | vs BC | SSIM mip 0 | MiB | train s |",
             "|---|" + "---:|" * (n + 5)]
    for r in rows:
        train = f"{r['train_seconds']:.0f}" if "train_seconds" in r else "-"
        lines.append(f"| {r['method']} | {psnr_cells(r['per_mip'])} | {r['psnr']:.2f} | {r['psnr'] - bc['psnr']:+.2f} "
                     f"| {r['ssim']:.4f} | {r['size_bytes'] / 2**20:.2f} | {train} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_options(ap, sets="teapot,brick", variants="before,standard", profile="1k", seed=0)
    ap.add_argument("--parallel", type=int, default=2, help="variants trained at once (1 torch thread each)")
    ap.add_argument("--out", type=Path, default=Path("/tmp/bcf_bench_fidelity"))
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    sets, variants = a.sets.split(","), a.variants.split(",")
    jobs = [(s, v) for v in variants for s in sets]
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=a.parallel, mp_context=ctx) as pool:
        futs = [pool.submit(run_variant, s, v, a.profile, a.seed, str(a.out)) for s, v in jobs]
        bcs = {s: baseline(s) for s in sets}
        rows = []
        for (s, v), f in zip(jobs, futs):
            r = f.result()
            print(f"{s} {v}: {r['psnr']:.2f} dB, train {r['train_seconds']:.0f} s", file=sys.stderr, flush=True)
            rows.append(r)
    print(f"# Per-mip PSNR (dB) against BC@1024, {machine()}, profile {a.profile}\n")
    for s in sets:
        print(f"## {s}\n")
        print(table([bcs[s]] + [r for r in rows if r["set"] == s], bcs[s]))
        print("\nsamples/s per phase:\n")
        print("| method | warmup | constrained | finetune | wall s |\n|---|---:|---:|---:|---:|")
        for r in rows:
            if r["set"] == s:
                sp = r["samples_per_second"]
                print(f"| {r['method']} | " + " | ".join(f"{sp.get(p, 0):,.0f}" for p in ("warmup", "constrained", "finetune"))
                      + f" | {r['wall_seconds']:.0f} |")
        print()
    write_json(a.json, indent=1, baselines=bcs, rows=rows)


if __name__ == "__main__":
    main()
