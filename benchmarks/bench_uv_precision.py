"""Where fp32 uv precision runs out: a material decoded by the GLSL decoder at random points
shifted by whole periods (uv + K), against the same points unshifted (issue #11, item 4).

    .venv/bin/python benchmarks/bench_uv_precision.py [MATERIAL_FOLDER] [--s 0]

The shader range-reduces uv exactly (uv - floor(uv)), so the only loss left is the fp32 uv
itself: near |uv| = K its spacing is ulp(K) = 2^(floor(log2 K) - 23), i.e. ulp(K) * W reference
texels. Prints, per K: that spacing in texels, max |error| and PSNR of the decoded channels.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, machine  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("material", nargs="?", default=str(REPO / "samples/sample_scene.bcf/materials/Bricks"))
    ap.add_argument("--s", type=float, default=0.0)
    args = ap.parse_args()
    from bcfpipe.verify.glsl import GLRuntime, read_material

    m = read_material(args.material)
    w, h = m.ref_size
    rt = GLRuntime()
    print(f"machine: {machine()}; GL: {rt.info['renderer']}")
    gm = rt.load(m)
    uv = np.random.default_rng(0).random((w * h, 2)).astype(np.float32)  # as many points as texels
    base = rt.decode(gm, uv, args.s)
    print(f"{m.name}: reference {w}x{h}, s = {args.s}")
    print("| uv offset K | fp32 uv spacing (texels) | max abs error | PSNR (dB) |")
    print("|---:|---:|---:|---:|")
    for k in (1.0, 16.0, 256.0, 1e3, 4096.0, 1e4, 1e5, 1e6):
        shifted = (uv.astype(np.float64) + k).astype(np.float32)
        out = rt.decode(gm, shifted, args.s)
        err = out.astype(np.float64) - base
        mse = float(np.mean(err ** 2))
        psnr = float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)
        spacing = np.spacing(np.float32(k)) * w
        print(f"| {k:g} | {spacing:.3g} | {np.abs(err).max():.3g} | {psnr:.1f} |")
    rt.unload(gm)
    rt.release()


if __name__ == "__main__":
    main()
