"""Benchmark of the mode-10 (mode bits 11110) BC6H encoder on real textures.

    .venv/bin/python benchmarks/bench_encode.py [--scenes ../shared/scenes] [--size 2048]

For each texture (teapot diffuse and ARM maps, MaterialX brick normal map), read
as a 3-channel float image in [0, 1] through OpenImageIO (values as stored, no
colour conversion; a centred ``--size`` crop, the whole 2048^2 map by default):
encode -> decode (bcfpipe.bc6h.decode) RMSE and PSNR (peak 1), the same with
every block forced to partition 0, the PSNR gain of choosing the shape, the
histogram of chosen shapes, and on a 256^2 crop the PSNR when all 32 shapes are
refined (``refine_top=32, keep=32``) to show what the shape pre-selection leaves.  Then
the wall time to encode one 1024x1024 layer (65,536 blocks), best of 3.
Prints markdown.
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from common import SHARED  # noqa: E402

import torch  # noqa: E402

from bcfpipe.bc6h import decode  # noqa: E402
from bcfpipe.bc6h.encode import encode  # noqa: E402
from bcfpipe.bc6h.encode import blocks_from_image, encode_params  # noqa: E402

TEXTURES = [
    ("teapot diffuse", "usdwg_teapot/textures/tea_set_01_diff_2k.jpg"),
    ("teapot ARM", "usdwg_teapot/textures/tea_set_01_arm_2k.jpg"),
    ("brick normal", "materialx_texture_sets/brick/brick_normal.jpg"),
]


def load_rgb(path: Path) -> np.ndarray:
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(path))
    if buf.has_error:
        raise RuntimeError(f"cannot read {path}: {buf.geterror()}")
    px = buf.get_pixels(oiio.FLOAT)
    if px is None or px.ndim != 3:
        raise RuntimeError(f"cannot read pixels of {path}")
    if px.shape[2] == 1:
        px = np.repeat(px, 3, axis=2)
    return np.ascontiguousarray(px[:, :, :3], dtype=np.float32)


def crop(img: np.ndarray, size: int) -> np.ndarray:
    h, w, _ = img.shape
    s = min(size, h, w) // 4 * 4
    y, x = (h - s) // 2, (w - s) // 2
    return np.ascontiguousarray(img[y : y + s, x : x + s])


def psnr_rmse(ref: np.ndarray, blocks: np.ndarray) -> tuple[float, float]:
    h, w, _ = ref.shape
    dec = decode(blocks, w, h).astype(np.float64)
    mse = float(np.mean((dec - ref) ** 2))
    return 10.0 * np.log10(1.0 / mse), float(np.sqrt(mse))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default=str(SHARED))
    ap.add_argument("--size", type=int, default=2048, help="centred square crop of each texture")
    ap.add_argument("--repeats", type=int, default=3, help="timing runs (best of)")
    args = ap.parse_args()
    scenes = Path(args.scenes)

    print("## BC6H encoder (issue 2)\n")
    print(f"- command: `.venv/bin/python benchmarks/bench_encode.py --size {args.size}`")
    print(f"- date: {datetime.date.today().isoformat()}")
    from bcfpipe.bench.run import machine

    print(f"- machine: {os.cpu_count()}-core CPU ({machine()['cpu']}), torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads")
    print("- encoder: mode 11110 only, default settings (`refine_top=4, keep=2, rounds=2, window=4`)\n")

    rows, hists = [], []
    layer = None
    for name, rel in TEXTURES:
        path = scenes / rel
        img = crop(load_rgb(path), args.size)
        if layer is None:
            layer = crop(img, 1024)
        h, w, _ = img.shape
        t0 = time.perf_counter()
        ep, ix, pt = encode_params(img)
        t_enc = time.perf_counter() - t0
        from bcfpipe.bc6h.mode10 import pack

        psnr, rmse = psnr_rmse(img, pack(ep, ix, pt))
        psnr0, rmse0 = psnr_rmse(img, encode(img, partitions=0))
        small = crop(img, 256)
        ps_def, _ = psnr_rmse(small, encode(small))
        ps_all, _ = psnr_rmse(small, encode(small, refine_top=32, keep=32))
        rows.append((name, f"{w}x{h}", rmse, psnr, rmse0, psnr0, psnr - psnr0, ps_def, ps_all, t_enc))
        hists.append((name, np.bincount(pt, minlength=32)))
        print(f"<!-- {name}: {path} done -->", file=sys.stderr, flush=True)

    print("| texture | size | RMSE | PSNR (dB) | RMSE, partition 0 | PSNR, partition 0 | gain (dB) "
          "| 256² crop: PSNR | 256² crop: all 32 shapes refined | encode time of the map (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, size, rmse, psnr, rmse0, psnr0, gain, psd, psa, te in rows:
        print(f"| {name} | {size} | {rmse:.5f} | {psnr:.2f} | {rmse0:.5f} | {psnr0:.2f} | {gain:+.2f} "
              f"| {psd:.2f} | {psa:.2f} | {te:.1f} |")

    print("\nChosen partition (shape id 0..31) histogram, blocks per shape:\n")
    print("| texture | " + " | ".join(str(i) for i in range(32)) + " |")
    print("|---|" + "---|" * 32)
    for name, hist in hists:
        print(f"| {name} | " + " | ".join(str(int(v)) for v in hist) + " |")

    assert layer is not None and layer.shape == (1024, 1024, 3)
    n_blocks = blocks_from_image(layer).shape[0]
    encode(layer[:64, :64])  # warm-up
    times = []
    for _ in range(max(1, args.repeats)):
        t0 = time.perf_counter()
        encode(layer)
        times.append(time.perf_counter() - t0)
    print(f"\nEncode time of one 1024x1024 layer ({n_blocks:,} blocks, teapot diffuse crop): "
          f"**{min(times):.2f} s** best of {len(times)} (all: {', '.join(f'{t:.2f}' for t in times)} s).")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
