"""Issue 58: the layout's probe encodes its T_0 of principal components in BC7's modes with alpha.

For each named set, the T_0 a 1k training fixes (`train.fixed_t0.pca_t0`: the set's principal
components, every mip of each layer) is taken from a smoke training at 1k and encoded again by ISPC
at `texset.baselines.BC7_PROFILES` ``basic`` (what ships) and ``alpha_modes`` (modes 4-7: the
probe's), on the job's cores. Prints seconds, PSNR over the layer's four 8-bit channels (every mip's
texels), how many blocks took each mode, and how many blocks differ from basic's.

  python benchmarks/bench_t0_encode.py [--sets teapot,brick,wood,bottle]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, specs  # noqa: E402


def t0_levels(name: str, out: Path) -> list[list[np.ndarray]]:
    """The (H, W, 4) [0, 1] levels of each T_0 layer a 1k smoke training of ``name`` encodes."""
    from bcfpipe.config import TrainingOptions
    from bcfpipe.export.material import make_config, train_material
    from bcfpipe.texset.texture_set import load_texture_set
    from bcfpipe.train import fixed_t0

    ts = load_texture_set(specs(name))
    cfg = make_config(ts, TrainingOptions(profile="1k", preset="smoke", device="cpu", threads=1))[1]
    seen: list[list[np.ndarray]] = []
    encode = fixed_t0.encoded_levels

    def keep(levels, *a, **k):
        seen.append([np.array(l) for l in levels])
        return encode(levels, *a, **k)

    fixed_t0.encoded_levels = keep
    try:
        train_material(ts, out, cfg, "1k")
    finally:
        fixed_t0.encoded_levels = encode
    return seen


def modes(blocks: np.ndarray) -> np.ndarray:
    """Blocks per BC7 mode (the lowest set bit of byte 0)."""
    first = blocks[:, 0].astype(np.int64)
    mode = np.where(first == 0, 8, np.log2(first & -first).astype(np.int64))
    return np.bincount(mode, minlength=9)[:8]


def main() -> None:
    from bcfpipe.texset.baselines import bc7_mips

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", default="teapot,brick,wood,bottle")
    a = ap.parse_args()
    print(f"machine: {machine()}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.sets.split(","):
            for j, levels in enumerate(t0_levels(name, Path(tmp) / name)):
                got, bytes_of = {}, {}
                for profile in ("basic", "alpha_modes"):
                    blocks: list = []
                    t = time.perf_counter()
                    dec, _ = bc7_mips(levels, blocks, profile)
                    dt = time.perf_counter() - t
                    sq = sum(float(((np.rint(d * 255) - np.rint(np.clip(l, 0, 1) * 255)) ** 2).sum()) for d, l in zip(dec, levels))
                    n = sum(l.size for l in levels)
                    psnr = 10 * np.log10(255.0 ** 2 / (sq / n)) if sq else float("inf")
                    hist = sum(modes(np.asarray(b, np.uint8).reshape(-1, 16)) for b, _, _ in blocks)
                    got[profile] = (dt, psnr)
                    bytes_of[profile] = np.concatenate([np.asarray(b, np.uint8).reshape(-1, 16) for b, _, _ in blocks])
                    print(f"{name:7s} T_0 layer {j} ({levels[0].shape[1]}², {len(levels)} mips) {profile:13s}: "
                          f"{dt:5.2f} s, {psnr:.3f} dB, blocks per mode {hist.tolist()}", flush=True)
                tb, pb = got["basic"]
                for profile, (tp, pp) in got.items():
                    same = int((bytes_of[profile] == bytes_of["basic"]).all(1).sum())
                    print(f"{name:7s} T_0 layer {j}: {profile} {tp / tb:.2f}x the time, {pp - pb:+.3f} dB, "
                          f"{len(bytes_of['basic']) - same} of {len(bytes_of['basic'])} blocks other than basic's", flush=True)


if __name__ == "__main__":
    main()
