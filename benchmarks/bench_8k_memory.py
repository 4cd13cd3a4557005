"""Peak memory and time of `bcfpipe train` on an 8192² texture set with 8 channels (issue #11, item 3).

    .venv/bin/python benchmarks/bench_8k_memory.py [--size 8192] [--profile tiny] [--preset draft] [--kernel auto]
                                                   [--layout auto|neural]

Writes a synthetic but not trivially compressible set into a temporary folder (8-bit PNGs:
albedo rgb, normal xy, and an ORM file for occlusion, roughness, metallic: 8 channels), runs
`bcfpipe train` on it as a child process, and reads the child's peak RSS (ru_maxrss of
RUSAGE_CHILDREN, which is exact for one child). Prints the machine, the figures, and a Markdown
row for docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, machine, run_bcfpipe  # noqa: E402


def write_set(folder: Path, n: int) -> list[str]:
    """Smooth waves plus value noise at a few scales, one PNG per file, written band by band."""
    from PIL import Image

    rng = np.random.default_rng(0)
    coarse = [rng.random((n // s + 2, n // s + 2, 3), np.float32) for s in (512, 64, 8)]

    def band(y0: int, y1: int) -> np.ndarray:
        y, x = np.mgrid[y0:y1, 0:n].astype(np.float32) / n
        out = np.zeros((y1 - y0, n, 3), np.float32)
        for k, c in enumerate(coarse):
            s = n // (c.shape[0] - 2)
            out += c[(y * n / s).astype(np.int64), (x * n / s).astype(np.int64)] * 0.5 ** k
        out += 0.25 * np.sin(2 * np.pi * (7 * x + 3 * y))[..., None]
        return np.clip(out / 2.2, 0, 1)

    files = {name: np.empty((n, n, 3), np.uint8) for name in ("albedo", "normal", "orm")}
    step = 512
    for y0 in range(0, n, step):
        b = band(y0, min(n, y0 + step))
        files["albedo"][y0:y0 + b.shape[0]] = (b * 255 + 0.5).astype(np.uint8)
        files["normal"][y0:y0 + b.shape[0]] = (np.roll(b, 1, -1) * 255 + 0.5).astype(np.uint8)
        files["orm"][y0:y0 + b.shape[0]] = (b[..., ::-1] ** 2 * 255 + 0.5).astype(np.uint8)
    for name, a in files.items():
        Image.fromarray(a).save(folder / f"{name}.png", compress_level=1)
    del files
    return [f"albedo={folder / 'albedo.png'}:rgb", f"normal={folder / 'normal.png'}:xy",
            f"occlusion={folder / 'orm.png'}:r", f"roughness={folder / 'orm.png'}:g",
            f"metallic={folder / 'orm.png'}:b"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_options(ap, size=8192, profile="tiny", preset="draft")
    ap.add_argument("--kernel", default="auto", help="bcfpipe train --kernel (issue 30)")
    ap.add_argument("--layout", default=None, help="bcfpipe train --layout (issue 31); default: train's default")
    args = ap.parse_args()
    print(f"machine: {machine()}")
    with tempfile.TemporaryDirectory(prefix="bcf8k-") as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        specs = write_set(tmp, args.size)
        print(f"wrote the {args.size}² set in {time.perf_counter() - t0:.0f} s")
        wall, p = run_bcfpipe("train", *specs, "-o", tmp / "out", "--profile", args.profile, "--quality", args.preset,
                              "--kernel", args.kernel, "--json", *(["--layout", args.layout] if args.layout else []))
        peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 2 ** 20  # KiB -> GiB
        if p.returncode != 0:
            raise SystemExit(f"train failed ({p.returncode}): {p.stderr.strip()[-2000:]}")
        res = json.loads(p.stdout)
        per_mip = ", ".join(f"{v:.1f}" for v in res["metrics"]["psnr_per_mip"])
        print(f"exit 0 in {wall:.0f} s, peak RSS {peak:.2f} GiB, PSNR {res['psnr']:.2f} dB (per mip {per_mip})")
        print(f"phases: {res['phase_seconds']}")
        layout = (res.get("layout") or {}).get("chosen", {}).get("layout", "neural")
        print(f"| {args.size}² x 8 channels, --kernel {args.kernel}, layout {args.layout or 'default'} ({layout}) | "
              f"{args.profile} | {args.preset} | {peak:.2f} GiB | {wall:.0f} s | {res['psnr']:.2f} dB |")


if __name__ == "__main__":
    main()
