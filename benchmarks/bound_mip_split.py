"""Issue 31, oracle first: what a layout split by mip could hold, measured before it is built.

BC@R (bench's BC set at the material's resolution R) loses little close up and much at the middle
mips; the neural features the reverse. A material that samples BC@R's own levels for reference
mips below ``split`` and the features from ``split`` on would hold the close-up floor by
construction. This script measures both parts from their own files:

  * BC@R's per-mip error (bcfpipe.layout.classic: every group encoded at R, measured per mip), and
    the bytes of the levels that serve reference mips 0 .. split-1 (level 0 also magnified for
    the reference mips above R);
  * a neural model trained only for s >= split (the trainer's scale draw mapped into
    [split, s_max]) with T_0 = ``--t0`` (the paper's halving pattern below it), exported, its
    per-mip PSNR from the DDS features and fp16 decoder (fit_material), and its bytes;

then prints the split layout's per-mip PSNR (BC@R's below split, the model's from split on), all
mips (MSE averaged over the mips >= 4 texels, as everywhere), its size against BC@R's, and whether
every mip is within 0.5 dB of BC@R. The runtime switch between the two sources is not built:
these are the figures it would have at the reference mips.

  python benchmarks/bound_mip_split.py --set teapot --resolution 1024 --split 3 --t0 256 [--preset standard]
                                       [--features bc6h]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fidelity import specs  # noqa: E402
from common import machine  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", default="teapot")
    ap.add_argument("--resolution", type=int, default=1024, help="R, BC@R's level 0")
    ap.add_argument("--split", type=int, default=3, help="first reference mip the features serve")
    ap.add_argument("--t0", type=int, default=256, help="the features' T_0")
    ap.add_argument("--preset", default="standard")
    ap.add_argument("--features", default="bc6h", help="bc6h or bc7")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    import numpy as np

    import bcfpipe.train.trainer as T
    from bcfpipe.config import TrainingOptions, scaled_profile
    from bcfpipe.export.fit import exported_size, fit_material, make_config
    from bcfpipe.formats.dds import HEADER_BYTES
    from bcfpipe.layout.classic import channel_errors, encode
    from bcfpipe.texset.metrics import psnr_from_mse
    from bcfpipe.texset.texture_set import build_mip_chain, load_texture_set

    ts = load_texture_set(specs(args.set))
    ref = build_mip_chain(ts.data)
    use = [k for k, m in enumerate(ref) if min(m.shape[:2]) >= 4]
    print(f"machine: {machine()}; {args.set} {ts.width}x{ts.height}, R = {args.resolution}, split at mip "
          f"{args.split}, T_0 = {args.t0}, {args.features}, {args.preset}, 1 thread, seed {args.seed}", flush=True)

    groups = encode(ts, args.resolution, ref)
    bc_mse = channel_errors(ts, groups, ref).mean(axis=1)
    bc_bytes = sum(g.size_bytes for g in groups)
    # reference mip k >= d is served by BC@R's level k - d; mips 0 .. d-1 by level 0 magnified
    d = sum(1 for m in ref if max(m.shape[:2]) > args.resolution)
    kept = max(0, args.split - d)  # BC@R levels 0 .. kept-1 serve the mips below split
    top_bytes = sum(HEADER_BYTES + sum(b.nbytes for b, _, _ in g.levels[:max(kept, 1)]) for g in groups)
    del groups

    s_min = float(args.split)
    base = T.StratifiedScale

    class FromSplit(base):  # the preset's draw, mapped into [split, s_max]
        def __call__(self) -> float:
            s = super().__call__()
            return s_min + s * (self.s_max - s_min) / self.s_max

    T.StratifiedScale = FromSplit
    _, cfg = make_config(ts, TrainingOptions(profile="1k", preset=args.preset, device="cpu", seed=args.seed,
                                             layout="neural", features=args.features))
    cfg = cfg.with_(model=replace(cfg.model, resolutions=scaled_profile(args.t0)), threads=1)
    with tempfile.TemporaryDirectory(prefix="bcfpipe-split-") as tmp:
        t = time.perf_counter()
        res, _ = fit_material(ts, Path(tmp) / "m", cfg, f"T0={args.t0}", image_metrics=False)
        wall = time.perf_counter() - t
        nn_bytes = exported_size(Path(tmp) / "m")
    T.StratifiedScale = base
    nn_mse = np.array([10.0 ** (-p / 10.0) for p in res.metrics.psnr_per_mip])

    split_mse = np.where(np.arange(len(bc_mse)) < args.split, bc_mse, nn_mse)
    rows = {"BC@R": bc_mse, f"features (T_0 {args.t0}, s >= {args.split})": nn_mse, "split layout": split_mse}
    n = len(bc_mse)
    print("\n| layout | MiB | " + " | ".join(f"mip {k}" for k in range(n)) + " | all mips |")
    print("|---|---:|" + "---:|" * (n + 1))
    sizes = {"BC@R": bc_bytes, f"features (T_0 {args.t0}, s >= {args.split})": nn_bytes,
             "split layout": top_bytes + nn_bytes}
    for name, mse in rows.items():
        allm = psnr_from_mse(float(np.mean([mse[k] for k in use])))
        print(f"| {name} | {sizes[name] / 2**20:.2f} | " + " | ".join(f"{psnr_from_mse(float(m)):.1f}" for m in mse)
              + f" | **{allm:.2f}** |")
    margin = [psnr_from_mse(float(a)) - psnr_from_mse(float(b)) for a, b in zip(split_mse, bc_mse)]
    worst = min(use, key=lambda k: margin[k])  # the floor counts the mips of >= 4 texels, as the layout rule
    print(f"\nsplit layout: {(top_bytes + nn_bytes) / bc_bytes:.3f}x BC@R's bytes (BC@R levels < {max(kept, 1)}: "
          f"{top_bytes / 2**20:.2f} MiB, features {nn_bytes / 2**20:.2f} MiB); worst margin against BC@R "
          f"{margin[worst]:+.2f} dB at mip {worst} (floor: -0.5, mips of >= 4 texels); the features trained in "
          f"{res.train_seconds:.0f} s ({wall:.0f} s with export and measurement)")


if __name__ == "__main__":
    main()
