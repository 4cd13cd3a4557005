"""Issue 31, oracle first: what a layout split by mip could hold, measured before it is built.

BC@R (bench's BC set at the material's resolution R) loses little close up and much at the middle
mips; the neural features the reverse. A material that samples BC@R's own levels for reference
mips below ``split`` and the features from ``split`` on would hold the close-up floor by
construction. This script measures both parts from their own files:

  * BC@R's per-mip error (bcfpipe.layout.classic: every group encoded at R, measured per mip), and
    the bytes of the levels that serve reference mips 0 .. split-1 (level 0 also magnified for
    the reference mips above R);
  * a neural model trained only for s >= split (ModelConfig.split: the trainer's scale draw in
    [split, s_max]) with T_0 = ``--t0`` (the paper's halving pattern below it) or ``--resolutions``,
    exported, its per-mip PSNR from the DDS features and fp16 decoder (train_material), and its bytes;
  * the two written as one mip-split material folder (bcfpipe.layout.export.export_split: BC@R's
    levels for the mips below split as C_i.dds, material.json format 4 with ``split``), decoded
    back from its files (bcfpipe.export.writer.decode_mips) and sized as a renderer loads it;

then prints the split layout's per-mip PSNR, all mips (MSE averaged over the mips >= 4 texels, as
everywhere), its size against BC@R's, and its worst margin against BC@R (the floor is -0.5 dB).
`--layout auto` weighs such splits itself (bcfpipe.layout.kinds.split_candidates); this script
measures any one split and feature size by hand.

  python benchmarks/bound_mip_split.py --set teapot --resolution 1024 --split 3 --t0 256 [--resolutions 128,128,128,64] [--hidden H] [--preset standard]
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
from common import machine, mip_columns, psnr_cells, specs  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", default="teapot")
    ap.add_argument("--resolution", type=int, default=1024, help="R, BC@R's level 0")
    ap.add_argument("--split", type=int, default=3, help="first reference mip the features serve")
    ap.add_argument("--t0", type=int, default=256, help="the features' T_0 (T_1..T_3 halving from it)")
    ap.add_argument("--resolutions", default="", help="T_0,T_1,T_2,T_3 instead of --t0's halving pattern, e.g. 128,128,128,64")
    ap.add_argument("--hidden", type=int, default=0, help="the decoder's hidden units (default: the preset's)")
    ap.add_argument("--preset", default="standard")
    ap.add_argument("--features", default="bc6h", help="bc6h or bc7")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    import numpy as np

    from bcfpipe.config import TrainingOptions, scaled_profile
    from bcfpipe.export import writer as E
    from bcfpipe.export.material import FIGURES, exported_size, train_material, make_config
    from bcfpipe.layout.classic import channel_errors, encode, split_levels
    from bcfpipe.layout.export import export_split
    from bcfpipe.texset.metrics import mse_per_channel, psnr_from_mse
    from bcfpipe.texset.texture_set import build_mip_chain, load_texture_set

    ts = load_texture_set(specs(args.set))
    ref = build_mip_chain(ts.data)
    use = [k for k, m in enumerate(ref) if min(m.shape[:2]) >= 4]
    res_t = tuple(int(v) for v in args.resolutions.split(",")) if args.resolutions else scaled_profile(args.t0)
    print(f"machine: {machine()}; {args.set} {ts.width}x{ts.height}, R = {args.resolution}, split at mip "
          f"{args.split}, T = {res_t}, hidden {args.hidden or 'default'}, {args.features}, {args.preset}, "
          f"1 thread, seed {args.seed}", flush=True)

    groups = encode(ts, args.resolution, ref)
    bc_mse = channel_errors(ts, groups, ref).mean(axis=1)
    bc_bytes = sum(g.size_bytes for g in groups)
    for g in groups:
        g.decoded = []

    _, cfg = make_config(ts, TrainingOptions(profile="1k", preset=args.preset, device="cpu", seed=args.seed,
                                             layout="neural", features=args.features))
    model = replace(cfg.model, resolutions=res_t, split=args.split, **({"hidden": args.hidden} if args.hidden else {}))
    cfg = cfg.with_(model=model, threads=1)
    with tempfile.TemporaryDirectory(prefix="bcfpipe-split-") as tmp:
        t = time.perf_counter()
        res, _ = train_material(ts, Path(tmp) / "m", cfg, f"T={res_t}", measure=FIGURES)
        wall = time.perf_counter() - t
        nn_bytes = exported_size(Path(tmp) / "m")
        out = export_split(groups, Path(tmp) / "m", ts, Path(tmp) / "split", args.split, args.resolution)
        split_bytes = exported_size(out)
        dec = E.decode_mips(E.load(out), [m.shape[:2] for m in ref])  # the split folder, as a reader decodes it
        split_mse = mse_per_channel(ref, dec, ts.channels).mean(axis=1)
    nn_mse = np.array([10.0 ** (-p / 10.0) for p in res.metrics.psnr_per_mip])
    keep = split_levels(args.split, args.resolution, max(ts.width, ts.height))

    rows = {"BC@R": (bc_mse, bc_bytes), f"features (T {res_t}, s >= {args.split})": (nn_mse, nn_bytes),
            "split layout (exported, decoded)": (split_mse, split_bytes)}
    n = len(bc_mse)
    print("\n| layout | MiB | " + mip_columns(n) + " | all mips |")
    print("|---|---:|" + "---:|" * (n + 1))
    for name, (mse, size) in rows.items():
        allm = psnr_from_mse(float(np.mean([mse[k] for k in use])))
        print(f"| {name} | {size / 2**20:.3f} | {psnr_cells([psnr_from_mse(float(m)) for m in mse], allm)} |")
    margin = [psnr_from_mse(float(a)) - psnr_from_mse(float(b)) for a, b in zip(split_mse, bc_mse)]
    worst = min(use, key=lambda k: margin[k])  # the floor counts the mips of >= 4 texels, as the layout rule
    gain = psnr_from_mse(float(np.mean([split_mse[k] for k in use]))) - psnr_from_mse(float(np.mean([bc_mse[k] for k in use])))
    print(f"\nsplit layout: {split_bytes} bytes, {split_bytes / bc_bytes:.3f}x BC@R's {bc_bytes} (BC@R levels "
          f"0..{keep - 1} and the features); all mips {gain:+.2f} dB against BC@R; worst margin {margin[worst]:+.2f} dB "
          f"at mip {worst} (floor: -0.5, mips of >= 4 texels); the features trained in {res.train_seconds:.0f} s "
          f"({wall:.0f} s with export and measurement)")


if __name__ == "__main__":
    main()
