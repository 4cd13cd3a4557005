"""BC1/BC4/BC5/BC7 level decodes: texture2ddecoder (the tests' oracle) against bcfpipe's decoders
(numba: `bcfpipe.formats.s3tc`, `bcfpipe.bc7.kernel`; what `decode_levels` runs), on one thread.

Each decodes a size² level to 8-bit texels (texture2ddecoder: its BGRA bytes; bcfpipe's: the
cropped (h, w, channels) image), warm (after one call), the median of --reps calls; the last two
columns are `decode_levels` to float32 and texture2ddecoder's bytes to the same float32 image (what
the layout ran before bcfpipe's decoders were compiled, issue 59). Blocks: random bytes (BC7: every mode, the reserved 8 too), and a real image
(--image, default the water bottle's base colour, tiled or cropped to size²) encoded by bcfpipe's
own encoders as bcfpipe.texset.baselines does (quicktex for BC1/BC4/BC5: RGB, R, RG; ISPC for BC7:
RGB and the image's alpha or 1). Then the numba decoders' first call in a fresh process with an
empty kernel cache (compile) and with the cache it left (cached load), per format.

  python benchmarks/bench_bcn_decode.py [--size 2048] [--reps 5] [--formats bc1,bc4,bc5,bc7]
                                        [--image PNG | --no-real]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import BOTTLE, REPO, machine  # noqa: E402

N_BYTES = {"bc1": 8, "bc4": 8, "bc5": 16, "bc7": 16}
T2D = {"bc1": ("decode_bc1", [2, 1, 0]), "bc4": ("decode_bc4", [2]), "bc5": ("decode_bc5", [2, 1]),
       "bc7": ("decode_bc7", [2, 1, 0, 3])}

# A fresh process: import the kernels, then time each format's first call (a 4x4 level).
FIRST_CALL = """
import json, sys, time
import numpy as np
t = time.perf_counter()
from bcfpipe.bc7 import kernel
from bcfpipe.formats import s3tc
from bcfpipe.formats.bcn import unorm_decoder
out = {"import": time.perf_counter() - t}
for fmt in sys.argv[1].split(","):
    b = np.zeros((1, 16 if fmt in ("bc5", "bc7") else 8), np.uint8)
    t = time.perf_counter()
    unorm_decoder(fmt)(b, 4, 4)
    out[fmt] = time.perf_counter() - t
print(json.dumps(out))
"""


def random_blocks(fmt: str, n: int, rng: np.random.Generator) -> np.ndarray:
    b = rng.integers(0, 256, (n, N_BYTES[fmt]), dtype=np.uint8)
    if fmt == "bc7":  # a random mode 0-8 per block, the bits above its mode bit random
        modes = rng.integers(0, 9, n)
        low = np.where(modes < 8, 1 << np.minimum(modes, 7), 0)
        b[:, 0] = (b[:, 0] & ~((low << 1) - 1)) | low
    return b


def real_blocks(fmt: str, img: np.ndarray) -> np.ndarray:
    """``img`` ((size, size, 4) in [0, 1]) encoded as bcfpipe.texset.baselines encodes a layout's."""
    from bcfpipe.texset import baselines

    levels: list = []
    {"bc1": lambda: baselines.bc1_mips([img[..., :3]], blocks=levels),
     "bc4": lambda: baselines.bc4_mips([img[..., :1]], blocks=levels),
     "bc5": lambda: baselines.bc5_mips([img[..., :2]], blocks=levels),
     "bc7": lambda: baselines.bc7_mips([img], blocks=levels)}[fmt]()
    return levels[0][0]


def load_image(path: Path, size: int) -> np.ndarray:
    from bcfpipe.formats import images

    px = np.asarray(images.read(path, as_float=True).pixels, np.float32)
    rgba = np.ones(px.shape[:2] + (4,), np.float32)
    rgba[..., :min(4, px.shape[2])] = px[..., :4]
    if px.shape[2] < 3:
        rgba[..., 1:3] = px[..., :1]
    reps = (-(-size // rgba.shape[0]), -(-size // rgba.shape[1]), 1)
    return np.ascontiguousarray(np.tile(rgba, reps)[:size, :size])


def median_s(f, reps: int) -> float:
    f()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def decoders(fmt: str, b: np.ndarray, size: int):
    """(texture2ddecoder, bcfpipe's, decode_levels, texture2ddecoder to float32)."""
    import texture2ddecoder as t2d

    from bcfpipe.formats.bcn import ClassicFormat, decode_levels, unorm_decoder

    raw, name = b.tobytes(), T2D[fmt][0]

    def t2d_float():
        bgra = np.frombuffer(getattr(t2d, name)(raw, size, size), np.uint8).reshape(size, size, 4)
        return np.ascontiguousarray(bgra[..., T2D[fmt][1]], np.float32) / 255.0

    return (lambda: getattr(t2d, name)(raw, size, size), lambda: unorm_decoder(fmt)(b, size, size), lambda: decode_levels(ClassicFormat(fmt), [(b, size, size)]),
            t2d_float)


def first_calls(formats: list[str]) -> tuple[dict, dict]:
    """The numba decoders' first calls in fresh processes: with an empty kernel cache, then with it."""
    with tempfile.TemporaryDirectory(prefix="bcn-kernels-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=str(REPO))
        runs = [json.loads(subprocess.run([sys.executable, "-c", FIRST_CALL, ",".join(formats)], env=env, check=True,
                                          capture_output=True, text=True).stdout) for _ in range(2)]
    return runs[0], runs[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--formats", default="bc1,bc4,bc5,bc7")
    ap.add_argument("--image", type=Path, default=BOTTLE / "WaterBottle_baseColor.png")
    ap.add_argument("--no-real", action="store_true", help="random blocks only")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    formats = args.formats.split(",")
    n = (-(-args.size // 4)) ** 2
    rng = np.random.default_rng(args.seed)
    sources = [("random", None)]
    if not args.no_real:
        if not args.image.is_file():
            raise SystemExit(f"no image at {args.image} (--image PNG, or --no-real)")
        sources.append((args.image.stem, load_image(args.image, args.size)))
    compiled, cached = first_calls(formats)

    print(f"machine: {machine()}; one thread; {args.size}x{args.size}, median of {args.reps} warm calls")
    print("\n| format | blocks | texture2ddecoder ms | bcfpipe ms | bcfpipe / t2d | decode_levels ms "
          "| t2d + float32 ms |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for fmt in formats:
        for label, img in sources:
            b = random_blocks(fmt, n, rng) if img is None else real_blocks(fmt, img)
            t2d_s, nb_s, dl_s, old_s = (median_s(f, args.reps) for f in decoders(fmt, b, args.size))
            print(f"| {fmt} | {label} | {1e3 * t2d_s:.1f} | {1e3 * nb_s:.1f} | {nb_s / t2d_s:.2f} | "
                  f"{1e3 * dl_s:.1f} | {1e3 * old_s:.1f} |", flush=True)
    print(f"\nnumba first call in a fresh process (import of the decoders: {compiled['import']:.2f} s empty cache, "
          f"{cached['import']:.2f} s cached); the first format's includes numba's start-up in the process")
    print("\n| format | compile (empty cache) s | cached load s |")
    print("|---|---:|---:|")
    for fmt in formats:
        print(f"| {fmt} | {compiled[fmt]:.2f} | {cached[fmt]:.3f} |")


if __name__ == "__main__":
    main()
