"""Quality / size / time of BCf presets against BC1 and ASTC 12x12 on the teapot material.

The teapot set is the diffuse rgb + ARM rgb JPEGs (2048^2, 6 channels). Every row is measured with
the same metric code (bcfpipe.metrics) against the same 2048^2 reference mip chain; BCf rows are
measured from the exported files (BC6H DDS + fp16 weights through onnxruntime).

  python benchmarks/bench_teapot.py [--presets draft,fast,standard] [--profile 1k] [--out /tmp/bench]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, machine, specs  # noqa: E402

from bcfpipe.texset.baselines import encode_texture_set_baseline  # noqa: E402
from bcfpipe.config import TrainingOptions  # noqa: E402
from bcfpipe.export.material import train_material, make_config  # noqa: E402
from bcfpipe.texset.metrics import compute_metrics  # noqa: E402
from bcfpipe.texset.texture_set import build_mip_chain, load_texture_set  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_options(ap, presets="draft,fast,standard", profile="1k", device="cpu")
    ap.add_argument("--threads", type=int, default=1, help="torch threads per training (1: see the throughput bench)")
    ap.add_argument("--out", type=Path, default=Path("/tmp/bcf_bench_teapot"))
    ap.add_argument("--no-baselines", action="store_true")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    ts = load_texture_set(specs("teapot"))
    ref = build_mip_chain(ts.data)
    rows = []
    if not a.no_baselines:
        for codec, res in (("bc", 1024), ("bc", 2048), ("astc", 1024), ("astc", 2048)):
            t0 = time.perf_counter()
            dec, size = encode_texture_set_baseline(ts, codec, res, ref_mips=ref)
            m = compute_metrics(ref, dec, ts.channels)
            name = f"BC1@{res} (quicktex level 18)" if codec == "bc" else f"ASTC 12x12@{res} (astcenc -thorough)"
            rows.append(dict(method=name, psnr=m.psnr, ssim=m.ssim, flip=m.flip, size_bytes=size,
                             seconds=time.perf_counter() - t0, per_mip=m.psnr_per_mip))
            print(f"{name}: {m.psnr:.2f} dB", file=sys.stderr, flush=True)
    for preset in a.presets.split(","):
        name, cfg = make_config(ts, TrainingOptions(profile=a.profile, preset=preset, device=a.device,
                                                    threads=a.threads))
        t0 = time.perf_counter()
        res, _ = train_material(ts, a.out / preset, cfg, name)
        m = res.metrics
        rows.append(dict(method=f"BCf {name} {preset}", psnr=m.psnr, ssim=m.ssim, flip=m.flip,
                         size_bytes=res.size_bytes, seconds=time.perf_counter() - t0, train_seconds=res.train_seconds,
                         float_psnr=res.float_metrics.psnr, per_mip=m.psnr_per_mip, steps=cfg.preset.total_steps,
                         batch=cfg.preset.batch))
        print(f"{preset}: {m.psnr:.2f} dB (float {res.float_metrics.psnr:.2f}) in {res.train_seconds:.0f} s",
              file=sys.stderr, flush=True)
    bc1 = next((r for r in rows if r["method"].startswith("BC1@1024")), None)
    print(f"# Teapot (2048^2 diffuse + ARM, 6 ch), {machine()}\n")
    print("| method | PSNR all mips (dB) | vs BC1@1024 | SSIM | FLIP | size (MiB) | time (s) | float PSNR before quant. |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        gain = f"{r['psnr'] - bc1['psnr']:+.2f}" if bc1 else "-"
        fp = f"{r['float_psnr']:.2f} ({r['float_psnr'] - r['psnr']:.2f} lost)" if "float_psnr" in r else "-"
        print(f"| {r['method']} | {r['psnr']:.2f} | {gain} | {r['ssim']:.4f} | {r['flip']:.4f} | "
              f"{r['size_bytes'] / 2**20:.2f} | {r['seconds']:.0f} | {fp} |")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
