"""Issue 31: each material's layout chosen by measured rate-distortion against BC@R.

For one set at R = 1024 (`--profile 1k`): BC@R measured per channel, the probe trained on all
channels, every candidate layout (classic groups × profiles) with its figures and basis, the
choice, the model trained for it, and the final choice among measured layouts with its per-mip
margin against BC@R. Every figure is from exported files (DDS features and the fp16 decoder through
onnxruntime; the classic groups' blocks through quicktex's decoder). Run one process per set to use
two cores.

  python benchmarks/bench_layout.py --set teapot [--match-bc] [--kernel fused] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fidelity import specs  # noqa: E402
from common import machine  # noqa: E402


def row(c, bc, mark="", match_bc=False):
    from bcfpipe.layout.choose import admissible

    why = admissible(c, bc, match_bc) or "ok"
    return (f"| {mark}{c.label} | {c.basis} | {c.size_bytes / 2**20:.2f} | "
            + " | ".join(f"{v:.1f}" for v in c.psnr_per_mip) + f" | **{c.psnr:.2f}** | {why} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", default="teapot")
    ap.add_argument("--profile", default="1k")
    ap.add_argument("--preset", default="standard")
    ap.add_argument("--match-bc", action="store_true")
    ap.add_argument("--kernel", default="fused")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()

    from bcfpipe.config import PROFILES, TrainingOptions
    from bcfpipe.layout.fit import fit_layout
    from bcfpipe.texset.texture_set import load_texture_set

    ts = load_texture_set(specs(args.set))
    r = PROFILES[args.profile][0]
    opts = TrainingOptions(profile=args.profile, preset=args.preset, device="cpu", seed=0, threads=1,
                           kernel=args.kernel)
    print(f"machine: {machine()}; {args.set} {ts.width}x{ts.height}, --profile {args.profile} (R = {r}), "
          f"{args.preset}, --kernel {args.kernel}, 1 thread{', --match-bc' if args.match_bc else ''}", flush=True)
    t = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bcfpipe-layout-") as tmp:
        fit = fit_layout(ts, tmp, opts, r, match_bc=args.match_bc, log=lambda s: print("  " + s, flush=True))
    n = len(fit.decision.bc.mse_per_mip)
    head = "| layout | basis | MiB | " + " | ".join(f"mip {k}" for k in range(n)) + " | all mips | admissible |"
    sep = "|---|---|---:|" + "---:|" * (n + 1) + "---|"
    print("\nCandidates (the first choice is made here):\n\n" + head + "\n" + sep)
    bc = fit.first.bc
    for c in sorted(fit.first.candidates, key=lambda c: -c.psnr):
        print(row(c, bc, "→ " if c is fit.first.chosen else "", args.match_bc))
    print("\nMeasured layouts (the final choice):\n\n" + head + "\n" + sep)
    for c in fit.decision.candidates:
        print(row(c, bc, "→ " if c is fit.decision.chosen else "", args.match_bc))
    ch = fit.decision.chosen
    print(f"\nchosen: {ch.label}: {fit.decision.reason}")
    print("margin against BC@R per mip (dB): " + " ".join(f"{v:+.1f}" for v in ch.margins(bc)))
    print(f"probe and second model {fit.train_seconds:.0f} s with export and measuring (probe training "
          f"{fit.probe.train_seconds:.0f} s), "
          f"{time.perf_counter() - t:.0f} s in all", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({"set": args.set, "decision": fit.decision.to_json(),
                                               "first": fit.first.to_json(), "train_seconds": fit.train_seconds,
                                               "seconds": fit.seconds}, indent=1))


if __name__ == "__main__":
    main()
