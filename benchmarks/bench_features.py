"""Issue 29: BC6H against BC7 feature textures, measured from the exported files.

For each set and profile, trains `--features bc6h` and `--features bc7` side by side (two
processes, one torch thread each, started together so both see the same load), then reports from
each exported folder: PSNR at every reference mip and over all mips (`bcfpipe train --json`, which
decodes the exported DDS and weights through onnxruntime), SSIM, the files' size and the training
time. BC@1024 (bcfpipe bench's BC set at 1024²) is given per mip for comparison. Every material is
all-neural (`--layout neural`): the formats are compared, not the layouts a build would choose.
`bc7` trains what `--features bc7` trains by default (`--t0 pca` since MODEL_FORMAT 11).

  python benchmarks/bench_features.py [--sets teapot,brick] [--profiles 1k,0.5k] [--preset standard]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, bc_per_mip, machine, mip_columns, psnr_cells, spec_args, specs  # noqa: E402

FORMATS = ("bc6h", "bc7")


def run_pair(name: str, profile: str, preset: str, seed: int, root: Path) -> dict[str, dict]:
    procs = {}
    for f in FORMATS:
        out = root / f"{name}-{profile}-{f}"
        procs[f] = subprocess.Popen([sys.executable, "-m", "bcfpipe", "train", *spec_args(name), "-o", str(out),
                                     "--profile", profile, "--quality", preset, "--seed", str(seed), "--features", f,
                                     "--threads", "1", "--layout", "neural", "--json"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                    text=True)
    res = {}
    for f, p in procs.items():
        stdout, _ = p.communicate()
        if p.returncode != 0:
            raise SystemExit(f"{name} {profile} {f}: bcfpipe train exited {p.returncode}")
        res[f] = json.loads(stdout)
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(ap, sets="teapot,brick", profiles="1k,0.5k", preset="standard", seed=0)
    args = ap.parse_args()
    from bcfpipe.texset.texture_set import load_texture_set

    print(f"machine: {machine()}; preset {args.preset}, seed {args.seed}, 1 thread per training, the two "
          "formats trained side by side")
    with tempfile.TemporaryDirectory(prefix="bcfpipe-features-") as tmp:
        for name in args.sets.split(","):
            bc = bc_per_mip(load_texture_set(specs(name)), 1024)
            n = len(bc)
            print(f"\n### {name}\n")
            print("| method | " + mip_columns(n) + " | all mips | SSIM mip 0 | quantization loss | size | train |")
            print("|---|" + "---:|" * (n + 5))
            print("| BC@1024 | " + psnr_cells(bc) + " | | | | | |")
            for profile in args.profiles.split(","):
                res = run_pair(name, profile, args.preset, args.seed, Path(tmp))
                for f in FORMATS:
                    r = res[f]
                    per = r["metrics"]["psnr_per_mip"]
                    print(f"| {profile} {f} | {psnr_cells(per, r['psnr'])} | {r['ssim']:.3f} "
                          f"| {r.get('quantization_loss_db', float('nan')):.2f} dB "
                          f"| {r['size_bytes'] / 2**20:.2f} MiB "
                          f"| {r['train_seconds']:.0f} s |", flush=True)


if __name__ == "__main__":
    main()
