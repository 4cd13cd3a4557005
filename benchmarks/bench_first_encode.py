"""Issue 30: the trainer's first encode, refined (the encoders' defaults) against quick (its setting).

Trains one set at one profile and preset once per start named, side by side (one process, one
thread each): `refined`, phase 2's first encode at the encoders' full refinement (BC6H: four shapes
refined, two rounds, a window of ±4 codes; BC7: four rounds); `quick`, the trainer's start
(`bcfpipe.model.features._BC6H_START`, `_BC7_START_ROUNDS`; BC6H compiled, bc6h/quick.cpp);
`quick-torch`, the same BC6H start in the torch encoder. Prints, from the exported files, the PSNR
over all mips and at mips 0 and 1, and the encode phase's seconds.

  python benchmarks/bench_first_encode.py --set teapot --profile 1k --preset draft [--features bc7]
                                          [--starts refined,quick,quick-torch]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, machine, specs  # noqa: E402

REFINED = {"bc6h": dict(refine_top=4, keep=2, rounds=2, window=4), "bc7": 4}


def one(args) -> None:
    """Child: train with the named start and print the result as JSON."""
    import bcfpipe.model.features as F
    from bcfpipe.config import TrainingOptions
    from bcfpipe.export.material import train_material, make_config
    from bcfpipe.texset.texture_set import load_texture_set

    if args.child == "refined":
        F._BC6H_START = REFINED["bc6h"]
        F._BC7_START_ROUNDS = REFINED["bc7"]
    F._BC6H_NATIVE = args.child != "quick-torch"
    ts = load_texture_set(specs(args.set))
    _, cfg = make_config(ts, TrainingOptions(profile=args.profile, preset=args.preset, features=args.features,
                                             device="cpu", seed=args.seed, threads=1))
    with tempfile.TemporaryDirectory(prefix="bcfpipe-encode-") as tmp:
        res, _ = train_material(ts, Path(tmp) / "m", cfg, args.profile)
    print(json.dumps({"psnr": res.metrics.psnr, "mips": list(res.metrics.psnr_per_mip[:2]),
                      "encode": res.phase_seconds.get("encode"), "train": res.train_seconds}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(ap, set="teapot", profile="1k", preset="draft", features="bc6h", seed=0, starts="refined,quick")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return one(args)
    print(f"machine: {machine()}; {args.set}, profile {args.profile}, {args.preset}, {args.features}, seed "
          f"{args.seed}, one thread each, side by side", flush=True)
    base = [sys.executable, __file__, "--set", args.set, "--profile", args.profile, "--preset", args.preset,
            "--features", args.features, "--seed", str(args.seed), "--child"]
    procs = {k: subprocess.Popen(base + [k], stdout=subprocess.PIPE, text=True) for k in args.starts.split(",")}
    print("\n| start | all mips | mip 0 | mip 1 | encode | train |\n|---|---:|---:|---:|---:|---:|")
    for k, p in procs.items():
        out, _ = p.communicate()
        if p.returncode:
            raise SystemExit(f"{k}: exited {p.returncode}")
        r = json.loads(out.strip().splitlines()[-1])
        print(f"| {k} | {r['psnr']:.2f} | {r['mips'][0]:.1f} | {r['mips'][1]:.1f} | {r['encode']:.1f} s "
              f"| {r['train']:.0f} s |")


if __name__ == "__main__":
    main()
